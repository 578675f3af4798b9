"""Fuzz: damaged copies of sample_data's recordings through `softforce record info` and the
frame reader (iter_frames, the one path every frame-reading command takes).

Damage kinds, each seeded: flipped bits anywhere, flipped bits inside the chunk data only,
truncation at any byte, chunks swapped in place (the index then points at the wrong chunks) and
a chunk's bytes overwritten with another's. Every case must end in a clean error or exit 0
(with a warning whenever a frame was lost); a damaged chunk must cost only its own frame.
"""

from __future__ import annotations

import json
import random
import warnings
from collections import Counter
from pathlib import Path

import pytest

from softforce_cli.errors import RecordingError
from softforce_cli.io.mcap_reader import RecordingWarning, iter_frames, read_summary
from tests.test_fuzz_harness import call_reader, classify, fuzz_cases, report, run_cli

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = sorted((ROOT / "sample_data" / "recordings").glob("*.mcap"))


def chunk_spans(data: bytes) -> list[tuple[int, int]]:
    """(start, end) byte ranges of the chunk records, from the (intact) file's index."""
    import io

    from mcap.reader import make_reader

    summary = make_reader(io.BytesIO(data)).get_summary()
    return [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length)
            for c in summary.chunk_indexes]


def damaged(data: bytes, kind: str, rng: random.Random) -> bytes:
    """A copy of `data` with damage of `kind`."""
    out = bytearray(data)
    spans = chunk_spans(data)
    if kind == "flip":
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
    elif kind == "flip_chunk":
        start, end = rng.choice(spans)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(start + 60, end)] ^= 1 << rng.randrange(8)
    elif kind == "truncate":
        return bytes(out[: rng.randrange(len(out))])
    elif kind == "shuffle":
        a, b = rng.sample(range(len(spans)), 2)
        (a0, a1), (b0, b1) = sorted([spans[a], spans[b]])
        return bytes(out[:a0] + out[b0:b1] + out[a1:b0] + out[a0:a1] + out[b1:])
    elif kind == "overwrite":
        (a0, a1), (b0, b1) = rng.sample(spans, 2)
        length = min(a1 - a0, b1 - b0)
        out[a0 : a0 + length] = data[b0 : b0 + length]
    return bytes(out)


KINDS = ("flip", "flip_chunk", "truncate", "shuffle", "overwrite")


@pytest.fixture(scope="module")
def originals() -> dict[str, tuple[bytes, int]]:
    """name -> (bytes, frame count) of each sample recording, read without a warning."""
    out = {}
    for path in RECORDINGS:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out[path.name] = (path.read_bytes(), len(list(iter_frames(path))))
    return out


@pytest.mark.parametrize("kind", KINDS)
def test_damaged_recordings_never_crash(tmp_path, originals, kind):
    counts = Counter()
    rng = random.Random(f"recording-{kind}")
    for case in range(fuzz_cases(20)):
        name = RECORDINGS[case % len(RECORDINGS)].name
        data, _ = originals[name]
        path = tmp_path / f"{case}-{name}"
        path.write_bytes(damaged(data, kind, rng))
        outcome = classify(run_cli("record", "info", path, "--json"))
        counts[f"info {outcome}"] += 1
        counts[f"frames {call_reader(lambda p: list(iter_frames(p)), path)}"] += 1
        path.unlink()
    report(f"recording ({kind})", counts)
    assert sum(counts.values()) == 2 * fuzz_cases(20)


