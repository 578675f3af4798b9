"""Residual fields of a model with effects, and least squares over an effect's parameters.

Problem.fields(effects) predicts every state (FE solves warm-started from the nominal ones),
moves the predicted surface as the camera effects would show it, and measures each frame's
observed points against it: (t, s) mean normal residuals per frame and surface node, with the
point counts as weights. fit() runs Gauss-Newton on an effect's few free parameters with
secant sensitivities (one step per parameter, on every state), projected on the bounds, each
step checked on the exact residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.hypotheses import Hypothesis, physics_model
from softforce_cli.diagnosis.observations import Observations
from softforce_cli.diagnosis.prediction import Predictor
from softforce_cli.diagnosis.residuals import node_residuals, surface_normals
from softforce_cli.diagnosis.states import States
from softforce_cli.errors import SolverError
from softforce_cli.model.effects import (
    Effect,
    FrameContext,
    effective_actuation,
    effects_of_kind,
    observed_points_robot,
)
from softforce_cli.model.robot import Robot

GAUSS_NEWTON_STEPS = 3


@dataclass(frozen=True, eq=False)
class Fields:
    """Residual fields: mean_mm (t, s) per frame and surface node, count (t, s) weights."""

    mean_mm: np.ndarray
    count: np.ndarray

    def rms(self, frames: np.ndarray | None = None) -> float:
        mean, count = (self.mean_mm, self.count) if frames is None else (
            self.mean_mm[frames], self.count[frames])
        return float(np.sqrt(np.sum(count * mean**2) / max(count.sum(), 1)))


@dataclass
class Problem:
    """Everything a residual evaluation needs; caches nothing but the predictor's starts."""

    robot: Robot
    observations: Observations
    states: States
    contexts: list[FrameContext]
    predictor: Predictor
    robot_from_camera: RigidTransform
    evaluations: int = field(default=0)
    # predictions by their physics and actuation effects (sensor effects only move them)
    _cache: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def surface_nodes(self) -> np.ndarray:
        return self.robot.mesh.surface_nodes

    def positions(self, effects: tuple[Effect, ...]) -> np.ndarray:
        """(S, n_mesh, 3) predicted mesh nodes per state, as the camera shows them."""
        key = repr(sorted((e.label, sorted(e.parameters.items()))
                          for e in effects_of_kind(effects, "physics", "actuation")))
        out = self._cache.get(key)
        if out is None:
            out = self._cache.setdefault(key, self._physics_positions(effects))
        sensor = effects_of_kind(effects, "sensor")
        if sensor:
            shape = out.shape
            out = observed_points_robot(out.reshape(-1, 3), sensor,
                                        self.robot_from_camera).reshape(shape)
        self.evaluations += 1
        return out

    def _physics_positions(self, effects: tuple[Effect, ...]) -> np.ndarray:
        names = [spec.name for spec in self.robot.cable_specs]
        actuation = effective_actuation(effects, self.contexts, names)  # (t, a)
        first = np.unique(self.states.of_frame, return_index=True)[1]
        per_state = actuation[first]
        physics = effects_of_kind(effects, "physics")
        creep = any(e.name == "viscoelastic_creep" for e in physics)
        if creep:
            out = np.stack([self.predictor.positions_with(
                physics_model(self.robot, physics, hold), per_state, [s])[0]
                for s, hold in enumerate(self.states.hold_s)])
        else:
            out = self.predictor.positions_with(physics_model(self.robot, physics), per_state)
        return out

    def fields(self, effects: tuple[Effect, ...]) -> Fields:
        positions = self.positions(effects)
        faces = self.robot.mesh.surface_faces
        normals = [surface_normals(p, faces) for p in positions]
        frames = self.observations.frames
        mean = np.zeros((len(frames), len(self.surface_nodes)))
        count = np.zeros_like(mean)
        for i, frame in enumerate(frames):
            s = self.states.of_frame[i]
            field_ = node_residuals(frame.points_mm, positions[s], self.surface_nodes,
                                    normals[s])
            mean[i], count[i] = field_.mean_mm, field_.count
        return Fields(mean, count)


@dataclass(frozen=True, eq=False)
class Fit:
    """A fitted hypothesis.

    values    : (k,) fitted free parameters.
    fields    : the residual fields at values.
    jacobian  : (k, t, s) d(mean residual)/d(parameter) at values (secant).
    """

    hypothesis: Hypothesis
    values: np.ndarray
    fields: Fields
    jacobian: np.ndarray

    @property
    def effect(self) -> Effect:
        return self.hypothesis.effect(self.values)


def secant_jacobian(problem: Problem, hypothesis: Hypothesis, values: np.ndarray,
                    base: Fields, others: tuple[Effect, ...]) -> np.ndarray:
    """(k, t, s): residual change per unit of each free parameter, by one secant step each
    (towards the interior of the bounds)."""
    columns = []
    for j, step in enumerate(hypothesis.step):
        sign = 1.0 if values[j] + step <= hypothesis.upper[j] else -1.0
        for _ in range(3):  # a step the solver cannot follow is quartered
            trial = values.copy()
            trial[j] += sign * step
            try:
                shifted = problem.fields((*others, hypothesis.effect(trial)))
                break
            except SolverError:
                step /= 4
        else:
            raise SolverError(f"{hypothesis.label}: no equilibrium near the neutral model")
        columns.append((shifted.mean_mm - base.mean_mm) / (sign * step))
    return np.array(columns)


def linear_step(mean: np.ndarray, weights: np.ndarray, jacobian: np.ndarray,
                rows: np.ndarray | None = None, damping: float = 1e-9) -> np.ndarray:
    """(k,) the weighted least-squares step minimising sum w (mean + J d)^2 over frame rows
    (default all); mean, weights (t, s), jacobian (k, t, s)."""
    if rows is not None:
        mean, weights, jacobian = mean[rows], weights[rows], jacobian[:, rows]
    k = len(jacobian)
    flat = jacobian.reshape(k, -1)
    w = weights.ravel()
    normal = (flat * w) @ flat.T
    normal += damping * np.trace(normal) / max(k, 1) * np.eye(k)
    return -np.linalg.solve(normal, (flat * w) @ mean.ravel())


def fit(problem: Problem, hypothesis: Hypothesis, others: tuple[Effect, ...] = (),
        base: Fields | None = None) -> Fit:
    """Gauss-Newton from the neutral values with secant sensitivities, each step kept only
    when the exact weighted residual falls (else halved)."""
    values = hypothesis.start.astype(float).copy()
    current = base if base is not None else problem.fields((*others, hypothesis.effect(values)))
    jacobian = secant_jacobian(problem, hypothesis, values, current, others)
    for _ in range(GAUSS_NEWTON_STEPS):
        step = linear_step(current.mean_mm, current.count, jacobian)
        for _ in range(4):
            trial = np.clip(values + step, hypothesis.lower, hypothesis.upper)
            try:
                candidate = problem.fields((*others, hypothesis.effect(trial)))
            except SolverError:  # too far for Newton: a shorter step
                step = step / 2
                continue
            if candidate.rms() < current.rms():
                break
            step = step / 2
        else:
            break
        # Broyden's update keeps the secant model consistent with the step just taken
        taken = trial - values
        change = candidate.mean_mm - current.mean_mm
        predicted = np.tensordot(taken, jacobian, axes=1)
        jacobian = jacobian + np.einsum("k,ts->kts", taken / (taken @ taken), change - predicted)
        values, current = trial, candidate
        if np.all(np.abs(taken) < 0.02 * hypothesis.step):
            break
    return Fit(hypothesis, values, current, jacobian)
