"""The reduced-order model of the quadratic element on the coarse default robot (issue 9).

Rows: training time; one sensing update (reduced tangent, its factorisation, W for 51 normal
effectors + 4 cables + 2 forces, free motion) through the unchanged fem.compliance seam;
static solves; calibration from 9 markers; the accuracy against the full P2 model on
untrained load cases; and the update and accuracy of the same basis sampled for speed
(FAST_SETTINGS, ECSW 3e-2). Each reduced model is trained once and cached in
out/bench_reduced/ (diamond_p2.rom.npz, diamond_p2_fast.rom.npz: delete one to retrain it);
alone, this script prints the rows and writes the accuracy plot:

    .venv/bin/python benchmarks/bench_reduced.py [--study] [--tangent] [--solve] [--capacity]
        [--starts] [--sensitivity]

--study also sweeps the basis size and the ECSW tolerance on the cached snapshots, senses
benchmarks/bench_sense.py's probe recording through each model, and writes
docs/figures/reduced_model_accuracy.png (about 45 minutes). --tangent times the ways of
forming the reduced tangent against each other in this process, interleaved (medians), and
the float32 tangent's effect on W (docs/reduced_model_history.md, "The update's floor").
--solve times the pieces of a reduced static solve's Newton iteration in turn, and the
compliance's cable rows now and as formed before. --capacity measures W at the loaded
cases against the basis size alone (200, 280 and 400 modes, integrated exactly; a few
minutes), then 280 modes hyper-reduced as the bench trains them, with their update (7
minutes more). --starts compares static solves given no start (the nearest start
equilibrium moved to first order: the training equilibria and the grid, or the training
equilibria alone) with solves from rest at 16 random actuations (a minute). --sensitivity
sets the reduced model's W error at the loaded cases beside how far the full model's own W
moves when the force, a cable or the contact point moves by what sensing cannot pin down
(a minute).
"""

from __future__ import annotations

import dataclasses
import pickle
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.timing import BenchRow, median_time  # noqa: E402
from softforce_cli.calibration.calibrate import calibrate  # noqa: E402
from softforce_cli.calibration.synthetic import observed_markers, paper_transform  # noqa: E402
from softforce_cli.errors import SolverError  # noqa: E402
from softforce_cli.estimation.sensing import tangent_basis  # noqa: E402
from softforce_cli.fem.attachment import Attachment  # noqa: E402
from softforce_cli.fem.compliance import (  # noqa: E402
    compliance,
    effector_rows,
    force_rows,
    linearize,
    linearize_state,
)
from softforce_cli.fem.element import deformation_gradients  # noqa: E402
from softforce_cli.fem.model import FEModel  # noqa: E402
from softforce_cli.fem.reduction.accuracy import (  # noqa: E402
    CaseErrors,
    CaseResult,
    LoadCase,
    between_features,
    compare,
    held_cables,
    respond,
)
from softforce_cli.fem.reduction.reduced_model import (  # noqa: E402
    ReducedCoordinates,
    TrainingBox,
)
from softforce_cli.fem.reduction.rom_file import save_reduction  # noqa: E402
from softforce_cli.fem.reduction.tangent import plain_tangent  # noqa: E402
from softforce_cli.fem.reduction.train import TrainingSettings, train_robot  # noqa: E402
from softforce_cli.fem.statics import Equilibrium, solve_equilibrium  # noqa: E402
from softforce_cli.model.robot import Robot, load_robot, with_element  # noqa: E402

COARSE = ROOT / "sample_data" / "diamond" / "diamond.toml"
CACHE = ROOT / "out" / "bench_reduced"
ACTUATION = np.array([5.0, 5.0, 0.0, 0.0])
CALIBRATION_MM = np.array([6.0, 2.0, 4.0, 9.0])
# where the sensing bench's probe touches the north bar (rest, mm)
PROBE_MM = np.array([0.0, 45.0, 90.0])
FIGURE = ROOT / "docs" / "figures" / "reduced_model_accuracy.png"
# Cables over 0-10 mm (the sensing and calibration cases use up to 9 mm): the file's 20 mm
# with the other cables held folds the p2 Diamond beyond a quick Newton solve. ECSW to 1e-2
# (in the energy norm): on the Diamond the sampling's error is then small beside the basis'
# (--study, --capacity), with a third of the default 1e-3's points.
SETTINGS = TrainingSettings(box_fraction=0.5, ecsw_tolerance=1e-2)
# The camera-rate-first setting of the same basis (--study): a looser sampling, the update
# at about 200 Hz, the surface within ~0.2 mm of the full model, sensing as accurate.
FAST_SETTINGS = dataclasses.replace(SETTINGS, ecsw_tolerance=3e-2)
# (basis size, ECSW tolerance) pairs of the study (docs/reduced_model.md)
# basis sizes of --capacity (no hyper-reduction: the basis alone), and the one it also
# trains hyper-reduced as the bench does
CAPACITY_MODES = (200, 280, 400)
CAPACITY_SAMPLED = 280
STUDY_GRID = ((200, 1e-3), (200, 1e-2), (200, 3e-2), (200, 1e-1), (160, 1e-2), (160, 3e-2),
              (120, 1e-2), (120, 3e-2))


