"""SIGINT and SIGTERM in the middle of `softforce sense`: whole frames kept, valid files."""

from __future__ import annotations

import csv
import dataclasses
import json
import signal
import subprocess
import sys
import time

import pytest

from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.io.mcap_writer import write_recording
from tests.conftest import ROOT, SAMPLE_ROBOT
from tests.test_sense_cli import PROBES, pose_calibration

EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory):
    """The probes recording played 15 times over (60 frames: seconds of sensing)."""
    folder = tmp_path_factory.mktemp("long")
    frames = list(iter_frames(PROBES))
    path = folder / "long.mcap"
    write_recording((dataclasses.replace(frames[i % len(frames)], time_ns=i * 33_333_333)
                     for i in range(60)), path)
    return path, pose_calibration(PROBES.with_suffix("").with_suffix(".truth.json"), folder)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_sense_keeps_whole_frames(tmp_path, long_recording, sig):
    recording, calibration = long_recording
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "softforce_cli", "sense", str(recording), "--robot",
         str(SAMPLE_ROBOT), "--calibration", str(calibration), "-o", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        frames_csv = out / "frames.csv"
        if frames_csv.exists() and len(frames_csv.read_text().splitlines()) >= 4:
            process.send_signal(sig)
            break
        time.sleep(0.02)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == EXIT_STATUS[sig], stderr
    assert "Traceback" not in stderr
    assert "interrupted" in stderr and str(out) in stderr
    rows = list(csv.reader((out / "frames.csv").read_text().splitlines()))[1:]
    document = json.loads((out / "sense.json").read_text())
    assert 3 <= len(rows) < 60
    assert [int(r[0]) for r in rows] == [f["frame"] for f in document["frames"]]
    assert document["summary"]["interrupted"] is True
    assert document["summary"]["frames"] == len(rows)
    contacts = list(csv.reader((out / "contacts.csv").read_text().splitlines()))[1:]
    assert all(int(r[0]) <= int(rows[-1][0]) for r in contacts)


def test_an_unreadable_frame_ends_sense_with_the_frames_before_it(tmp_path, long_recording):
    """A frame the reader refuses (an actuation value that is NaN) ends the run with one
    error line that says where the frames before it are; sense.json's summary keeps that
    line, so the files do not read as the whole recording (they had said nothing)."""
    _, calibration = long_recording
    frames = list(iter_frames(PROBES))
    broken = frames[2].actuation
    frames[2] = dataclasses.replace(frames[2], actuation=dataclasses.replace(
        broken, values=broken.values * float("nan")))
    recording = tmp_path / "nan.mcap"
    write_recording(frames, recording)
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "softforce_cli", "sense", str(recording), "--robot",
         str(SAMPLE_ROBOT), "--calibration", str(calibration), "-o", str(out)],
        capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error:") and "not a finite number" in last
    assert f"the 2 frame(s) processed before it are in {out}" in last
    summary = json.loads((out / "sense.json").read_text())["summary"]
    assert summary["frames"] == 2 and "not a finite number" in summary["error"]
    assert len((out / "frames.csv").read_text().splitlines()) == 3
