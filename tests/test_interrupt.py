"""SIGINT and SIGTERM in the middle of a run: the outputs so far stay valid and are named.

Each test starts the real `softforce` command in a subprocess, waits until its recording's
temporary file holds a few frames, signals it, and checks: the conventional exit status (130
for SIGINT, 143 for SIGTERM), no traceback, stderr naming the outputs, a finished, indexed MCAP
holding the frames done (read back without any warning), no temporary file left behind, and for
`simulate` a truth file with exactly the recording's frames.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import pytest

from softforce_cli.cli.interrupt import install_signal_handlers
from softforce_cli.io import atomic, mcap_writer
from softforce_cli.io.mcap_reader import iter_frames, read_summary

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
STATES = 40  # distinct actuations: one FE solve (~0.2 s) each, so the run lasts seconds
REPEAT = 3

# `softforce record --from` converts a small .db3 at ~1500 frames/s, faster than a test can
# signal it reliably; this runs the real entry point with the file's frames slowed to 100/s.
THROTTLED_CLI = """
import sys, time
from softforce_cli.cli import record_commands
read = record_commands.iter_file_frames
def slowly(*args, **kwargs):
    for frame in read(*args, **kwargs):
        time.sleep(0.01)
        yield frame
record_commands.iter_file_frames = slowly
from softforce_cli.cli.main import main
sys.argv = ["softforce", *sys.argv[1:]]
main()
"""


def run_and_signal(command: list[str], output: Path, sig: int, min_bytes: int):
    """Start `command`, signal it once its temporary output has `min_bytes`; wait for it."""
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT
    )
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and process.poll() is None:
            partial = list(output.parent.glob(f".{output.name}.*.tmp"))
            if partial and partial[0].stat().st_size >= min_bytes:
                process.send_signal(sig)
                break
            time.sleep(0.02)
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == EXIT_STATUS[sig], stderr  # not finished before the signal
    assert "Traceback" not in stderr
    assert not list(output.parent.glob("*.tmp")), "a temporary file was left behind"
    return stdout, stderr


def read_clean(path: Path) -> list:
    """Every frame of `path`, asserting the file is finished and indexed: no warning at all."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        summary = read_summary(path)
        frames = list(iter_frames(path))
    assert summary.indexed and summary.frame_count == len(frames)
    return frames


@pytest.fixture
def long_scenario(tmp_path: Path) -> Path:
    lines = [f'name = "long"\nrobot = "{ROBOT}"\nlaw = "linear"\nseed = 1\n']
    lines.append("[camera]\nwidth = 160\nheight = 120\n")
    for state in range(STATES):
        value = 0.1 * state
        lines.append(f"[[frame]]\nactuation = [{value}, 0.0, {value}, 0.0]\nrepeat = {REPEAT}\n")
    path = tmp_path / "long.toml"
    path.write_text("\n".join(lines))
    return path


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_during_simulate_keeps_frames_and_truth(tmp_path, long_scenario, sig):
    output = tmp_path / "out" / "long.mcap"
    command = [sys.executable, "-m", "softforce_cli", "simulate", str(long_scenario), "-o"]
    # 160x120 noisy frames are ~60 kB: wait for about 3 frames
    _, stderr = run_and_signal([*command, str(output)], output, sig, 150_000)
    frames = read_clean(output)
    assert 0 < len(frames) < STATES * REPEAT
    truth_file = output.with_name("long.truth.json")
    truth = json.loads(truth_file.read_text())
    assert [f["log_time_ns"] for f in truth["frames"]] == [f.time_ns for f in frames]
    flat = " ".join(stderr.split())
    assert str(output) in flat.replace(" ", "") or str(output) in flat
    assert "interrupted" in flat


