"""The nominal FE prediction of every state: one equilibrium and one factorisation each.

Per distinct actuation state s the *accurate* model A is solved once (warm-started from the
previous state) and linearised once (one tangent factorisation, reused for every
sensitivity in diagnosis.sensitivities). A robot with linear tetrahedra (P1) locks
(docs/locking.md): under gravity alone it sags about 5 mm less than the locking-free body,
and its response to a cable differs by 40% (a 6 mm pull: 1.5 mm RMS of 3.5 mm), in every
recording. That is discretisation, not missing physics: neither its prediction nor its
sensitivities can be trusted to tell physics apart. So the accurate model of a P1 robot is
the same mesh with quadratic elements (P2), and the P1 model is solved too, only to measure
how much of the mismatch the mesh alone makes (the *mesh correction* x_P2 - x_P1, reported
in the evidence). A robot with P2 or P2-P0 elements is its own accurate model.

Solutions and sensitivity columns are cached on disk (SolveCache), keyed by the model's
definition and the inputs: a second diagnosis of the same robot (another recording with the
same states, a rerun with --force) solves nothing again.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path

import numpy as np

from softforce_cli.diagnosis.sensitivities import ColumnSet, state_columns
from softforce_cli.errors import OutputError, SolverError
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.compliance import linearize
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import (
    SolverSettings,
    solve_by_continuation,
    solve_equilibrium,
)
from softforce_cli.io.atomic import atomic_write_bytes
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import make_effect
from softforce_cli.model.robot import Robot, with_element

# Diagnosis compares shapes against a noise floor of ~0.3 mm: Newton's last full step being
# under 0.01 mm leaves the position known to ~1e-4 mm (quadratic convergence); the solver's
# defaults (1e-7 mm) cost a P2 state two more iterations. Ending instead on a predicted step
# under 1e-4 mm (fem.statics, the same precision) took 65 tangents against 62 to diagnose
# sample_data's diagnose_slack, and is not used. A solve ends on a step only,
# never on a small force residual alone: the residual is checked per degree of freedom, and
# a start whose only imbalance is a share of the weight spread over every node passes any
# per-node threshold far from equilibrium (a P2 beam 40% softer, started from its nominal
# equilibrium: 5e-5 N per node, 2 mm from its equilibrium, where 1e-3 N stopped it at once;
# the Diamond's nodes carry 5e-4 N of weight each).
SETTINGS = SolverSettings(step_tolerance_mm=1e-2, force_tolerance_n=0.0,
                          predicted_step=False)
# Bump when what a cached solve means changes.
CACHE_VERSION = 2
# Laws whose blend column is the secant to the other law (one more solve per state) instead
# of the tangent. The small-strain linear law's spurious stresses under rotation make its
# tangent correlate -0.46 with the exact change to Neo-Hookean under the Diamond's north
# cable at 6 mm, and a file with that law screened at blend 0 (named a softer or heavier
# body); the corotational law's tangent correlates 0.999 with its exact change there (0.8 mm
# RMS), so its 28-state diagnosis is spared 28 solves, about 9 s each here
# (benchmarks/law_blend_check.py).
SECANT_LAWS = frozenset({"linear"})
# Bump when what the cached sensitivity columns mean changes (2: compliant_base's rigid give;
# 3: the law blend's secant).
COLUMNS_VERSION = 3
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class SolveCache:
    """Equilibria on disk under `folder` (None: no cache), one .npz per model and inputs."""

    folder: Path | None

    def key(self, model: FEModel, inputs: CableInputs) -> str:
        digest = hashlib.sha256(f"{CACHE_VERSION}{SETTINGS}{model.material}"
                                f"{model.element_name}{inputs.control}".encode())
        for array in (model.rest_nodes_mm, model.tets, model.fixed_nodes, model.node_masses_kg,
                      model.gravity_mm_s2, np.asarray(inputs.values, dtype=float)):
            digest.update(np.ascontiguousarray(array).tobytes())
        for cable in model.cables:
            for array in (cable.path.node_indices, cable.path.weights, cable.pull_point_mm):
                digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()[:32]

    def load(self, key: str) -> dict[str, np.ndarray] | None:
        path = None if self.folder is None else self.folder / f"{key}.npz"
        if path is None or not path.is_file():
            return None
        try:
            with np.load(path) as stored:
                return {name: stored[name] for name in stored.files}
        except (OSError, ValueError, EOFError):  # a damaged entry is computed again
            return None

    def store(self, key: str, **arrays: np.ndarray) -> None:
        if self.folder is None:
            return
        buffer = BytesIO()
        np.savez(buffer, **arrays)
        try:
            atomic_write_bytes(self.folder / f"{key}.npz", buffer.getvalue(), force=True)
        except OutputError as error:  # a cache that cannot be written costs time, not the run
            warnings.warn(f"diagnose's cache is not kept ({error}); a later run solves its "
                          "states again", stacklevel=2)

    def solve(self, model: FEModel, inputs: CableInputs, start_mm: np.ndarray | None,
              solved: list[tuple[np.ndarray, np.ndarray]] = ()) -> tuple[np.ndarray, np.ndarray]:
        """(positions (N, 3) mm, cable tensions (a,) N) of the nominal `model` at `inputs`,
        by Newton's method from `start_mm`, else by continuation from the nearest of the
        `solved` (inputs, positions) pairs (a far jump of the inputs)."""
        key = self.key(model, inputs)
        stored = self.load(key)
        if stored is not None and {"positions_mm", "tensions_n"} <= set(stored):
            return stored["positions_mm"], stored["tensions_n"]
        try:
            solution = solve_equilibrium(model, inputs, start_mm=start_mm, settings=SETTINGS)
        except SolverError:
            solution = solve_by_continuation(model, inputs.control, inputs.values,
                                             list(solved), SETTINGS)
        self.store(key, positions_mm=solution.positions_mm, tensions_n=solution.cable_tensions_n)
        return solution.positions_mm, solution.cable_tensions_n


@dataclass(frozen=True, eq=False)
class StateSolutions:
    """The nominal prediction of every state (S states, n mesh nodes, N FE nodes of A).

    robot        : the accurate robot A (the given one, or it with P2 elements).
    given        : the element of the robot file ("p1", "p2", "p2-p0").
    actuation    : (S, a) commanded inputs per state.
    positions_mm : (S, N, 3) equilibria of A.
    tensions_n   : (S, a) cable tensions of A.
    columns      : (S, C, N, 3) sensitivity columns at every FE node (mm per unit).
    given_mm     : (S, n, 3) the given robot's own equilibria when it is not A (P1), else
                   None.
    """

    robot: Robot
    given: str
    actuation: np.ndarray
    positions_mm: np.ndarray
    tensions_n: np.ndarray
    columns: np.ndarray
    given_mm: np.ndarray | None
    column_set: ColumnSet

    @property
    def count(self) -> int:
        return len(self.actuation)

    @property
    def predicted_mm(self) -> np.ndarray:
        """(S, n, 3) the nominal prediction at the mesh nodes."""
        return self.positions_mm[:, :self.robot.mesh.node_count]

    @property
    def mesh_columns(self) -> np.ndarray:
        """(S, C, n, 3) the sensitivity columns at the mesh nodes."""
        return self.columns[:, :, :self.robot.mesh.node_count]

    def first_order(self, s: int, changes: dict[str, float]) -> np.ndarray:
        """(N, 3) state s's equilibrium moved to first order by {column name: change}: a
        Newton start that needs two iterations fewer than the equilibrium itself."""
        moved = self.positions_mm[s].copy()
        for name, change in changes.items():
            if change:
                moved += change * self.columns[s, self.column_set.index(name)]
        return moved


def accurate_robot(robot: Robot) -> Robot:
    """The robot diagnosis predicts with: P2 elements on the same mesh for a P1 robot."""
    return with_element(robot, "p2") if robot.element_name == "p1" else robot


def solve_states(robot: Robot, actuation: np.ndarray, cache: SolveCache, columns: ColumnSet,
                 progress: Progress | None = None,
                 stop_requested: Callable[[], bool] = lambda: False) -> StateSolutions | None:
    """Solve and linearise the accurate model at every state (S, a), its sensitivity columns,
    and the given P1 model's equilibria.

    States are solved nearest-neighbour first from the least actuated, each warm-started from
    its predecessor. Returns None when stop_requested() turns true between states.
    """
    accurate = accurate_robot(robot)
    model = accurate.nominal_fe_model
    n = robot.mesh.node_count
    given = robot.nominal_fe_model if accurate is not robot else None
    order = _chain(np.asarray(actuation, dtype=float))
    positions = np.empty((len(order), model.node_count, 3))
    tensions = np.empty((len(order), len(model.cables)))
    sensitivity = np.empty((len(order), len(columns.names), model.node_count, 3))
    cables = [columns.index(f"cable.{spec.name}") for spec in robot.cable_specs]
    given_mm = None if given is None else np.empty((len(order), n, 3))
    factor_box: list = [None]  # the factorisation whose symbolic analysis states reuse
    solved: dict[bytes, int] = {}  # states of equal inputs (loading, hold) share one solve
    for done, s in enumerate(order):
        if stop_requested():
            return None
        twin = solved.setdefault(np.asarray(actuation[s], dtype=float).tobytes(), s)
        if twin != s:
            positions[s], tensions[s], sensitivity[s] = (positions[twin], tensions[twin],
                                                         sensitivity[twin])
            if given is not None:
                given_mm[s] = given_mm[twin]
        else:
            # the chain's last steps can jump across the box: start from the nearest done
            done_states = list(solved.values())[:-1]
            nearest = min(done_states, default=None, key=lambda d: float(
                np.abs(actuation[d] - actuation[s]).sum()))
            _solve_state(s, nearest, done_states, accurate, model, actuation, cache, columns,
                         cables, positions, tensions, sensitivity, factor_box)
            if given is not None:
                given_mm[s], _ = cache.solve(
                    given, robot.cable_inputs(actuation[s]),
                    None if nearest is None else given_mm[nearest],
                    [(actuation[d], given_mm[d]) for d in done_states])
        if progress is not None:
            progress(done + 1, len(order))
    return StateSolutions(accurate, robot.element_name, np.asarray(actuation, dtype=float),
                          positions, tensions, sensitivity, given_mm, columns)


def _solve_state(s, previous, done_states, accurate, model, actuation, cache, columns, cables,
                 positions, tensions, sensitivity, factor_box) -> None:
    """Equilibrium and sensitivity columns of state s (from the disk cache when there),
    warm-started from state `previous` moved to first order, else continued from the nearest
    of the `done_states`."""
    inputs = accurate.cable_inputs(actuation[s])
    start = None
    if previous is not None:
        start = positions[previous] + np.einsum(
            "a,ani->ni", actuation[s] - actuation[previous], sensitivity[previous, cables])
    positions[s], tensions[s] = cache.solve(
        model, inputs, start, [(actuation[d], positions[d]) for d in done_states])
    key = f"{cache.key(model, inputs)}-columns{COLUMNS_VERSION}-" + hashlib.sha256(
        " ".join(columns.names).encode()).hexdigest()[:12]
    stored = cache.load(key)
    if stored is not None and stored.get("columns", np.empty(0)).shape == sensitivity[s].shape:
        sensitivity[s] = stored["columns"]
        return
    lin = linearize(model, positions[s], tensions[s], factorization=factor_box[0])
    factor_box[0] = lin.factorization  # the next state refactorises its symbolic analysis
    sensitivity[s] = state_columns(accurate, columns, lin, tensions[s])
    if "blend" in columns.names and model.material.law in SECANT_LAWS:
        blend = columns.index("blend")
        sensitivity[s, blend] = _law_secant(accurate, inputs, positions[s],
                                            sensitivity[s, blend], cache)
    cache.store(key, columns=sensitivity[s])


def _law_secant(accurate: Robot, inputs: CableInputs, positions_mm: np.ndarray,
                tangent_mm: np.ndarray, cache: SolveCache) -> np.ndarray:
    """(N, 3) mm: the equilibrium with the other law (blend 1) minus this one, the exact
    change over the blend's whole range [0, 1]; the first-order column `tangent_mm` where
    the other law has no equilibrium near this one."""
    other = fe_model_with_effects(accurate, (make_effect("material_nonlinearity", blend=1.0),))
    try:
        switched, _ = cache.solve(other, inputs, positions_mm)
    except SolverError:
        return tangent_mm
    return switched - positions_mm


@dataclass(frozen=True)
class ElementBracket:
    """How far the other quadratic element on the robot's mesh (P2-P0 for P2, P2 for P2-P0)
    is from the accurate model at the least actuated state: P2 is too stiff and P2-P0
    slightly too soft on a mesh, so the converged body lies between the two
    (docs/locking.md), and this is the size of the mesh's own error.

    load_scale     : the least-squares scale k of the other element's displacement from rest
                     onto the accurate model's, k u_A ~ u_other (on the coarse Diamond under
                     gravity, Neo-Hookean: P2-P0 deforms 1.14 times what P2 does);
    surface_rms_mm : the RMS distance between the two over the mesh's surface nodes (1.29
                     mm there).
    """

    load_scale: float
    surface_rms_mm: float

    def holds(self, load_scale: float) -> bool:
        """Whether a load scale g / E lies between 1 and the other element's."""
        return min(1.0, self.load_scale) <= load_scale <= max(1.0, self.load_scale)


