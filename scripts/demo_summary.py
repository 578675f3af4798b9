"""The end of `make demo`: what it wrote, and its results scored against the truth files.

The truth sidecars of the sample recordings are read here only, after the tool has run, to
say how close it came (they are never inputs of the tool).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from softforce_cli.estimation.truth_errors import compare_with_truth, read_truth

RECORDINGS = Path("sample_data/recordings")


def main(out: Path) -> None:
    calibration = json.loads((out / "calibration_material.json").read_text())
    print(f"calibration: residual {calibration['residual_rms_mm']:.2f} mm RMS over the "
          f"markers; Young's modulus {calibration['material']['young_modulus_mpa']:.4f} MPa "
          "(truth body: 0.18 MPa, Neo-Hookean)")
    sense = json.loads((out / "sense" / "sense.json").read_text())
    scores = compare_with_truth(sense, read_truth(RECORDINGS / "probes.truth.json")).summary()
    print(f"sensing on probes.mcap: {scores['located']} of {scores['true_contacts']} true "
          f"contacts located (median {scores['location_error_median_mm']} mm), intensity "
          f"error median {_percent(scores['intensity_error_median'])}, 90th percentile "
          f"{_percent(scores['intensity_error_p90'])}, {scores['phantoms']} phantom contacts")
    diagnosis = json.loads((out / "diagnose" / "diagnosis.json").read_text())
    concealed = read_truth(RECORDINGS / "diagnose_slack.truth.json").get("concealed_effects", [])
    print(f"diagnosis of diagnose_slack.mcap: verdict '{diagnosis['verdict']}'; concealed: "
          + ", ".join(_effect(e) for e in concealed))
    for effect in diagnosis["effects"][:1]:
        fitted = ", ".join(f"{name} {p['value']:.3g} {p['unit']} (95% {p['ci95'][0]:.3g}-"
                           f"{p['ci95'][1]:.3g})" for name, p in effect["parameters"].items())
        print(f"  fitted {effect['name']}: {fitted}; held-out residual "
              f"{effect['heldout_rms_before_mm']:.2f} -> {effect['heldout_rms_after_mm']:.2f} mm")
    print("\nwritten:")
    for path in sorted(out.rglob("*")):
        if path.is_file():
            print(f"  {path}")


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.0f}%"


def _effect(effect: dict) -> str:
    values = ", ".join(f"{name} {p['value']} {p['unit']}"
                       for name, p in effect.get("parameters", {}).items())
    target = f" on {effect['target']}" if effect.get("target") else ""
    return f"{effect['name']}{target} ({values})"


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "out/demo"))
