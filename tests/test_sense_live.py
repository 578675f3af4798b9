"""`softforce sense --live` through pyrealsense2's software_device (no camera needed).

The frames of a sample recording are pushed at 30 fps into a software depth + colour device,
synced and aligned by pyrealsense2 as a camera's would be, and handed to `sense --live` in
place of the RealSense; `--record` must keep every frame while sensing takes the newest.
"""

from __future__ import annotations

import json
import threading
import time

from typer.testing import CliRunner

from softforce_cli.camera import realsense
from softforce_cli.camera.realsense import rgbd_frames_from_framesets
from softforce_cli.cli.main import _register_commands, app
from softforce_cli.io.mcap_reader import iter_frames
from tests.conftest import ROOT, SAMPLE_ROBOT
from tests.realsense_fakes import FPS, PERIOD_MS, T0_MS, SoftwareCamera
from tests.test_sense_cli import pose_calibration

PROBES = ROOT / "sample_data" / "recordings" / "probes.mcap"
REPEATS = 6  # each recorded frame is shown this many times: 24 frames, 0.8 s at 30 fps


def live_frames_from(recording):
    frames = list(iter_frames(recording))
    k = frames[0].intrinsics
    camera = SoftwareCamera(depth_k=k, color_k=k)
    pushed = len(frames) * REPEATS

    def push() -> None:
        start = time.monotonic()
        for number in range(pushed):
            time.sleep(max(0.0, start + number / FPS - time.monotonic()))
            frame = frames[number // REPEATS]
            camera.push(number, frame.depth_mm, frame.color)

    def framesets(pusher: threading.Thread):
        while True:
            done = not pusher.is_alive()
            ok, frameset = camera.syncer.try_wait_for_frames(100)
            if ok:
                yield frameset
            elif done:
                return

    def iter_live_frames(settings, duration_s=None, on_progress=None):
        pusher = threading.Thread(target=push)
        pusher.start()
        try:
            yield from rgbd_frames_from_framesets(framesets(pusher))
        finally:
            pusher.join()
            camera.close()

    return iter_live_frames, pushed


def test_sense_live_senses_the_newest_frames_and_records_every_frame(tmp_path, monkeypatch):
    truth_file = PROBES.with_suffix("").with_suffix(".truth.json")
    truth = json.loads(truth_file.read_text())
    calibration = pose_calibration(truth_file, tmp_path, actuation={
        "control": "displacement", "values": truth["frames"][0]["actuation"]["values"]})
    fake, pushed = live_frames_from(PROBES)
    monkeypatch.setattr(realsense, "iter_live_frames", fake)
    _register_commands()
    out, kept = tmp_path / "out", tmp_path / "live.mcap"
    result = CliRunner().invoke(app, ["sense", "--live", "--robot", str(SAMPLE_ROBOT),
                                      "--calibration", str(calibration), "-o", str(out),
                                      "--record", str(kept)])
    assert result.exit_code == 0, result.output
    recorded = [frame.time_ns for frame in iter_frames(kept)]
    # every frame the syncer pairs (all but the first) is recorded, in order
    assert recorded == [round((T0_MS + n * PERIOD_MS) * 1e6) for n in range(1, pushed)]
    document = json.loads((out / "sense.json").read_text())
    sensed = [f["time_s"] for f in document["frames"]]
    assert 0 < len(sensed) <= pushed - 1 and sensed == sorted(sensed)
    assert document["recording"] == "live RealSense"
