"""Outputs of every command: never overwritten without --force, never half-written.

Each command is given an output that already exists: it must refuse with one error line that
names the file and --force, leave the file byte for byte as it was, and leave no temporary file.
A run that fails part-way must leave either nothing or a finished, readable file.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest

from softforce_cli.errors import SolverError
from softforce_cli.io.mcap_reader import iter_frames, read_summary
from tests.test_fuzz_harness import classify, run_cli

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
PRECIOUS = b"an earlier result\n"


def scenario_file(folder: Path, frames: int = 3) -> Path:
    lines = [f'name = "small"\nrobot = "{ROBOT}"\nlaw = "linear"\n', "[camera]\nwidth = 32\n"
             "height = 24\n"]
    lines += [f"[[frame]]\nactuation = [{i}.0, 0.0, 0.0, 0.0]\n" for i in range(frames)]
    path = folder / "small.toml"
    path.write_text("\n".join(lines))
    return path


def markers_file(folder: Path) -> Path:
    path = folder / "markers.csv"
    path.write_text("id,x_mm,y_mm,z_mm\napex,0,0,400\nelbow_north,0,101,480\n"
                    "elbow_west,-101,0,480\nelbow_south,0,-101,480\n")
    return path


# (command arguments with {out} for the existing file, the file's name)
COMMANDS = {
    "model init": (["model", "init", "{dir}"], "diamond.toml"),
    "model solve": (["model", "solve", ROBOT, "-o", "{out}"], "deformed.vtu"),
    "model show --picture": (["model", "show", ROBOT, "--picture", "{out}"], "robot.png"),
    "record": (["record", "--from", "{dir}/missing.db3", "-o", "{out}"], "rec.mcap"),
    "simulate (recording)": (["simulate", "{scenario}", "-o", "{out}"], "sim.mcap"),
    "simulate (truth)": (["simulate", "{scenario}", "-o", "{dir}/sim.mcap"], "sim.truth.json"),
    "calibrate": (["calibrate", "--robot", ROBOT, "--markers", "{markers}", "-o", "{out}"],
                  "calib.json"),
    "calibrate --plot": (["calibrate", "--robot", ROBOT, "--markers", "{markers}", "-o",
                          "{dir}/calib.json", "--plot", "{out}"], "residual.png"),
}


@pytest.mark.parametrize("command", COMMANDS)
def test_existing_output_is_refused_without_force(tmp_path, command):
    arguments, name = COMMANDS[command]
    existing = tmp_path / name
    existing.write_bytes(PRECIOUS)
    values = {"out": existing, "dir": tmp_path, "scenario": scenario_file(tmp_path),
              "markers": markers_file(tmp_path)}
    args = [str(a).format(**values) if isinstance(a, str) else a for a in arguments]
    before = sorted(p.name for p in tmp_path.iterdir())
    outcome = run_cli(*args)
    assert classify(outcome) == "error"
    line = " ".join(outcome.stderr.split())
    assert f"{existing} already exists; pass --force to overwrite it" in line
    assert existing.read_bytes() == PRECIOUS
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing new, no .tmp


SAMPLES = ROOT / "sample_data" / "recordings"
# outputs that are folders, or files written after the work (a blocked folder must be found
# before it: diagnose checks it before its vision stage)
FOLDER_COMMANDS = {
    "sense": ["sense", SAMPLES / "probes.mcap", "--robot", ROBOT, "--calibration",
              "{calibration}", "--frames", "0:1", "-o", "{out}"],
    "diagnose": ["diagnose", SAMPLES / "diagnose_slack.mcap", "--robot", ROBOT,
                 "--calibration", "{calibration}", "-o", "{out}"],
    "model reduce": ["model", "reduce", ROBOT, "-o", "{out}/robot.rom.npz"],
}


# record: its input is a RealSense file, refused before any output is made
@pytest.mark.parametrize("command", [*(c for c in COMMANDS if c != "record"), *FOLDER_COMMANDS])
def test_an_output_that_cannot_be_written_is_one_line(tmp_path, command):
    """An output under a path that cannot be a folder (a file stands there, as a read-only
    or virtual file system would refuse it): one error line naming it, no traceback (the
    writers' OSError had escaped as one)."""
    blocked = tmp_path / "a_file"
    blocked.write_bytes(PRECIOUS)
    calibration = tmp_path / "pose.json"
    calibration.write_text('{"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], '
                           '"translation_mm": [0, 0, 0]}')
    if command in COMMANDS:
        arguments, name = COMMANDS[command]
    else:
        arguments, name = FOLDER_COMMANDS[command], "out"
    values = {"out": blocked / name, "dir": blocked, "scenario": scenario_file(tmp_path),
              "markers": markers_file(tmp_path), "calibration": calibration}
    args = [str(a).format(**values) if isinstance(a, str) else a for a in arguments]
    outcome = run_cli(*args)
    assert classify(outcome) == "error"
    line = " ".join(outcome.stderr.split())
    assert "error: cannot write" in line and str(blocked) in line
    assert blocked.read_bytes() == PRECIOUS


def test_force_replaces_the_output(tmp_path):
    existing = tmp_path / "deformed.vtu"
    existing.write_bytes(PRECIOUS)
    outcome = run_cli("model", "solve", ROBOT, "-o", existing, "--actuation", "2,0,0,0",
                      "--force")
    assert classify(outcome) == "ok"
    mesh = meshio.read(existing)
    displacement = mesh.point_data["displacement_mm"]
    assert mesh.points.shape == displacement.shape and np.abs(displacement).max() > 0.1
    assert not list(tmp_path.glob("*.tmp*"))


def failing_solver(fail_at: int):
    """solve_frame that raises SolverError on its `fail_at`-th call (0-based)."""
    from softforce_cli.sim import simulate

    real, calls = simulate.solve_frame, []

    def solve(*args, **kwargs):
        calls.append(1)
        if len(calls) > fail_at:
            raise SolverError("the truth robot did not converge (injected by the test)")
        return real(*args, **kwargs)

    return solve


def test_failure_before_the_first_frame_writes_nothing(tmp_path, monkeypatch):
    from softforce_cli.sim import simulate

    monkeypatch.setattr(simulate, "solve_frame", failing_solver(0))
    scenario = scenario_file(tmp_path)
    outcome = run_cli("simulate", scenario, "-o", tmp_path / "sim.mcap")
    assert classify(outcome) == "error" and "injected by the test" in outcome.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml"]


def test_failure_mid_run_leaves_a_finished_recording(tmp_path, monkeypatch):
    """A solver failure at frame 2: the two frames done are a finished, indexed MCAP (the
    writer's promise) with their truth beside it (it had been left out: a recording without
    its truth, or, under --force, with an earlier run's), the error is one line that says
    so, and no temporary file is left."""
    from softforce_cli.sim import simulate

    monkeypatch.setattr(simulate, "solve_frame", failing_solver(2))
    output = tmp_path / "sim.mcap"
    output.write_bytes(b"an earlier run")
    truth = tmp_path / "sim.truth.json"
    truth.write_text('{"frames": "of an earlier run"}')
    outcome = run_cli("simulate", scenario_file(tmp_path), "-o", output, "--force")
    assert classify(outcome) == "error" and "injected by the test" in outcome.stderr
    assert "the 2 frame(s) before it are kept in" in outcome.stderr
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_summary(output).indexed
        assert len(list(iter_frames(output))) == 2
    frames = json.loads(truth.read_text())["frames"]
    assert [frame["actuation"]["values"] for frame in frames] == [[0, 0, 0, 0], [1, 0, 0, 0]]
    assert not list(tmp_path.glob(".*.tmp"))
