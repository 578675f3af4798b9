"""Why diagnose screens the law blend on its secant for the linear law only (diagnosis.solves,
SECANT_LAWS; docs/diagnosis.md, method 4): at one state of the coarse Diamond with P2
elements, the blend's first-order column (the tangent) against the exact change to the other
law (two solves), for the corotational and the small-strain linear law: correlation and
length ratio over the mesh nodes.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/law_blend_check.py [--north 6]
"""

from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np

from softforce_cli.diagnosis.sensitivities import column_set, state_columns
from softforce_cli.diagnosis.solves import SETTINGS, accurate_robot
from softforce_cli.fem.compliance import linearize
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import make_effect
from softforce_cli.model.robot import load_robot

ROBOT = Path(__file__).resolve().parents[1] / "sample_data" / "diamond" / "diamond.toml"


def robot_with_law(law: str, folder: Path):
    """The sample robot (P2 on its mesh, as diagnose predicts with) with `law`."""
    text = ROBOT.read_text()
    mesh = re.search(r'^path = "(.*)"$', text, re.MULTILINE)
    text = re.sub(r'^law = ".*"$', f'law = "{law}"', text, flags=re.MULTILINE).replace(
        mesh.group(0), f'path = "{(ROBOT.parent / mesh.group(1)).resolve()}"')
    path = folder / f"diamond_{law}.toml"
    path.write_text(text)
    return accurate_robot(load_robot(path))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--north", type=float, default=6.0, help="north cable, mm")
    args = parser.parse_args()
    actuation = np.array([args.north, 0.0, 0.0, 0.0])
    with tempfile.TemporaryDirectory() as folder:
        for law in ("corotational", "linear"):
            robot = robot_with_law(law, Path(folder))
            model = robot.nominal_fe_model
            inputs = robot.cable_inputs(actuation)
            nominal = solve_equilibrium(model, inputs, settings=SETTINGS)
            other = fe_model_with_effects(robot, (make_effect("material_nonlinearity",
                                                              blend=1.0),))
            switched = solve_equilibrium(other, inputs, start_mm=nominal.positions_mm,
                                         settings=SETTINGS)
            columns = column_set(robot)
            lin = linearize(model, nominal.positions_mm, nominal.cable_tensions_n)
            tangent = state_columns(robot, columns, lin, nominal.cable_tensions_n)[
                columns.index("blend")]
            n = robot.mesh.node_count
            exact = (switched.positions_mm - nominal.positions_mm)[:n].ravel()
            first = tangent[:n].ravel()
            correlation = first @ exact / np.linalg.norm(first) / np.linalg.norm(exact)
            rms = np.sqrt(np.mean(np.sum((exact.reshape(-1, 3)) ** 2, axis=1)))
            print(f"{law}: exact change {rms:.2f} mm RMS; tangent correlation "
                  f"{correlation:.3f}, length ratio "
                  f"{np.linalg.norm(first) / np.linalg.norm(exact):.2f}", flush=True)


if __name__ == "__main__":
    main()
