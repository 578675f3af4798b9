"""Static equilibrium by Newton's method with a backtracking line search.

Unknowns are the free nodal positions and the tensions of displacement-controlled cables;
each Newton step solves the cables' constraints in their own small space (the W_aa system of
the paper's eq. 4), and a cable asked to push goes slack instead (lam >= 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.optimize

from softforce_cli.errors import SolverError
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.coordinates import Factor, State
from softforce_cli.fem.model import FEModel


@dataclass(frozen=True)
class PointLoads:
    """Dead loads at attached points: forces_n (p, 3) N applied at `points`."""

    points: Attachment
    forces_n: np.ndarray

    def nodal(self, node_count: int) -> np.ndarray:
        """(n, 3) N: the loads spread on nodes by the barycentric weights."""
        return self.points.interpolation(node_count).T @ np.asarray(self.forces_n, dtype=float)


@dataclass(frozen=True)
class SolverSettings:
    """Convergence thresholds, with why.

    step_tolerance_mm  : a full Newton step this small, or the next one predicted this small
                         (_next_step), means the position is known far better than any
                         camera measures it (D415 noise ~1 mm); None: the model's
                         coordinates' own (1e-7 mm for the full model, 1e-3 for a reduced
                         one: fem.coordinates).
    force_tolerance_n  : residual force small against the lightest load of interest (10 mN).
    predicted_step     : also end when the next step, predicted from the last three full
                         ones (_next_step), is under step_tolerance_mm; False: only a step
                         taken under it ends the solve, which leaves the position known to
                         ~C tol^2, far better than tol (diagnosis.solves relies on that).
    """

    step_tolerance_mm: float | None = None
    force_tolerance_n: float = 1e-8
    max_iterations: int = 60
    max_backtracks: int = 30
    predicted_step: bool = True


@dataclass(frozen=True)
class NewtonTangent:
    """The factorised tangent of a solve's last Newton step, taken one small step before its
    answer, and its mean diagonal (the line search's scale for the cables' gaps)."""

    factorization: Factor
    stiffness_scale: float


@dataclass(frozen=True)
class Equilibrium:
    """A static equilibrium.

    state                  : the configuration in the model's coordinates (fem.coordinates),
                             where a next solve can start (solve_equilibrium's start).
    tangent                : its last Newton step's tangent, where the coordinates keep it
                             (a reduced model's; None for the full model or without a
                             step): a next solve from it takes its first step with it.
    positions_mm           : (n, 3) deformed node positions in the robot frame, formed from
                             the state when first read (a reduced model's lift reads all of
                             its basis: 2.6 ms for the Diamond's 200 modes).
    cable_tensions_n       : (a,) cable forces (>= 0 for displacement control).
    cable_shortenings_mm   : (a,) delta = L0 - L of each cable.
    external_n             : (n, 3) the dead loads it holds (gravity and point loads) N.
    reaction_forces_n      : (k, 3) forces the supports exert on the clamped nodes, formed
                             when first read.
    residual_history_n     : max free-dof force residual before each iteration.
    """

    state: State = field(repr=False, compare=False)
    cable_tensions_n: np.ndarray
    cable_shortenings_mm: np.ndarray
    external_n: np.ndarray = field(repr=False, compare=False)
    tangent: NewtonTangent | None = field(repr=False, compare=False)
    iterations: int
    residual_history_n: tuple[float, ...] = field(default=())

    @cached_property
    def positions_mm(self) -> np.ndarray:
        return self.state.positions_mm

    @cached_property
    def reaction_forces_n(self) -> np.ndarray:
        return self.state.reactions(self.external_n, self.cable_tensions_n)

    def __getstate__(self) -> dict:
        # a pickle carries the node positions and reactions, not the model the state
        # belongs to
        return {**self.__dict__, "positions_mm": self.positions_mm,
                "reaction_forces_n": self.reaction_forces_n, "state": None, "tangent": None}


def external_forces(model: FEModel, loads: PointLoads | None) -> np.ndarray:
    """(n, 3) N: gravity plus dead point loads."""
    forces = model.gravity_forces_n.copy()
    if loads is not None:
        forces += loads.nodal(model.node_count)
    return forces


def solve_equilibrium(
    model: FEModel,
    inputs: CableInputs,
    loads: PointLoads | None = None,
    start_mm: np.ndarray | None = None,
    settings: SolverSettings = SolverSettings(),
    start: Equilibrium | None = None,
) -> Equilibrium:
    """Deformed configuration where elastic, applied and cable forces balance, from node
    positions start_mm (n, 3), or from an earlier solve of the same model (`start`: its
    state, so that a reduced model needs no projection of positions on its basis, and its
    last tangent for the first Newton step, a chord step that saves forming the tangent
    there), or else the model's own start for the inputs (fem.coordinates: rest, or a
    reduced model's nearest start equilibrium moved to first order).

    Raises SolverError when Newton's method does not converge in settings.max_iterations.
    """
    if len(inputs.values) != len(model.cables):
        raise SolverError(
            f"{len(inputs.values)} actuation values given for {len(model.cables)} cables"
        )
    if start_mm is not None and start is not None:
        raise ValueError("give start_mm or start, not both")
    space = model.coordinates
    state = (start.state if start is not None
             else space.start(inputs) if start_mm is None else space.state(start_mm))
    last = None if start is None else start.tangent
    tolerance = (space.step_tolerance_mm if settings.step_tolerance_mm is None
                 else settings.step_tolerance_mm)
    external = external_forces(model, loads)
    applied = space.project_loads(loads)
    controlled = inputs.displacement_controlled
    tensions = np.where(controlled, 0.0, inputs.values)
    space.check_load(inputs, external)  # a reduced model warns outside its training box

    # the state's evaluation; after the first, each comes from the line search's accepted
    # trial, so that no configuration is evaluated twice
    current = _Evaluation.at(state)
    tensions = _held_tensions(current, applied, controlled, tensions)
    stiffness_scale = None if last is None else last.stiffness_scale
    factor = None if last is None else last.factorization
    chord = last is not None  # the first step on the earlier solve's tangent, not a new one
    history: list[float] = []
    full_steps: list[float] = []  # the largest coordinate of each full step in a row
    for _ in range(settings.max_iterations):
        jacobian = current.cable_rows
        residual = applied - current.internal + jacobian.T @ tensions
        violation = (inputs.values - current.shortenings)[controlled]
        history.append(float(np.abs(residual).max(initial=0.0)))
        # a slack cable (no tension) may be shorter than asked, never longer
        slack = tensions[controlled] <= 0.0
        gap = np.where(slack, violation, np.abs(violation))
        if history[-1] <= settings.force_tolerance_n and np.all(gap < 1e-9):
            break
        if not chord:
            tangent = state.tangent(tensions)
            if stiffness_scale is None:
                stiffness_scale = float(np.mean(tangent.diagonal()))
            # a fresh factorisation object: an earlier solve's, started from, stays its own
            reused = last is not None and factor is last.factorization
            factor = space.factorize(tangent, None if reused else factor)
        chord = False
        base = applied - current.internal + jacobian[~controlled].T @ tensions[~controlled]
        # the step and the held cables' responses K^-1 H_d^T, solved together
        pulled = jacobian[controlled]
        solved = factor.solve(np.column_stack([base, pulled.T]))
        step = solved[:, 0]
        if controlled.any():
            tensions, step = _cable_tensions(
                pulled, solved[:, 1:], controlled, violation, step, tensions
            )
        state, current, full_step = _line_search(
            state, current, step, tensions, applied, inputs, controlled, stiffness_scale,
            settings,
        )
        full_steps = [*full_steps, float(np.abs(step).max())] if full_step else []
        if full_steps and (full_steps[-1] <= tolerance or (
                settings.predicted_step and _next_step(full_steps) <= tolerance)):
            break
    else:
        raise SolverError(
            f"static solve did not converge in {settings.max_iterations} Newton iterations "
            f"(force residual {history[-1]:.3g} N); reduce the load or refine the mesh"
        )
    space.check_solution(state)  # a reduced model warns beyond its training's shapes
    return Equilibrium(
        state=state,
        cable_tensions_n=tensions,
        cable_shortenings_mm=current.shortenings,
        external_n=external,
        tangent=(NewtonTangent(factor, stiffness_scale)
                 if factor is not None and space.keeps_tangent else None),
        iterations=len(history),
        residual_history_n=tuple(history),
    )


def _next_step(sizes: list[float]) -> float:
    """The size of the next Newton step predicted from those of the last full steps (each
    step's largest coordinate), inf until three full steps have shrunk in a row.

    In quadratic convergence s_k+1 ~ C s_k^2; C is taken as the larger of the last two
    ratios s_k / s_k-1^2, since it settles only near the solution. The solve ends when the
    predicted step is below the tolerance instead of taking it: the step would have moved
    the body by that much, and the iteration that measured it costs a tangent (on the
    Diamond, the last 2e-6 mm step of a tracking solve, whose step before was 0.02 mm).
    """
    if len(sizes) < 3 or not sizes[-1] < sizes[-2] < sizes[-3]:
        return np.inf
    return max(sizes[-1] / sizes[-2] ** 2, sizes[-2] / sizes[-3] ** 2) * sizes[-1] ** 2


@dataclass(frozen=True)
class _Evaluation:
    """What the solver needs at a state: elastic energy (mJ), T^T g (c,) N, cable
    shortenings (a,) mm and rows H T (a, c)."""

    energy: float
    internal: np.ndarray
    shortenings: np.ndarray
    cable_rows: np.ndarray

    @classmethod
    def at(cls, state: State) -> _Evaluation:
        energy, internal = state.energy_and_forces()
        return cls(energy, internal, *state.cables())


def _held_tensions(current: _Evaluation, applied: np.ndarray, controlled: np.ndarray,
                   tensions: np.ndarray) -> np.ndarray:
    """Tensions (a,) >= 0 of the displacement-controlled cables that best balance the forces
    at the start (least squares on the residual): the starting guess, so that the first
    tangent carries the cables' geometric stiffness when the start is a loaded state (a
    tracking solve from the previous frame's equilibrium), and zero at rest.
    """
    if not controlled.any():
        return tensions
    rows = current.cable_rows
    rest = applied - current.internal + rows[~controlled].T @ tensions[~controlled]
    # only the coordinates the cables move matter (the full model's rows touch a few dofs),
    # and scipy's nnls is slow on tall matrices (27 ms on a full p2 Diamond's 27k dofs)
    pulled = np.asarray(rows[controlled]).T
    used = np.flatnonzero(np.any(pulled != 0.0, axis=1))
    tensions = tensions.copy()
    # cables moving no coordinate (all on clamped nodes) hold nothing: scipy's nnls returns
    # uninitialised memory for an empty system
    tensions[controlled] = scipy.optimize.nnls(pulled[used], -rest[used])[0] if len(used) else 0.0
    return tensions


def _cable_tensions(rows, responses, controlled, violation, free_step, tensions):
    """Tensions of displacement-controlled cables for this Newton step, slack where negative.

    From their rows H_d (d, f) and responses K^-1 H_d^T (f, d), solves
    W lam = violation - H dx_free on the taut set (an active set on at most a few cables);
    returns the tensions and the full step dx_free + K^-1 H^T lam.
    """
    compliance = rows @ responses  # W_aa of eq. 4
    target = violation - rows @ free_step
    taut = np.ones(len(target), dtype=bool)
    for _ in range(2 ** len(target)):
        lam = np.zeros(len(target))
        if taut.any():
            lam[taut] = np.linalg.solve(compliance[np.ix_(taut, taut)], target[taut])
        predicted_gap = compliance @ lam - target  # > 0: cable would be shorter than asked
        negative = lam < -1e-12
        stretched = ~taut & (predicted_gap < -1e-12)
        if not negative.any() and not stretched.any():
            break
        taut = (taut & ~negative) | stretched
    tensions = tensions.copy()
    tensions[controlled] = lam
    return tensions, free_step + responses @ lam


def _line_search(state, current, step, tensions, applied, inputs, controlled, scale,
                 settings):
    """Backtrack along `step` until it decreases enough either the potential energy (with the
    cable tensions held) or the residual merit |r|^2 + (k |c|)^2 (Armijo, factor 1e-4).

    The energy test accepts the first Newton step from rest, where rotations briefly raise the
    residual; the residual test takes over near convergence, where energy changes drown in
    round-off. `current` is the evaluation at `state` (alpha = 0). Returns the new state, its
    evaluation and whether the full step was taken.
    """
    load_slope = float(applied @ step)  # the dead loads' work per unit alpha: f^T T step

    def merits(evaluation: _Evaluation, alpha: float) -> tuple[np.ndarray, float, float]:
        r = applied - evaluation.internal + evaluation.cable_rows.T @ tensions
        c = (inputs.values - evaluation.shortenings)[controlled]
        c = np.where(tensions[controlled] > 0.0, c, np.maximum(c, 0.0))  # slack: one-sided
        potential = evaluation.energy - alpha * load_slope - tensions @ evaluation.shortenings
        merit = float(r @ r + scale**2 * c @ c)
        return (r, potential if np.isfinite(potential) else np.inf,
                merit if np.isfinite(merit) else np.inf)

    residual, potential0, merit0 = merits(current, 0.0)
    slope = -float(residual @ step)  # d(potential)/d(alpha) at alpha = 0
    alpha = 1.0
    for _ in range(settings.max_backtracks):
        trial = state.moved(step, alpha)
        evaluation = _Evaluation.at(trial)
        _, potential, merit = merits(evaluation, alpha)
        energy_ok = slope < 0 and potential <= potential0 + 1e-4 * alpha * slope
        if energy_ok or merit <= (1.0 - 1e-4 * alpha) * merit0 or merit0 == 0.0:
            return trial, evaluation, alpha == 1.0
        alpha *= 0.5
    return trial, evaluation, False


# Equal steps of the cable inputs tried in turn by solve_by_continuation: a far corner of
# the actuation box folds the body further than one Newton run from a distant state reaches.
CONTINUATION_STEPS = (1, 2, 4, 8)


def solve_by_continuation(model: FEModel, controls: tuple[str, ...], target: np.ndarray,
                          solved: list[tuple[np.ndarray, np.ndarray]],
                          settings: SolverSettings = SolverSettings(),
                          step_counts: tuple[int, ...] = CONTINUATION_STEPS) -> Equilibrium:
    """The equilibrium at cable inputs `target` (a,) mm or N, from the nearest of the
    `solved` (inputs (a,), positions (n, 3) mm) pairs (rest when there are none), in 1, 2, 4
    or 8 (step_counts) equal steps of the inputs until Newton's method reaches every step.

    Raises the last SolverError when even the most steps fail.
    """
    target = np.asarray(target, dtype=float)
    if solved:
        origin, positions = min(solved, key=lambda pair: float(np.linalg.norm(pair[0] - target)))
    else:
        origin, positions = np.zeros_like(target), model.rest_nodes_mm
    last_error: SolverError | None = None
    for steps in step_counts:
        try:
            start = positions
            for k in range(1, steps + 1):
                values = origin + k / steps * (target - origin)
                equilibrium = solve_equilibrium(model, CableInputs(controls, values),
                                                start_mm=start, settings=settings)
                start = equilibrium.positions_mm
            return equilibrium
        except SolverError as error:
            last_error = error
    assert last_error is not None
    raise last_error
