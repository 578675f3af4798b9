"""Which part of the estimator's model makes it misread the probes: the mesh or the law.

    OPENBLAS_NUM_THREADS=1 python benchmarks/intensity_law_check.py   # ~3 min

The perfect-observation check of tests/test_intensity_truth.py (the sample probes' truth at
the estimator's feature points, the contact at the true point, the push along the probe's
axis: no camera, no contact detection) run with four estimators, P2 with 151 features each:
the sample's coarse mesh or the truth's own 6.5 mm mesh, with the corotational law (the
sample robot's) or the truth's Neo-Hookean one. The last (the truth's mesh and law) is the
truth's own model: it checks the method itself (an inverse crime on purpose), and the other
three say how much the mesh and the law each cost. docs/sensing_studies.md ("The material law")
quotes the table; out/intensity_law_check/results.json keeps it.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from intensity_fixture import ESTIMATOR, fixture_document  # noqa: E402

from softforce_cli.io.atomic import atomic_write_text  # noqa: E402
from tests.test_intensity_truth import sense_perfect_observations  # noqa: E402

OUT = ROOT / "out" / "intensity_law_check"
TRUTH_MESH_ROBOT = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
LAWS = ("corotational", "neo-hookean")


def variant(source: Path, law: str, name: str) -> Path:
    """source's robot file with the given law, 151 features and its mesh path made absolute,
    written under OUT."""
    text = source.read_text()
    mesh = re.search(r'^path = "(.+)"$', text, flags=re.M)
    text = text.replace(mesh.group(0), f'path = "{(source.parent / mesh.group(1)).resolve()}"')
    text = re.sub(r'^law = ".+"$', f'law = "{law}"', text, flags=re.M)
    text = re.sub(r"^count = \d+$", "count = 151", text, flags=re.M)
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{name}.toml"
    path.write_text(text)
    return path


def main() -> None:
    rows = []
    for mesh, source in (("coarse (the sample's)", ESTIMATOR), ("the truth's", TRUTH_MESH_ROBOT)):
        for law in LAWS:
            name = f"{'coarse' if source == ESTIMATOR else 'truth_mesh'}_{law}"
            document = fixture_document(variant(source, law, name))
            results = sense_perfect_observations(document)
            rows.append({"mesh": mesh, "law": law,
                         "estimated_n": [[round(float(v), 3) for v in e] for e, _ in results],
                         "true_n": [[round(float(v), 3) for v in t] for _, t in results]})
            print(f"{mesh:22s} {law:13s} " + "  ".join(
                " + ".join(f"{v:.3f}" for v in e) for e in rows[-1]["estimated_n"]), flush=True)
    atomic_write_text(OUT / "results.json", json.dumps(rows, indent=1), force=True)


if __name__ == "__main__":
    main()