@pytest.fixture(scope="module")
def db3_file(tmp_path_factory) -> Path:
    """A 400-frame 64x48 RealSense .db3, written by rs.recorder around a software device."""
    import numpy as np

    from tests.realsense_fakes import H, SoftwareCamera, W

    path = tmp_path_factory.mktemp("db3") / "long.db3"
    camera = SoftwareCamera(record_to=path)
    rng = np.random.default_rng(4)
    images = [(rng.integers(300, 2000, (H, W), dtype=np.uint16),
               rng.integers(0, 256, (H, W, 3), dtype=np.uint8)) for _ in range(8)]
    for number in range(400):
        camera.push(number, *images[number % len(images)])
        if number % 50 == 49:
            camera.framesets()  # drain the syncer as a real consumer would
    camera.framesets()
    camera.close()
    return path


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_during_record_from_file_keeps_frames(tmp_path, db3_file, sig):
    output = tmp_path / "rec.mcap"
    command = [sys.executable, "-c", THROTTLED_CLI, "record", "--from", str(db3_file), "-o"]
    # a 64x48 frame is ~15 kB: wait for about 10 frames
    _, stderr = run_and_signal([*command, str(output)], output, sig, 150_000)
    frames = read_clean(output)
    assert 0 < len(frames) < 400
    flat = " ".join(stderr.split())
    assert f"wrote {output}: {len(frames)} frames" in flat
    name = "SIGTERM" if sig == signal.SIGTERM else "Ctrl-C"
    assert f"stopped by {name}" in flat


def test_signal_before_any_frame_writes_nothing(tmp_path, long_scenario):
    """Stopped during the first solve: no recording, no truth file, no temporary file."""
    output = tmp_path / "early.mcap"
    process = subprocess.Popen(
        [sys.executable, "-m", "softforce_cli", "simulate", str(long_scenario), "-o", str(output)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".early.mcap.*.tmp")) and time.monotonic() < deadline:
        time.sleep(0.01)  # the writer opens its temporary file before the first solve
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.toml"]


def _recording(folder: Path) -> None:
    mcap_writer.RecordingWriter(folder / "rec.mcap")


def _atomic_text(folder: Path) -> None:
    with atomic.atomic_open(folder / "out.json") as handle:
        handle.write("{}")


@pytest.mark.parametrize("write", [_recording, _atomic_text])
def test_a_signal_as_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch, write):
    """SIGTERM right after an output's temporary file appeared (the moment the test above
    signals at; once in many runs it landed before the writer held the file, and the file
    stayed): the writer still deletes it, and the signal stops the run. For a recording and
    for any atomically written file."""
    previous = signal.getsignal(signal.SIGTERM)
    install_signal_handlers()  # as the command does: SIGTERM raises Terminated
    made = tempfile.mkstemp

    def make_then_signal(*args, **kwargs):
        made_file = made(*args, **kwargs)
        signal.raise_signal(signal.SIGTERM)
        return made_file

    monkeypatch.setattr(tempfile, "mkstemp", make_then_signal)
    try:
        with pytest.raises(KeyboardInterrupt):
            write(tmp_path)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert list(tmp_path.iterdir()) == []


def test_a_signal_while_finishing_waits_for_the_finished_file(tmp_path):
    """SIGTERM arriving inside the writer's finish(): held back until the file is complete and
    renamed, then raised; the recording keeps every frame (without the hold, it was deleted)."""
    import os

    from softforce_cli.cli import interrupt
    from softforce_cli.cli.interrupt import Terminated, install_signal_handlers
    from softforce_cli.io.mcap_writer import RecordingWriter
    from tests.test_mcap import make_frames

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    install_signal_handlers()
    try:
        path = tmp_path / "rec.mcap"
        frames = make_frames(3)
        writer = RecordingWriter(path)
        for frame in frames:
            writer.write_frame(frame)
        finish = writer._writer.finish

        def finish_with_a_signal():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)  # time for the signal to be delivered, were it not held
            finish()

        writer._writer.finish = finish_with_a_signal
        with pytest.raises(Terminated):
            writer.close()
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        interrupt._received.clear()  # the SIGTERM sent here must not colour later tests
    assert len(read_clean(path)) == 3