def element_bracket(solutions: StateSolutions, cache: SolveCache) -> ElementBracket | None:
    """The ElementBracket of the accurate model of `solutions` (one more solve, cached);
    None when the other element has no equilibrium near the accurate one."""
    robot = solutions.robot
    other = other_element(robot)
    state = _least_actuated(solutions.actuation)
    accurate = solutions.positions_mm[state]
    try:
        positions, _ = cache.solve(other.nominal_fe_model,
                                   other.cable_inputs(solutions.actuation[state]), accurate)
    except SolverError:
        return None
    rest = robot.nominal_fe_model.rest_nodes_mm
    moved = accurate - rest
    size = float(np.vdot(moved, moved))
    if size <= 0.0:
        return None
    apart = (positions - accurate)[robot.mesh.surface_nodes]
    return ElementBracket(float(np.vdot(positions - rest, moved) / size),
                          float(np.sqrt(np.mean(np.sum(apart**2, axis=1)))))


def other_element(robot: Robot) -> Robot:
    """The robot with the other quadratic element of its mesh (P2 <-> P2-P0): the two bracket
    the mesh-converged body (docs/locking.md)."""
    return with_element(robot, "p2" if robot.element_name == "p2-p0" else "p2-p0")


def _least_actuated(actuation: np.ndarray) -> int:
    """The state (row of actuation (S, a)) whose inputs sum smallest in magnitude."""
    return int(np.argmin(np.abs(actuation).sum(axis=1)))


def _chain(actuation: np.ndarray) -> list[int]:
    """State indices from the least actuated, each next the nearest unvisited one."""
    remaining = list(range(len(actuation)))
    current = _least_actuated(actuation)
    order = []
    while remaining:
        remaining.remove(current)
        order.append(current)
        if remaining:
            distance = np.abs(actuation[remaining] - actuation[current]).sum(axis=1)
            current = remaining[int(np.argmin(distance))]
    return order
