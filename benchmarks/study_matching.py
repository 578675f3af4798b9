"""Sensing's accuracy over eleven of the studies' recordings, for one settings file or more.

    python benchmarks/study_matching.py [SETTINGS.toml ...]   # about 5 minutes a file

One settings change can help the 12-location probes and hurt another camera or another
actuation; this runs `benchmarks/study_sensing.py` (each recording simulated once, sensed
with the truth's camera pose, tared on its first 3 frames) on the 12-location probes at
640x480, on the converged body, at 424x240 and 1280x720, and on the scenarios of
benchmarks/scenarios/, once with the defaults (no argument) or once per settings file
(docs/sensing.md, "Settings"), and prints a markdown table of the intensity error (median /
90th percentile) with the sum of the medians: docs/sensing_studies.md ("Averaging the
matched points, with edge-on features hidden") is such a table. Recordings and outputs are
those of study_sensing.py (out/study_sensing/, out/study_sensing_converged/).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ESTIMATOR = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
SCENARIOS = ROOT / "benchmarks" / "scenarios"
# (label, study_sensing.py's arguments, whether its JSON nests the result under "probes")
RECORDINGS = (
    ("12-location probes, 640x480", ["--probes-only"], True),
    ("the same on the converged body", ["--probes-only", "--converged"], True),
    ("12 locations at 424x240", ["--probes-only", "--width", "424", "--height", "240"], True),
    ("12 locations at 1280x720", ["--probes-only", "--width", "1280", "--height", "720"], True),
    *((name.replace("_", " "), ["--scenario", str(SCENARIOS / f"{name}.toml")], False)
      for name in ("other_actuation", "other_actuation_424", "far_camera", "many_contacts",
                   "large_deformation", "oblique_camera", "hidden_contacts")),
)


def sensed(arguments: list[str], settings: Path | None) -> dict:
    """One study_sensing.py run -> its comparison with the truth (truth_errors' summary)."""
    command = [sys.executable, str(ROOT / "benchmarks" / "study_sensing.py"),
               "--robot", str(ESTIMATOR), *arguments]
    if settings is not None:
        command += ["--settings", str(settings)]
    run = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(run.stdout)


def cell(result: dict) -> str:
    median, p90 = 100 * result["intensity_error_median"], 100 * result["intensity_error_p90"]
    located = f"{result['located']}/{result['true_contacts']}"
    return f"{median:.1f}% / {p90:.1f}% ({located})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("settings", type=Path, nargs="*",
                        help="settings files (docs/sensing.md); none: the defaults")
    args = parser.parse_args()
    columns = args.settings or [None]
    rows, sums = [], [0.0] * len(columns)
    for label, arguments, nested in RECORDINGS:
        cells = []
        for k, settings in enumerate(columns):
            document = sensed(arguments, settings)
            result = document["probes"] if nested else document
            sums[k] += 100 * result["intensity_error_median"]
            cells.append(cell(result))
            print(f"{label}, {settings or 'defaults'}: {cells[-1]}", file=sys.stderr, flush=True)
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    names = [("defaults" if s is None else s.stem) for s in columns]
    print("| recording | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(columns))
    print("\n".join(rows))
    print("| sum of the medians | " + " | ".join(f"{s:.1f}%" for s in sums) + " |")


if __name__ == "__main__":
    main()
