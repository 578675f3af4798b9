"""FE engine speed on the coarse default robot (issues: foundation; 5, quadratic elements).

One "update" is what a sensing frame costs: corotational K(x) at the current configuration,
its factorisation, and the compliance matrices for 51 normal effectors, 4 cables and 2 force
points, with the free displacements (paper eq. 3-6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.timing import BenchRow, median_time, peak_memory_mb
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.compliance import compliance, effector_rows, force_rows, linearize
from softforce_cli.fem.linear_solver import Factorization
from softforce_cli.fem.statics import Equilibrium, solve_equilibrium
from softforce_cli.model.config import load_config
from softforce_cli.model.mesh_io import read_tet_mesh
from softforce_cli.model.robot import Robot, build_robot, load_robot

ROOT = Path(__file__).resolve().parents[1]
COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
TRUTH = ROOT / "sample_data" / "diamond_truth" / "diamond.toml"
ACTUATION = np.array([5.0, 5.0, 0.0, 0.0])


def robot_with_element(path: Path, element: str) -> Robot:
    """The robot of a file with its `[mesh] element` replaced."""
    config = load_config(path)
    config = dataclasses.replace(config, mesh=dataclasses.replace(config.mesh, element=element))
    spec = config.mesh
    return build_robot(config, read_tet_mesh(spec.path, spec.scale, spec.rotation_deg,
                                              spec.translation_mm))


def sensing_update(robot: Robot) -> tuple[Callable[[], None], Equilibrium]:
    """One sensing frame's FE work at the equilibrium for ACTUATION, as a callable: K(x), its
    factorisation (symbolic analysis reused), W for 51 normal effectors, 4 cables, 2 forces."""
    model = robot.fe_model
    equilibrium = solve_equilibrium(model, robot.cable_inputs(ACTUATION))
    features = Attachment.at_nodes(robot.feature_nodes)
    effectors = effector_rows(features, model.node_count, robot.feature_normals)
    contacts = np.array([0, len(robot.feature_nodes) // 2])
    forces = force_rows(features.subset(contacts), robot.feature_normals[contacts],
                        model.node_count)
    x, tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
    state = {"lin": linearize(model, x, tensions)}

    def update() -> None:
        state["lin"] = linearize(model, x, tensions, factorization=state["lin"].factorization)
        compliance(state["lin"], effectors, forces)

    return update, equilibrium


def update_timing(element: str, repeats: int, robot: Robot | None = None
                  ) -> tuple[float, float, float, Robot]:
    """Median seconds of one update, of its K assembly and of its factorisation, on the
    coarse default robot with `element` (or on `robot`), at the equilibrium for ACTUATION."""
    robot = robot_with_element(COARSE, element) if robot is None else robot
    model = robot.fe_model
    update, equilibrium = sensing_update(robot)
    update()
    x = equilibrium.positions_mm
    _, stiffness = model.internal_forces_and_stiffness(x)
    factor = Factorization(stiffness)
    return (median_time(update, repeats=repeats, warmup=1),
            median_time(lambda: model.internal_forces_and_stiffness(x), repeats=repeats),
            median_time(lambda: factor.refactor(stiffness), repeats=repeats), robot)


def element_rows(elements: tuple[str, ...] = ("p2", "p2-p0"), repeats: int = 5
                 ) -> list[BenchRow]:
    """The update of `run` with quadratic elements on the same coarse mesh."""
    rows = []
    for element in elements:
        update_s, assemble_s, factor_s, robot = update_timing(element, repeats)
        dofs = len(robot.fe_model.free_dofs)
        rows.append(BenchRow(
            f"FE update, element = {element!r} (same mesh, 51 normals + 4 cables + 2 forces)",
            update_s, repeats, ">= 50 Hz (p1 default)", f"{1 / update_s:.1f} Hz",
            f"{robot.mesh.tet_count} tets, {dofs} dofs; K {assemble_s * 1e3:.0f} ms, "
            f"factorisation {factor_s * 1e3:.0f} ms (CHOLMOD)"))
    return rows


def run() -> list[BenchRow]:
    robot = load_robot(COARSE)
    model = robot.fe_model
    update, equilibrium = sensing_update(robot)

    def assemble() -> None:
        model.internal_forces_and_stiffness(equilibrium.positions_mm)

    update_s = median_time(update, repeats=40, warmup=3)
    assemble_s = median_time(assemble, repeats=40)
    update_mb = peak_memory_mb(update)
    sizes = f"{robot.mesh.tet_count} tets, {len(model.free_dofs)} dofs"
    rows = [
        BenchRow("FE update (K, factorise, W for 51 normals + 4 cables + 2 forces)", update_s,
                 40, ">= 50 Hz", f"{1 / update_s:.0f} Hz",
                 f"{sizes}; peak {update_mb:.0f} MB; paper: 7 Hz (51 features, 4884 tets)"),
        BenchRow("  of which corotational forces + tangent assembly", assemble_s, 40, "",
                 f"{assemble_s * 1e3:.1f} ms", "vectorised over elements, one bincount"),
    ]
    inputs = robot.cable_inputs(ACTUATION)
    solve_s = median_time(lambda: solve_equilibrium(model, inputs), repeats=5)
    solve_mb = peak_memory_mb(lambda: solve_equilibrium(model, inputs))
    rows.append(BenchRow("Nonlinear static solve from rest, cables 5,5,0,0 mm + gravity",
                         solve_s, 5, "< 0.5 s", f"{solve_s:.2f} s",
                         f"{sizes}; {equilibrium.iterations} Newton iterations; "
                         f"peak {solve_mb:.0f} MB"))
    truth = load_robot(TRUTH)
    truth_inputs = truth.cable_inputs(ACTUATION)
    truth_s = median_time(lambda: solve_equilibrium(truth.fe_model, truth_inputs), repeats=3,
                          warmup=0)
    rows.append(BenchRow("Nonlinear static solve, ground truth of `simulate` (P2)", truth_s, 3,
                         "", f"{truth_s:.2f} s",
                         f"{truth.mesh.tet_count} tets, {len(truth.fe_model.free_dofs)} dofs"))
    return rows + element_rows()
