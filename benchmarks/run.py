"""Run every benchmark and rewrite docs/benchmarks.md (machine, command, medians)."""

from __future__ import annotations

import argparse
import datetime
import importlib
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.timing import BenchRow
from softforce_cli.fem.allocator import keep_freed_memory

# Each module exposes run() -> list[BenchRow].
MODULES = ["benchmarks.bench_fem", "benchmarks.bench_calibration", "benchmarks.bench_recording",
           "benchmarks.bench_memory", "benchmarks.bench_reduced", "benchmarks.bench_sense",
           "benchmarks.bench_diagnose", "benchmarks.bench_occluded"]


def machine() -> str:
    cpu = platform.processor() or "unknown CPU"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                 if line.startswith("model name")]
        cpu = names[0] if names else cpu
    memory = ""
    meminfo = Path("/proc/meminfo")
    if meminfo.exists():
        total_kb = int(meminfo.read_text().split()[1])
        memory = f", {total_kb / 2**20:.0f} GiB RAM"
    import numpy
    import scipy

    return (f"{cpu}, {os.cpu_count()} cores{memory}; Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, scipy {scipy.__version__}")


def render(rows: list[BenchRow]) -> str:
    lines = [
        "# Benchmarks",
        "",
        "Written by `make bench` (`python benchmarks/run.py`); do not edit by hand.",
        "Figures are medians of repeated runs on a shared, noisy 2-core machine: compare",
        "ratios, not the last digit.",
        "",
        f"- date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC",
        f"- machine: {machine()}",
        "- command: `make bench`",
        "",
        "| benchmark | median | repeats | result | target | notes |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(f"| {row.name} | {row.median_s * 1e3:.1f} ms | {row.repeats} | "
                     f"{row.result} | {row.target} | {row.notes} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--output", type=Path, default=Path("docs/benchmarks.md"))
    parser.add_argument("--only", help="run only modules whose name contains this")
    args = parser.parse_args()
    keep_freed_memory()
    rows: list[BenchRow] = []
    for name in MODULES:
        if args.only and args.only not in name:
            continue
        print(f"running {name} ...", file=sys.stderr)
        rows.extend(importlib.import_module(name).run())
    text = render(rows)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