def test_a_damaged_chunk_costs_exactly_its_frame(tmp_path, originals):
    """Bits flipped in one chunk's compressed data: that frame is skipped, every other one is
    read, identical to the original, and the warning counts 1 frame."""
    name = "weights.mcap"
    data, count = originals[name]
    spans = chunk_spans(data)
    reference = list(iter_frames(RECORDINGS[[p.name for p in RECORDINGS].index(name)]))
    for lost in (0, len(spans) // 2, len(spans) - 1):
        start, end = spans[lost]
        broken = bytearray(data)
        broken[(start + end) // 2] ^= 0x10
        path = tmp_path / f"lost{lost}.mcap"
        path.write_bytes(bytes(broken))
        with pytest.warns(RecordingWarning, match=r"skipped 1 frame\(s\) in 1 damaged chunk"):
            frames = list(iter_frames(path))
        kept = [f for i, f in enumerate(reference) if i != lost]
        assert [f.time_ns for f in frames] == [f.time_ns for f in kept]
        for got, want in zip(frames, kept, strict=True):
            assert (got.color == want.color).all() and (got.depth_mm == want.depth_mm).all()
        with pytest.warns(RecordingWarning, match="skipped 1 frame"):
            assert read_summary(path).frame_count == count - 1
        outcome = run_cli("record", "info", path, "--json")
        assert classify(outcome) == "warning" and f'"frames": {count - 1}' in outcome.stdout


def test_damaged_index_falls_back_to_a_scan_that_keeps_every_frame(tmp_path, originals):
    """A flipped byte in the summary section: its CRC fails, the file is scanned, nothing lost."""
    data, count = originals["probes.mcap"]
    summary_start = int.from_bytes(data[-28:-20], "little")  # the footer's summary_start
    broken = bytearray(data)
    broken[summary_start + 40] ^= 0x01
    path = tmp_path / "index.mcap"
    path.write_bytes(bytes(broken))
    with pytest.warns(RecordingWarning, match="damaged index"):
        assert len(list(iter_frames(path))) == count


def test_every_chunk_damaged_is_one_clean_error(tmp_path, originals):
    data, _ = originals["probes.mcap"]
    broken = bytearray(data)
    for start, end in chunk_spans(data):
        broken[(start + end) // 2] ^= 0xFF
    path = tmp_path / "all.mcap"
    path.write_bytes(bytes(broken))
    with pytest.warns(RecordingWarning, match="skipped 4 frame"), pytest.raises(
        RecordingError, match="holds no readable frame"
    ):
        list(iter_frames(path))
    outcome = run_cli("record", "info", path)
    assert classify(outcome) == "error" and "warning:" in outcome.stderr


def test_sample_data_is_untouched():
    """The fuzz works on copies: the sample recordings still read without any warning."""
    for path in RECORDINGS:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            read_summary(path)


def test_the_reported_bug_as_a_user_meets_it(tmp_path, originals):
    """Issue 12: a few flipped bytes in a sample recording made `softforce record info` end in
    zstandard's "Data corruption detected" traceback. As a subprocess, like a user's shell."""
    import subprocess
    import sys

    data, count = originals["probes.mcap"]
    spans = chunk_spans(data)
    cases = {"flipped": bytearray(data), "cut": bytearray(data[: len(data) * 2 // 3]),
             "all chunks": bytearray(data)}
    for offset in (1000, 2000, 3000):
        cases["flipped"][spans[1][0] + offset] ^= 0xFF
    for start, end in spans:
        cases["all chunks"][(start + end) // 2] ^= 0xFF
    for name, broken in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.mcap"
        path.write_bytes(bytes(broken))
        result = subprocess.run(
            [sys.executable, "-m", "softforce_cli", "record", "info", path, "--json"],
            capture_output=True, text=True, timeout=60,
        )
        assert "Traceback" not in result.stderr, result.stderr
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        if name == "all chunks":
            assert result.returncode == 1 and lines[-1].startswith("error:")
            assert "holds no readable frame" in lines[-1]
        else:
            assert result.returncode == 0, result.stderr
            assert all(line.startswith("warning:") for line in lines) and lines
            whole_chunks = sum(end <= len(broken) for _, end in spans)
            expected = count - 1 if name == "flipped" else whole_chunks  # one frame a chunk
            assert json.loads(result.stdout)["frames"] == expected


def test_swapped_chunks_are_found_by_their_times(tmp_path, originals):
    """Two chunks swapped in place (the index now points at the wrong bytes): each is found by
    its time range, every frame is read in time order, identical, and the move is warned."""
    data, _ = originals["weights.mcap"]
    path = tmp_path / "swapped.mcap"
    path.write_bytes(damaged(data, "shuffle", random.Random(7)))
    reference = list(iter_frames(RECORDINGS[[p.name for p in RECORDINGS].index("weights.mcap")]))
    with pytest.warns(RecordingWarning, match="not where the index says"):
        frames = list(iter_frames(path))
    assert [f.time_ns for f in frames] == [f.time_ns for f in reference]
    for got, want in zip(frames, reference, strict=True):
        assert (got.color == want.color).all() and (got.depth_mm == want.depth_mm).all()
