"""Memory against recording length: peak RSS of writing, reading and `record info`.

A recording of 10 minutes at 30 fps (18,000 frames) and shorter ones are made by streaming
synthetic frames into write_recording (nothing is stored in the repository), then read back
frame by frame with iter_frames and summarised by `softforce record info`. Each measurement
runs in a fresh process, so that its peak resident set size (ru_maxrss) is its own; the
baseline is the same process's RSS after its imports, before any frame. Memory is flat when
the peak does not grow with the number of frames.

Frames are 160x120 (not the D415's 640x480) to keep the 10-minute recording to a minute of
writing on a shared machine; they are smooth moving gradients with a noisy 16x16 patch, which
compress to a few kB (real frames compress less: the file is smaller, not the buffers).
Per-frame buffers are ~16x smaller than at 640x480, so the absolute figures are small; what
the benchmark shows is the ratio between lengths.

    python benchmarks/bench_memory.py           # prints the table
    python benchmarks/run.py --only memory      # the same, into docs/benchmarks.md
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.timing import BenchRow  # noqa: E402

FPS = 30
LENGTHS_S = (60, 180, 600)  # 1, 3 and 10 minutes
WIDTH, HEIGHT = 160, 120


def _rss_mb() -> float:
    """Peak RSS of this process so far, MB (Linux reports kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _current_rss_mb() -> float:
    with open("/proc/self/statm") as handle:
        pages = int(handle.read().split()[1])
    return pages * resource.getpagesize() / 2**20


def synthetic_frames(count: int):
    """`count` 160x120 frames at 30 fps, made one at a time (never held together)."""
    import numpy as np

    from softforce_cli.camera.frame import Actuation, RgbdFrame
    from softforce_cli.camera.intrinsics import CameraIntrinsics

    intrinsics = CameraIntrinsics.from_fov(WIDTH, HEIGHT, 69.0)
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    for index in range(count):
        shade = (rows + cols + index) % 256
        color = np.stack([shade, (shade + 85) % 256, (shade + 170) % 256], axis=2)
        color = color.astype(np.uint8)
        depth = (500 + rows + (index % 50)).astype(np.uint16)
        # sensor noise on a patch: enough to make every frame's bytes differ, little enough
        # to keep the 10-minute file small
        color[:16, :16] = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
        depth[:16, :16] = rng.integers(400, 600, (16, 16), dtype=np.uint16)
        yield RgbdFrame(
            time_ns=round(index * 1e9 / FPS),
            color=color,
            depth_mm=depth,
            intrinsics=intrinsics,
            actuation=Actuation(("north", "west"), "displacement", np.array([index % 7, 1.0])),
        )


def worker(task: str, path: Path, count: int) -> dict:
    """One measurement in this (fresh) process: write, read or info; returns its figures."""
    from softforce_cli.cli import record_commands  # noqa: F401 (imported before the baseline)
    from softforce_cli.cli.main import _register_commands, main
    from softforce_cli.io.mcap_reader import iter_frames
    from softforce_cli.io.mcap_writer import write_recording

    _register_commands()
    baseline = _current_rss_mb()
    started = time.perf_counter()
    if task == "write":
        result = write_recording(synthetic_frames(count), path, force=True)
        frames = result.frames
    elif task == "read":
        frames = sum(1 for _ in iter_frames(path))
    else:
        sys.argv = ["softforce", "record", "info", str(path), "--json"]
        try:
            main()
        except SystemExit as exit_:
            if exit_.code:
                raise
        frames = count
    return {"baseline_mb": baseline, "peak_mb": _rss_mb(), "frames": frames,
            "seconds": time.perf_counter() - started}


def measure(task: str, path: Path, count: int) -> dict:
    process = subprocess.run(
        [sys.executable, __file__, "--worker", task, str(path), str(count)],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )
    return json.loads(process.stdout.strip().splitlines()[-1])


def run() -> list[BenchRow]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        figures: dict[str, list[tuple[int, dict]]] = {"write": [], "read": [], "info": []}
        for seconds in LENGTHS_S:
            count = seconds * FPS
            path = Path(folder) / f"long{seconds}.mcap"
            for task in ("write", "read", "info"):
                figure = measure(task, path, count)
                assert figure["frames"] == count, figure
                figures[task].append((count, figure))
            size_mb = path.stat().st_size / 1e6
            path.unlink()
        for task, results in figures.items():
            (short_n, short), (long_n, long) = results[0], results[-1]
            growth = [f"{n} frames: {f['peak_mb']:.0f} MB ({f['peak_mb'] - f['baseline_mb']:+.0f})"
                      for n, f in results]
            rows.append(BenchRow(
                name=f"memory, {task} ({WIDTH}x{HEIGHT}, {long_n} frames vs {short_n})",
                median_s=long["seconds"],
                repeats=1,
                target="flat: ratio ~1",
                result=f"peak RSS ratio {long['peak_mb'] / short['peak_mb']:.2f}",
                notes="; ".join(growth) + f" (peak RSS, its rise over the process's RSS after "
                      f"imports in brackets); the {long_n}-frame file is {size_mb:.0f} MB",
            ))
    return rows


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--worker":
        print(json.dumps(worker(sys.argv[2], Path(sys.argv[3]), int(sys.argv[4]))))
    else:
        for row in run():
            print(f"{row.name}: {row.result}; {row.median_s:.1f} s; {row.notes}")