def reduced_robot(element: str = "p2", settings: TrainingSettings = SETTINGS,
                  stem: str = "") -> tuple[Robot, Robot]:
    """(the full robot of `element`, the same robot reading the cached reduced model
    out/bench_reduced/{stem or diamond_element}.rom.npz), training and caching the reduced
    model with `settings` first when it is missing."""
    full = with_element(load_robot(COARSE), element)
    path = CACHE / f"{stem or 'diamond_' + element}.rom.npz"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        reduction = train_robot(full, settings, cache=CACHE / f"{element}.snapshots.npz")
        save_reduction(path, reduction, force=True)
    mesh = dataclasses.replace(full.config.mesh, reduced=path)
    return full, dataclasses.replace(full, config=dataclasses.replace(full.config, mesh=mesh))


def update_callable(robot: Robot, x: np.ndarray, tensions: np.ndarray):
    """One sensing frame's FE work at (x, tensions), as bench_fem.sensing_update does it."""
    model = robot.fe_model
    features = Attachment.at_nodes(robot.feature_nodes)
    effectors = effector_rows(features, model.node_count, robot.feature_normals)
    contacts = np.array([0, len(robot.feature_nodes) // 2])
    forces = force_rows(features.subset(contacts), robot.feature_normals[contacts],
                        model.node_count)
    # the configuration as a sensing loop holds it (a State: a reduced model's never lifts);
    # a fresh one each time, so that nothing it caches carries over
    at = model.coordinates.state(x)
    zero = np.zeros(model.coordinates.size)
    state = {"lin": linearize(model, x, tensions)}

    def update() -> None:
        state["lin"] = linearize_state(model, at.moved(zero, 0.0), tensions,
                                       factorization=state["lin"].factorization)
        compliance(state["lin"], effectors, forces)

    return update


def cases(robot: Robot, max_force_n: float) -> list[tuple[str, LoadCase]]:
    """Untrained cases: interior actuations; one force between features; two contacts; the
    sensing bench's probe (benchmarks/bench_sense.py: 0.25 N into the north bar along the
    normal of its nearest surface node, cables 5, 0, 5, 0 mm: a pair the actuation design
    does not hold)."""
    points, normals = between_features(robot.mesh.nodes_mm, robot.mesh.surface_faces,
                                       robot.feature_nodes, robot.fixed_nodes, 3)
    inputs = robot.cable_inputs
    surface = robot.mesh.surface_nodes
    nearest = surface[np.argmin(np.linalg.norm(robot.mesh.nodes_mm[surface] - PROBE_MM, axis=1))]
    inward = -robot.mesh.vertex_normals[nearest]
    return [
        ("actuation 7, 3, 8, 5 mm", LoadCase(inputs(np.array([7.0, 3.0, 8.0, 5.0])),
                                             points[:0], np.zeros((0, 3)))),
        ("actuation 5, 5, 0, 0 mm + 0.6 N between features",
         LoadCase(inputs(ACTUATION), points[:1], -0.6 * max_force_n * normals[:1])),
        ("actuation 3, 8, 2, 6 mm + two contacts 0.4 N",
         LoadCase(inputs(np.array([3.0, 8.0, 2.0, 6.0])), points[1:],
                  -0.4 * max_force_n * normals[1:])),
        ("actuation 5, 0, 5, 0 mm + a 0.25 N probe", LoadCase(
            inputs(np.array([5.0, 0.0, 5.0, 0.0])), PROBE_MM[None], 0.25 * inward[None])),
    ]


_REFERENCES: dict[str, object] = {}


def reference(full: Robot, name: str, case: LoadCase):
    """The full model's answer to a case, computed once and cached (minutes for p2)."""
    path = CACHE / "references.pkl"
    if not _REFERENCES and path.exists():
        _REFERENCES.update(pickle.loads(path.read_bytes()))
    if name not in _REFERENCES:
        _REFERENCES[name] = respond(full.fe_model, case, full.feature_nodes,
                                    full.feature_normals)
        path.write_bytes(pickle.dumps(_REFERENCES))
    return _REFERENCES[name]


def accuracy(full: Robot, reduced: Robot, max_force_n: float):
    """[(case name, CaseErrors)] of the reduced model against the full one."""
    out = []
    for name, case in cases(full, max_force_n):
        answer = respond(reduced.fe_model, case, full.feature_nodes, full.feature_normals)
        expected = reference(full, name, case)
        out.append((name, compare(expected, answer, full.rest_nodes_mm,
                                  full.mesh.surface_nodes, held_cables(case, expected))))
    return out


def _held(errors: CaseErrors) -> str:
    """', held W_ef x%' for a case with forces (the compliance sensing solves with)."""
    value = errors.held_ef_relative
    return "" if np.isnan(value) else f", held W_ef {100 * value:.1f}%"


def run() -> list[BenchRow]:
    started = time.perf_counter()
    full, reduced = reduced_robot()
    model = reduced.fe_model
    info = model.reduction.info
    rows = [BenchRow("Reduced model training (p2, coarse Diamond)", info["total_s"], 1,
                     "< 10 min", f"{info['total_s'] / 60:.1f} min",
                     f"snapshots {info['snapshots_s']:.0f} s (about 1 s when read from a "
                     f"training's cache), POD {info['pod_s']:.0f} s, ECSW {info['ecsw_s']:.0f} s; "
                     f"{info['static_snapshots']} static snapshots, "
                     f"{info.get('contact_snapshots', 0)} contact equilibria, "
                     f"{info['modes']} modes, "
                     f"{info['sampled_points']} of {info['points']} quadrature points sampled "
                     f"(in {info['sampled_elements']} elements); "
                     f"prepared in {time.perf_counter() - started:.0f} s here")]
    inputs = reduced.cable_inputs(ACTUATION)
    equilibrium = solve_equilibrium(model, inputs)
    update = update_callable(reduced, equilibrium.positions_mm, equilibrium.cable_tensions_n)
    update_s = median_time(update, repeats=200, warmup=5)
    rows.append(BenchRow("Reduced FE update, p2 (tangent, factorise, W: 51 normals + 4 cables"
                         " + 2 forces)", update_s, 200, ">= 200 Hz", f"{1 / update_s:.0f} Hz",
                         f"r = {info['modes']}, {info['sampled_points']} points; full p2:"
                         " 1.4 Hz, full p1: 31 Hz (docs/locking.md)"))
    (cold_s, cold_iterations), (warm_s, warm_iterations) = static_solves(reduced).values()
    rows.append(BenchRow("Reduced static solve given no start, 8 random actuations + gravity",
                         cold_s, 20, "< 20 ms", f"{cold_s * 1e3:.0f} ms",
                         f"{cold_iterations} Newton iterations from the nearest start "
                         "equilibrium moved to first order (before the start grid, 2026-11-29: "
                         "one solve at cables 5,5,0,0 mm, from the training equilibria alone)"))
    rows.append(BenchRow("Reduced static solve from a frame 0.5 mm away (tracking)", warm_s, 20,
                         "< 20 ms", f"{warm_s * 1e3:.0f} ms",
                         f"{warm_iterations} Newton iterations; from the earlier solve's "
                         "state, as a sensing loop starts"))
    positions = solve_equilibrium(model, reduced.cable_inputs(CALIBRATION_MM)).positions_mm
    observed = observed_markers(reduced, positions, paper_transform())
    calibrate(reduced, observed)
    calibration_s = median_time(lambda: calibrate(reduced, observed), repeats=3, warmup=0)
    rows.append(BenchRow("Calibration from 9 markers with the reduced p2 model", calibration_s,
                         3, "< 2 s", f"{calibration_s:.2f} s", "paper's Table I protocol"))
    for name, errors in accuracy(full, reduced, model.reduction.box.max_force_n):
        worst = max(errors.W_relative.values())
        rows.append(BenchRow(f"Reduced vs full p2: {name}", 0.0, 1, "<= 0.5 mm, W <= 5%",
                             f"{errors.rms_mm:.3f} mm RMS, W {100 * worst:.1f}%"
                             + _held(errors),
                             f"surface moves {errors.displacement_mm:.1f} mm RMS; max "
                             f"{errors.max_mm:.2f} mm; tensions within "
                             f"{errors.tension_n * 1e3:.1f} mN"))
    return rows + fast_rows(full)


def static_solves(robot: Robot, count: int = 8) -> dict[str, tuple[float, str]]:
    """{name: (median seconds, Newton iterations: median (range))} of static solves: given no
    start, at `count` random actuations across the training box (none on the start grid:
    the median over actuations of each one's median of 3); and tracking at the bench's
    actuation and at one cable 0.5 mm shorter, each solve starting from the state the one
    before ended in (as a sensing loop holds it: evaluated there, its tangent not formed),
    the actuation going back and forth between the two. The node positions are not read."""
    model = robot.fe_model
    times, iterations = [], []
    for values in random_actuations(model.reduction.box, count, seed=7):
        inputs = robot.cable_inputs(values)
        iterations.append(solve_equilibrium(model, inputs).iterations)
        times.append(median_time(lambda inputs=inputs: solve_equilibrium(model, inputs),
                                 repeats=3, warmup=0))
    targets = [robot.cable_inputs(ACTUATION - [0.5, 0.0, 0.0, 0.0]),
               robot.cable_inputs(ACTUATION)]
    last = [solve_equilibrium(model, targets[0])]

    def track() -> Equilibrium:
        targets.reverse()
        last[0] = solve_equilibrium(model, targets[0], start=last[0])
        return last[0]

    tracking_s = median_time(track, repeats=20)
    return {"given no start": (float(np.median(times)), _spread(iterations)),
            "from a frame 0.5 mm away": (tracking_s, str(track().iterations))}


def random_actuations(box: TrainingBox, count: int, seed: int) -> np.ndarray:
    """(count, a) actuations drawn uniformly in a reduced model's training box."""
    width = box.cable_max - box.cable_min
    return box.cable_min + np.random.default_rng(seed).random((count, len(width))) * width


def _spread(values: list[int]) -> str:
    return f"{np.median(values):.0f} ({min(values)}-{max(values)})"


def fast_rows(full: Robot) -> list[BenchRow]:
    """The update, the static solves and the worst untrained case inside the box (the two
    contacts' fold left out) of the same basis sampled at FAST_SETTINGS' ECSW tolerance."""
    _, fast = reduced_robot(settings=FAST_SETTINGS, stem="diamond_p2_fast")
    model = fast.fe_model
    info = model.reduction.info
    equilibrium = solve_equilibrium(model, fast.cable_inputs(ACTUATION))
    update_s = median_time(update_callable(fast, equilibrium.positions_mm,
                                           equilibrium.cable_tensions_n), repeats=200, warmup=5)
    solves = static_solves(fast)
    inside = [(name, errors) for name, errors in accuracy(full, fast,
                                                          model.reduction.box.max_force_n)
              if "two contacts" not in name]
    rms = max(errors.rms_mm for _, errors in inside)
    worst = {name: 100 * max(errors.W_relative.values()) for name, errors in inside}
    label = f"ECSW {FAST_SETTINGS.ecsw_tolerance:g}, {info['sampled_points']} points"
    return [
        BenchRow(f"Reduced FE update, p2, {label}", update_s, 200, ">= 200 Hz",
                 f"{1 / update_s:.0f} Hz", f"r = {info['modes']}; the same update as above"),
        *(BenchRow(f"Reduced static solve {name}, {label}", seconds, 20, "< 20 ms",
                   f"{seconds * 1e3:.0f} ms", f"{iterations} Newton iterations; the "
                   "same solve as above") for name, (seconds, iterations) in solves.items()),
        BenchRow(f"Reduced vs full p2, {label}: the untrained cases but the two contacts",
                 0.0, 1, "<= 0.5 mm, W <= 5%",
                 f"{rms:.3f} mm RMS at most, W {max(worst.values()):.1f}% at most",
                 "worst W block: " + "; ".join(f"{name} {worst[name]:.1f}%{_held(errors)}"
                                               for name, errors in inside)),
    ]


def interleaved_medians(functions: dict[str, Callable[[], object]], repeats: int
                        ) -> dict[str, float]:
    """{name: median seconds} of each function, run in turn `repeats` times after one warm-up
    round: on a shared machine the load changes within seconds, so timings taken one after
    the other are not comparable, timings taken in turn are."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for round_ in range(repeats + 1):
        for name, function in functions.items():
            start = time.perf_counter()
            function()
            if round_:
                times[name].append(time.perf_counter() - start)
    return {name: float(np.median(values)) for name, values in times.items()}


def tangent_study(repeats: int = 40) -> None:
    """The reduced tangent formed four ways at the bench state, interleaved; and the W of the
    default (float32) tangent against the float64 one on the untrained cases' states."""
    full, reduced = reduced_robot()
    model = reduced.fe_model
    equilibrium = solve_equilibrium(model, reduced.cable_inputs(ACTUATION))
    x, tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
    precise = dataclasses.replace(model, tangent_dtype=np.float64)
    fast, exact = model.coordinates, precise.coordinates
    operators, weights = fast.points, fast.point_weights[:, 0]
    r = operators.shape[-1]
    # the operator as the plain sum stored it before: C-ordered (9s, r), so that the GEMM
    # took it transposed
    stacked = np.ascontiguousarray(operators.reshape(-1, r))
    F = deformation_gradients(x, fast.tets, fast.gradients)[:, 0]

    # the assembly alone, from the law's output at the sampled points (the forces and
    # tangent rows below time everything, the law included)
    dense = model.full.constitutive_at(F, fast.rule_points, with_tangent=True)[1]

    def plain_before() -> np.ndarray:
        weighted = (weights[:, None, None] * dense) @ operators
        return stacked.T @ weighted.reshape(-1, r)

    def factored(space: ReducedCoordinates) -> Callable[[], np.ndarray]:
        pieces = [(where, model.full.material.evaluate(F[where], part).factors)
                  for where, part in space.parts]
        return lambda: space.tangent(pieces)

    timings = interleaved_medians({
        "law at the points, dense A_p (before)": lambda: model.full.constitutive_at(
            F, fast.rule_points, with_tangent=True),
        "law at the points, factored A_p": lambda: [
            model.full.material.evaluate(F[where], part).factors
            for where, part in fast.parts],
        "K_r plain sum, float64, (9s, r) operator transposed (before)": plain_before,
        "K_r plain sum, float64, (r, 9s) operator": lambda: plain_tangent(operators, weights,
                                                                          dense),
        "K_r factored A_p + syrk, float64": factored(exact),
        "K_r factored A_p + syrk, float32 (default)": factored(fast),
        "forces and tangent, float64": lambda: exact.forces_and_tangent(x, tensions),
        "forces and tangent, float32 (default)": lambda: fast.forces_and_tangent(x, tensions),
        "update (bench row)": update_callable(reduced, x, tensions),
    }, repeats)
    for name, seconds in timings.items():
        print(f"{name:62s} {seconds * 1e3:7.2f} ms")
    reference = plain_tangent(operators, weights, dense)
    for name, space in (("float64", exact), ("float32", fast)):
        tangent = space.forces_and_tangent(x, np.zeros_like(tensions))[1]
        error = np.linalg.norm(tangent - reference) / np.linalg.norm(reference)
        print(f"K_r {name} vs the plain sum: {error:.1e} relative (Frobenius)")
    for name, case in cases(full, model.reduction.box.max_force_n):
        answers = [respond(m, case, full.feature_nodes, full.feature_normals)
                   for m in (precise, model)]
        errors = compare(*answers, full.rest_nodes_mm, full.mesh.surface_nodes)
        print(f"{name}: float32 vs float64 tangent: positions {errors.max_mm:.1e} mm apart, "
              f"W {max(errors.W_relative.values()):.1e} relative, tensions "
              f"{errors.tension_n:.1e} N")


def solve_study(repeats: int = 30) -> None:
    """Where a reduced static solve's time goes: each piece of a Newton iteration at the bench
    equilibrium, and the compliance's cable and force rows as projected now and as formed
    before (dense (a, 3n) Jacobian, its sparse copy, both projected), interleaved (medians)."""
    _, reduced = reduced_robot()
    model = reduced.fe_model
    space = model.coordinates
    inputs = reduced.cable_inputs(ACTUATION)
    equilibrium = solve_equilibrium(model, inputs)
    x, tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
    state = space.state(x)
    tangent = state.tangent(tensions)
    factor = space.factorize(tangent)
    F = state.gradients.reshape(-1, 3, 3)
    features = Attachment.at_nodes(reduced.feature_nodes)
    contacts = np.array([0, len(reduced.feature_nodes) // 2])
    forces = force_rows(features.subset(contacts), reduced.feature_normals[contacts],
                        model.node_count)

    def fresh():
        return state.moved(state.q, 0.0)

    def rows_before() -> None:
        actuators = model.cable_jacobian(x)
        space.project_rows(sp.vstack([sp.csr_matrix(actuators), forces]).tocsr())
        space.project_rows(actuators)
        model.cable_shortenings(x)

    def rows_now() -> None:
        _, projected = space.cables(x)
        np.vstack([projected, space.project_rows(forces)])

    timings = interleaved_medians({
        "solve from rest": lambda: solve_equilibrium(model, inputs,
                                                     start_mm=model.rest_nodes_mm),
        # each from a fresh state: a state keeps its evaluation of the law
        "tangent: F, the law with factors, K_r, cables' stiffness": lambda: fresh().tangent(
            tensions),
        "  of which the law with factors": lambda: [
            model.full.material.evaluate(F[where], part).factors
            for where, part in space.parts],
        "  of which the cables' geometric stiffness": lambda: space.cable_stiffness(
            state.cable_nodes_mm, tensions),
        "energy and forces: F, the law, the GEMV": lambda: fresh().energy_and_forces(),
        "state: F = F_rest + G q, cable nodes": lambda: (fresh().gradients,
                                                         fresh().cable_nodes_mm),
        "cables: lengths and rows H V": state.cables,
        "LU": lambda: factor.refactor(tangent),
        "lift V q (once per solve)": lambda: space.lift(state.q),
        "compliance rows: cables projected + forces (now)": rows_now,
        "compliance rows: dense Jacobian, sparse copy (before)": rows_before,
    }, repeats)
    for name, seconds in timings.items():
        print(f"{name:62s} {seconds * 1e3:7.2f} ms")


def study() -> None:
    """Accuracy and update time vs basis size and ECSW tolerance, on the cached snapshots.

    Each model is kept as out/bench_reduced/study_{modes}_{tolerance}.rom.npz (for a sensing
    run through a robot file naming it). The two contacts are reported apart: their 21 mm fold
    lies outside every training state, and the worst case would always be theirs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from benchmarks.bench_sense import robot_reading, sense_run

    full, _ = reduced_robot()
    base = SETTINGS
    references = [(name, reference(full, name, case), case)
                  for name, case in cases(full, base.max_force_n)]
    figures = []
    for modes, tolerance in STUDY_GRID:
        settings = dataclasses.replace(base, max_modes=modes, ecsw_tolerance=tolerance,
                                       validations=0)
        path = CACHE / f"study_{modes}_{tolerance:g}.rom.npz"
        if not path.exists():
            reduction = train_robot(full, settings, cache=CACHE / "p2.snapshots.npz")
            save_reduction(path, reduction, force=True)
        mesh = dataclasses.replace(full.config.mesh, reduced=path)
        robot = dataclasses.replace(full, config=dataclasses.replace(full.config, mesh=mesh))
        points = robot.fe_model.reduction.points.size
        try:
            errors = {name: compare(answer, respond(robot.fe_model, case, full.feature_nodes,
                                                    full.feature_normals),
                                    full.rest_nodes_mm, full.mesh.surface_nodes,
                                    held_cables(case, answer))
                      for name, answer, case in references}
        except SolverError as error:  # too few modes or elements to hold a case
            print(modes, tolerance, points, error, flush=True)
            continue
        eq = solve_equilibrium(robot.fe_model, robot.cable_inputs(ACTUATION))
        update_s = median_time(update_callable(robot, eq.positions_mm,
                                               eq.cable_tensions_n), repeats=100)
        inside = [e for name, e in errors.items() if "two contacts" not in name]
        probe = next(e for name, e in errors.items() if "probe" in name)
        row = (modes, tolerance, points, max(e.rms_mm for e in inside),
               max(max(e.W_relative.values()) for e in inside), probe.rms_mm,
               probe.W_relative["W_ef"], update_s, probe.held_ef_relative)
        print(f"modes {modes}, ECSW tol {tolerance:g}: {points} points, worst RMS "
              f"{row[3]:.3f} mm, worst W {100 * row[4]:.1f}% (without the two contacts), "
              f"probe {row[5]:.3f} mm, W_ef {100 * row[6]:.1f}%; update "
              f"{update_s * 1e3:.1f} ms ({1 / update_s:.0f} Hz)", flush=True)
        for name, e in errors.items():
            print(f"    {name}: {e.rms_mm:.3f} mm, W " + ", ".join(
                f"{key} {100 * value:.1f}%" for key, value in e.W_relative.items())
                + _held(e), flush=True)
        for source in (COARSE, COARSE.parent / "diamond_p2.toml"):  # 51 and 151 features
            sensed = sense_run(robot_reading(source, path, f"study_{source.stem}.toml"))
            accuracy_ = sensed["accuracy"]
            print(f"    sensing the bench's probes, {source.name}: intensity error "
                  f"{100 * accuracy_['intensity_error_median']:.1f}% / "
                  f"{100 * accuracy_['intensity_error_p90']:.1f}% (median / 90th pct), "
                  f"{accuracy_['located']} of {accuracy_['true_contacts']} located",
                  flush=True)
        figures.append(row)
    data = np.array(figures)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    for tolerance in sorted(set(data[:, 1])):
        pick = data[:, 1] == tolerance
        label = f"ECSW tol {tolerance:g}"
        axes[0].semilogy(data[pick, 0], data[pick, 5], "o-", label=label)
        line, = axes[1].semilogy(data[pick, 0], 100 * data[pick, 6], "o-")
        axes[1].semilogy(data[pick, 0], 100 * data[pick, 8], "s--", color=line.get_color())
        axes[2].plot(data[pick, 2], 1 / data[pick, 7], "o", label=label)
    axes[0].axhline(0.5, color="k", lw=0.8, ls="--")
    axes[1].axhline(5.0, color="k", lw=0.8, ls="--")
    axes[0].set(xlabel="modes r", ylabel="probe case: RMS surface error (mm)")
    axes[1].set(xlabel="modes r", ylabel="probe case: W_ef error (%)")
    axes[1].legend([Line2D([], [], color="k", marker="o"),
                    Line2D([], [], color="k", marker="s", ls="--")],
                   ["cables free", "taut cables held (what sensing solves with)"], fontsize=8)
    axes[2].set(xlabel="sampled quadrature points", ylabel="update rate (Hz)")
    for axis in axes:
        axis.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle("Reduced P2 model of the coarse Diamond vs its full model "
                 "(0.25 N probe, untrained)")
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=120)
    print(f"wrote {FIGURE}")


def capacity_study() -> None:
    """W at the loaded cases against the basis size alone: each model trained on the cached
    snapshots without hyper-reduction (ECSW tolerance 0: every quadrature point at weight 1,
    the exact Galerkin projection), so that only the basis differs (about a minute each);
    then the largest hyper-reduced as the bench trains it, with its update (7 minutes to
    train)."""
    full, _ = reduced_robot()
    references = [(name, reference(full, name, case), case)
                  for name, case in cases(full, SETTINGS.max_force_n)
                  if "two contacts" not in name]
    runs = [(modes, 0.0) for modes in CAPACITY_MODES] + [(CAPACITY_SAMPLED,
                                                          SETTINGS.ecsw_tolerance)]
    for modes, tolerance in runs:
        path = CACHE / f"capacity_{modes}_{tolerance:g}.rom.npz"
        if not path.exists():
            settings = dataclasses.replace(SETTINGS, max_modes=modes, ecsw_tolerance=tolerance,
                                           validations=0)
            save_reduction(path, train_robot(full, settings,
                                             cache=CACHE / "p2.snapshots.npz"), force=True)
        mesh = dataclasses.replace(full.config.mesh, reduced=path)
        robot = dataclasses.replace(full, config=dataclasses.replace(full.config, mesh=mesh))
        points = robot.fe_model.reduction.points.size
        label = f"{modes} modes, " + (f"ECSW {tolerance:g} ({points} points)" if tolerance
                                      else "every point")
        for name, answer, case in references:
            errors = compare(answer, respond(robot.fe_model, case, full.feature_nodes,
                                             full.feature_normals),
                             full.rest_nodes_mm, full.mesh.surface_nodes,
                             held_cables(case, answer))
            blocks = ", ".join(f"{block} {100 * value:.1f}%"
                               for block, value in errors.W_relative.items())
            print(f"{label} | {name} | {errors.rms_mm:.3f} mm | {blocks}{_held(errors)}",
                  flush=True)
        if tolerance:
            eq = solve_equilibrium(robot.fe_model, robot.cable_inputs(ACTUATION))
            update_s = median_time(update_callable(robot, eq.positions_mm,
                                                   eq.cable_tensions_n), repeats=200, warmup=5)
            print(f"{label} | update {update_s * 1e3:.1f} ms ({1 / update_s:.0f} Hz)",
                  flush=True)


def starts_study(count: int = 16) -> None:
    """Newton iterations and time of reduced static solves given no start, from the
    nearest start equilibrium moved to first order (the training equilibria and the grid,
    or the training equilibria alone) and from rest, at `count` random actuations across
    the training box, and how far apart their answers land."""
    _, reduced = reduced_robot(settings=FAST_SETTINGS, stem="diamond_p2_fast")
    model = reduced.fe_model
    reduction = model.reduction
    starts, trained = reduction.starts, reduction.info["static_snapshots"]
    alone = dataclasses.replace(model, reduction=dataclasses.replace(
        reduction, starts=starts.first(trained)))
    ways = {"grid": (model, None), "training equilibria": (alone, None),
            "rest": (model, model.rest_nodes_mm)}
    rows = []
    for values in random_actuations(reduction.box, count, seed=1):
        inputs = reduced.cable_inputs(values)
        answers, times = [], []
        for way, start in ways.values():
            def solve(way=way, start=start, inputs=inputs):
                return solve_equilibrium(way, inputs, start_mm=start)
            answers.append(solve())
            times.append(median_time(solve, repeats=3, warmup=0))
        apart = max(float(np.abs(answer.positions_mm - answers[0].positions_mm).max())
                    for answer in answers)
        rows.append([*(answer.iterations for answer in answers), *times, apart])
        print(f"{np.round(values, 2)}: " + ", ".join(
            f"{name} {answer.iterations} iterations {seconds * 1e3:.0f} ms"
            for name, answer, seconds in zip(ways, answers, times, strict=True))
            + f"; answers {apart:.1e} mm apart", flush=True)
    table = np.array(rows)
    print(f"{len(starts.inputs)} start equilibria ({trained} trained); median over "
          f"{count} actuations: " + ", ".join(
              f"{name} {np.median(table[:, i]):.0f} iterations ({table[:, i].min():.0f}-"
              f"{table[:, i].max():.0f}), {np.median(table[:, 3 + i]) * 1e3:.0f} ms"
              for i, name in enumerate(ways)) + f"; answers at most {table[:, 6].max():.1e} mm"
          " apart")


# how far sensing's inputs may be off (the sensitivity study): a force, a cable, a point
SENSITIVITY_FORCE = 0.05
SENSITIVITY_CABLE_MM = 0.1
SENSITIVITY_POINT_MM = 0.5


def sensitivity_study() -> None:
    """How far the full model's own W moves at the loaded cases when an input moves by what
    sensing cannot pin down (the force by 5%, one cable by 0.1 mm, the contact point by 0.5
    mm along the surface, both ways on two axes: the largest over cables and moves), beside
    the reduced model's W error there (the bench's 1e-2 model; a minute)."""
    full, reduced = reduced_robot()
    blocks = ("W_ea", "W_ef", "W_aa", "W_af")

    def errors(expected: CaseResult, model: FEModel, case: LoadCase, held: np.ndarray
               ) -> np.ndarray:
        """(5,) the relative errors of the four blocks and of the held W_ef of `model`'s
        answer to `case` against `expected`."""
        found = compare(expected, respond(model, case, full.feature_nodes,
                                          full.feature_normals),
                        full.rest_nodes_mm, full.mesh.surface_nodes, held)
        return np.array([found.W_relative[b] for b in blocks] + [found.held_ef_relative])

    print("| case | change | " + " | ".join(blocks) + " | held W_ef |")
    print("|---|---|" + "---|" * (len(blocks) + 1))
    for name, case in cases(full, SETTINGS.max_force_n):
        if not len(case.forces_n) or "two contacts" in name:
            continue
        answer = reference(full, name, case)
        held = held_cables(case, answer)

        def moved(changed: LoadCase, answer=answer, held=held) -> np.ndarray:
            return errors(answer, full.fe_model, changed, held)

        steps = np.eye(len(case.inputs.values))
        along = tangent_basis(case.forces_n[:1] / np.linalg.norm(case.forces_n[0]))[0]
        rows = {
            "reduced model (ECSW 1e-2)": errors(answer, reduced.fe_model, case, held),
            f"full, force {100 * SENSITIVITY_FORCE:.0f}% less": moved(dataclasses.replace(
                case, forces_n=(1 - SENSITIVITY_FORCE) * case.forces_n)),
            f"full, a cable {SENSITIVITY_CABLE_MM} mm further (largest)": np.max([moved(
                dataclasses.replace(case, inputs=full.cable_inputs(
                    case.inputs.values + SENSITIVITY_CABLE_MM * step))) for step in steps],
                axis=0),
            f"full, the point {SENSITIVITY_POINT_MM} mm along the surface (largest of 4)": np.max(
                [moved(dataclasses.replace(case, points_mm=case.points_mm
                                           + SENSITIVITY_POINT_MM * sign * tangent))
                 for tangent in along for sign in (1, -1)], axis=0),
        }
        for change, values in rows.items():
            print(f"| {name} | {change} | "
                  + " | ".join(f"{100 * v:.1f}%" for v in values) + " |", flush=True)


# studies that replace the rows (--study prints the rows after it)
STUDIES = {"--starts": starts_study, "--capacity": capacity_study, "--tangent": tangent_study,
           "--solve": solve_study, "--sensitivity": sensitivity_study}

if __name__ == "__main__":
    chosen = [function for flag, function in STUDIES.items() if flag in sys.argv]
    if chosen:
        chosen[0]()
        sys.exit()
    if "--study" in sys.argv:
        study()
    for bench_row in run():
        print(bench_row)
