"""Recordings: virtual D415 rendering, and MCAP write/read of 640x480 RGB-D frames."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import BenchRow, median_time
from softforce_cli.camera.frame import Actuation, RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.io.mcap_writer import write_recording
from softforce_cli.model.robot import load_robot
from softforce_cli.sim.camera_pose import look_at
from softforce_cli.sim.depth_noise import apply_d415
from softforce_cli.sim.props import probe_surface
from softforce_cli.sim.render import SceneSurface, render, table_surface

ROOT = Path(__file__).resolve().parents[1]
FINE = ROOT / "sample_data" / "diamond_fine" / "diamond.toml"
FRAMES = 60


def run() -> list[BenchRow]:
    robot = load_robot(FINE)  # the simulator renders the fine truth mesh
    intrinsics = CameraIntrinsics.from_fov(640, 480, 69.0)
    pose = look_at(np.array([0.0, 0.0, 580.0]), np.array([0.0, 0.0, 40.0]))
    surfaces = [
        SceneSurface("robot", robot.mesh.nodes_mm, robot.mesh.surface_faces,
                     np.array([40, 90, 210]), smooth=True),
        table_surface(-37.5, 600.0, np.array([150, 118, 84])),
        probe_surface(np.array([0.0, 45.0, 90.0]), np.array([0.0, -0.6, -0.8]), (220, 50, 40)),
    ]
    triangles = sum(len(s.faces) for s in surfaces)
    render_s = median_time(lambda: render(surfaces, intrinsics, pose), repeats=20)
    view = render(surfaces, intrinsics, pose)
    rng = np.random.default_rng(0)
    noise_s = median_time(lambda: apply_d415(view, intrinsics, rng), repeats=20)
    frames = []
    for i in range(FRAMES):
        depth, color = apply_d415(view, intrinsics, rng)
        frames.append(RgbdFrame(i * 33_333_333, color, depth, intrinsics,
                                Actuation(("a", "b", "c", "d"), "displacement", np.zeros(4))))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bench.mcap"
        write_s = median_time(lambda: write_recording(frames, path, force=True), repeats=3,
                              warmup=0) / FRAMES
        size = path.stat().st_size / FRAMES
        read_s = median_time(lambda: sum(1 for _ in iter_frames(path)), repeats=3) / FRAMES
    return [
        BenchRow("Render 640x480 depth + colour (ray casting, no FE solve)", render_s, 20,
                 ">= 30 fps", f"{1 / render_s:.0f} fps",
                 f"{triangles} triangles: fine robot, table, probe"),
        BenchRow("  D415 sensor model on a 640x480 view", noise_s, 20, "",
                 f"{noise_s * 1e3:.1f} ms", "noise, quantisation, holes, colour noise"),
        BenchRow("  render + sensor model", render_s + noise_s, 20, "",
                 f"{1 / (render_s + noise_s):.0f} fps", "what `simulate` pays per frame"),
        BenchRow("MCAP write, 640x480 RGB-D + actuation (zstd)", write_s, 3, ">= 100 frames/s",
                 f"{1 / write_s:.0f} frames/s",
                 f"{size / 1e3:.0f} kB per noisy frame (raw 1536 kB)"),
        BenchRow("MCAP read, 640x480 RGB-D + actuation", read_s, 3, ">= 100 frames/s",
                 f"{1 / read_s:.0f} frames/s", "streamed frame by frame"),
    ]
