"""`make bench` only: the vision stage at the D415's 640x480 and 1280x720 on freshly
simulated probes recordings (about 30 s and 90 s to simulate): speed per stage, and both
probes found; at 1280x720 decimated (the default) and with every pixel.

Run alone with `.venv/bin/pytest -q -s -m bench tests/test_vision_speed.py`; it prints the
median milliseconds of every stage (docs/vision.md quotes them).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.sim.simulate import simulate
from softforce_cli.vision.pipeline import STAGES, process_frame, robot_distance_mm
from softforce_cli.vision.settings import VisionSettings, settings_for_camera
from tests.conftest import sample_probes_scenario

REPEATS = 40


@pytest.fixture(scope="module")
def probes(tmp_path_factory):
    """(width, height) -> the probes recording's frames and truth, simulated once each."""
    simulated = {}

    def recording(width: int, height: int) -> tuple[list, dict]:
        if (width, height) not in simulated:
            folder = tmp_path_factory.mktemp(f"vision_speed_{width}")
            (folder / "probes.toml").write_text(sample_probes_scenario(width, height))
            result = simulate(folder / "probes.toml", folder / "probes.mcap")
            simulated[width, height] = (list(iter_frames(result.recording)),
                                        json.loads(result.truth.read_text()))
        return simulated[width, height]

    return recording


@pytest.mark.bench
@pytest.mark.parametrize("width, height, decimation",
                         [(640, 480, 0), (1280, 720, 0), (1280, 720, 1)],
                         ids=["640x480", "1280x720-decimated", "1280x720-every-pixel"])
def test_vision_stage_speed_and_accuracy(probes, width, height, decimation, sample_robot):
    frames, truth = probes(width, height)
    intrinsics = frames[0].intrinsics
    pose = RigidTransform(np.array(truth["camera"]["rotation"]),
                          np.array(truth["camera"]["translation_mm"]))
    mesh = sample_robot.mesh
    settings = settings_for_camera(VisionSettings(decimation=decimation), intrinsics.fx,
                                   robot_distance_mm(mesh.bounds_mm, pose))
    if decimation == 0:  # the paper's values: 640x480, or 1280x720 decimated to its pixels
        assert settings.outlier_min_neighbours == 20
        assert settings.decimation == (2 if intrinsics.width == 1280 else 1)
    arguments = dict(
        intrinsics=intrinsics, robot_from_camera=pose, model_bounds_mm=mesh.bounds_mm,
        feature_positions_mm=mesh.nodes_mm[sample_robot.feature_nodes],
        feature_normals=sample_robot.feature_normals, robot_rgb=np.array([37, 82, 192]),
        settings=settings, excluded_box_mm=np.array(sample_robot.config.fixed_boxes_mm[0]),
    )
    timings = {stage: [] for stage in (*STAGES, "total")}
    wall, cpu = [], []
    for _ in range(REPEATS):
        for frame in frames:
            start, start_cpu = time.perf_counter(), time.process_time()
            result = process_frame(frame.depth_mm, frame.color, **arguments)
            cpu.append(1e3 * (time.process_time() - start_cpu))
            wall.append(1e3 * (time.perf_counter() - start))
            for stage, ms in result.timings_ms.items():
                timings[stage].append(ms)
    medians = {stage: float(np.median(ms)) for stage, ms in timings.items()}
    fastest = {stage: float(np.percentile(ms, 10)) for stage, ms in timings.items()}
    print(f"\nvision stage, {intrinsics.width}x{intrinsics.height}, decimation "
          f"{settings.decimation}, {len(wall)} frames: median {np.median(wall):.1f} ms, "
          f"10th-90th percentile {np.percentile(wall, 10):.1f}-{np.percentile(wall, 90):.1f} ms; "
          f"CPU time median {np.median(cpu):.1f} ms")
    for stage, ms in medians.items():
        print(f"  {stage:13s} median {ms:6.2f} ms, 10th percentile {fastest[stage]:6.2f} ms")
    # speed is reported (make bench prints it), never asserted: this machine is shared and
    # noisy (28-40 ms of CPU was measured at a load average of 7, docs/vision.md)
    # both probes of the last frame, the east one pressing on a side the camera cannot see
    last = process_frame(frames[3].depth_mm, frames[3].color, **arguments)
    probes_mm = np.array([c["point_mm"] for c in truth["frames"][3]["contacts"]])
    distance = np.linalg.norm(last.contacts.centres_mm[:, None] - probes_mm[None], axis=2)
    assert len(last.contacts) == 2
    assert np.all(distance.min(axis=1) < 20.0) and np.all(distance.min(axis=0) < 20.0)
