"""Sensing with the next frame's vision made ahead in a worker thread (estimation.lookahead)
reads the frames as sensing them in turn does, and stops cleanly."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from softforce_cli.calibration.result import read_calibration
from softforce_cli.estimation.lookahead import QUEUE_DEPTH, observed_frames
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.session import FrameRange, run_sensing
from softforce_cli.estimation.settings import SenseSettings
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.model.robot import load_robot
from tests.conftest import SAMPLE_ROBOT
from tests.test_sense_cli import PROBES, pose_calibration


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lookahead")
    calibration = pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), folder)
    robot = load_robot(SAMPLE_ROBOT)
    frames = list(iter_frames(PROBES))

    def sensor() -> ForceSensor:
        return ForceSensor(robot, read_calibration(calibration).robot_from_camera,
                           frames[0].actuation.values, SenseSettings(), tare_frames=1)

    return frames, sensor, folder


def _sense(setup, look_ahead: bool) -> list[dict]:
    """The frames of sense.json (written with an empty header: still a JSON document)."""
    frames, sensor, folder = setup
    out = folder / f"ahead_{look_ahead}"
    run_sensing(FrameRange().select(iter(frames)), sensor(), out, {},
                look_ahead=look_ahead)
    return json.loads((out / "sense.json").read_text())["frames"]


def test_frames_read_ahead_are_read_as_in_turn(setup):
    """The probes recording (one unloaded frame, then one and two probes): the same
    statuses, contacts and forces with and without the look-ahead (its crop box is the
    configuration one frame before, well inside the box's margin)."""
    ahead, in_turn = _sense(setup, True), _sense(setup, False)
    assert [f["status"] for f in ahead] == [f["status"] for f in in_turn] == [
        "tare", "ok", "ok", "ok"]
    for one, other in zip(ahead, in_turn, strict=True):
        assert [c["feature"] for c in one["contacts"]] == [c["feature"] for c in other["contacts"]]
        np.testing.assert_allclose([c["force_n"] for c in one["contacts"]],
                                   [c["force_n"] for c in other["contacts"]], rtol=1e-9)
        assert one["features_matched"] == other["features_matched"]
    assert sum(len(f["contacts"]) for f in ahead) == 4


def _counted(frames):
    """(index, frame, 0.0) of frames, counting how many were taken in `taken`."""
    taken = [0]

    def source():
        for index, frame in enumerate(frames):
            taken[0] += 1
            yield index, frame, 0.0

    return source(), taken


def test_closing_early_stops_the_worker_after_a_frame_or_two(setup):
    frames, sensor, _ = setup
    many = [frames[i % len(frames)] for i in range(40)]
    source, taken = _counted(many)
    reader = sensor()
    stream = observed_frames(source, reader)
    index, frame, _, observation = next(stream)
    assert observation is None  # the first frame is the caller's: it learns the colour
    reader.process(index, frame)
    index, frame, _, observation = next(stream)
    assert index == 1 and observation is not None
    reader.process(index, frame, observation)
    stream.close()
    assert not any(t.name == "softforce-vision" for t in threading.enumerate())
    # the first two, the one in the queue and the one the worker was observing
    assert taken[0] <= 2 + QUEUE_DEPTH + 1 < len(many)


def test_an_error_in_the_worker_reaches_the_caller(setup):
    frames, sensor, _ = setup
    source, _ = _counted(frames)
    reader = sensor()
    stream = observed_frames(source, reader)
    index, frame, _, _ = next(stream)
    reader.process(index, frame)

    def broken(frame):
        raise ValueError("a frame the vision cannot read")

    reader.observe = broken
    with pytest.raises(ValueError, match="cannot read"):
        next(stream)
