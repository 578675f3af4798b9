"""The whole diagnosis: observations -> states -> nominal residuals -> every hypothesis fitted
and validated -> forward selection of up to two effects -> verdict and location."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.fitting import Fields, Fit, Problem, fit
from softforce_cli.diagnosis.hypotheses import Hypothesis, hypotheses
from softforce_cli.diagnosis.observations import Observations
from softforce_cli.diagnosis.prediction import Predictor, mesh_correction
from softforce_cli.diagnosis.selection import (
    UNEXPLAINED_MM,
    HeldOut,
    clear_improvement,
    confidence_intervals,
    effective_sample_size,
    held_out,
    noise_floor_mm,
    systematic_mm,
)
from softforce_cli.diagnosis.states import States, group_states, trajectory_segments
from softforce_cli.errors import SolverError
from softforce_cli.model.effects import frame_contexts
from softforce_cli.model.regions import region_labels, region_names
from softforce_cli.model.robot import Robot

# Two effects' held-out RMS closer than this (mm) cannot be told apart by this data.
INDISTINCT_MM = 0.1
# Candidates tried as the second effect of forward selection.
SECOND_CANDIDATES = 3
Stage = Callable[[str, int, int | None], None]


@dataclass(frozen=True)
class Candidate:
    """One hypothesis fitted and validated."""

    fit: Fit
    heldout: HeldOut
    ci95: np.ndarray
    accepted: bool

    @property
    def label(self) -> str:
        return self.fit.hypothesis.label


@dataclass(frozen=True)
class Diagnosis:
    """The result: verdict, noise floor, ranked candidates (best per effect), selected effects,
    location, and the evidence numbers."""

    verdict: str
    noise_floor_mm: float
    ranked: tuple[Candidate, ...]
    selected: tuple[Candidate, ...]
    groups: tuple[tuple[str, ...], ...]
    location: dict
    evidence: dict
    nominal: Fields
    final: Fields
    states: States
    observations: Observations = field(repr=False)


def diagnose_observations(robot: Robot, observations: Observations,
                          robot_from_camera: RigidTransform,
                          stage: Stage | None = None) -> Diagnosis:
    """Fit every hypothesis to the observations and choose what the data supports."""
    report = stage or (lambda name, done, total: None)
    contexts = frame_contexts(observations.times_s, observations.actuations)
    hold_needed = True
    states = group_states_from(contexts, hold_needed)
    reference = int(np.argmin(np.abs(states.actuation).sum(axis=1)))
    report("mesh correction", 0, 1)
    correction, accurate = mesh_correction(robot, states.actuation[reference])
    report("mesh correction", 1, 1)
    predictor = Predictor(robot, states.actuation, reference, correction)
    predictor.warm(lambda done, total: report("states", done, total))
    problem = Problem(robot, observations, states, contexts, predictor, robot_from_camera)
    nominal = problem.fields(())
    uncorrected = _without_correction(problem)
    floor = noise_floor_mm(nominal, states.of_frame)
    segments = trajectory_segments(states, np.array([f.recording for f in observations.frames]))
    n_eff = effective_sample_size(nominal)
    candidates = hypotheses(robot)
    fitted: list[Candidate] = []
    skipped: list[str] = []
    for i, hypothesis in enumerate(candidates):
        report("fitting", i, len(candidates))
        try:
            fitted.append(_candidate(problem, hypothesis, nominal, segments, floor, n_eff))
        except SolverError as error:  # this effect cannot be evaluated on this robot
            skipped.append(f"{hypothesis.label}: {error}")
    report("fitting", len(candidates), len(candidates))
    ranked = _best_per_effect(fitted)
    selected, final = _forward(problem, ranked, nominal, segments, floor, n_eff, report)
    before = nominal.rms()
    after = final.rms()
    remaining = systematic_mm(after, floor)
    if selected and remaining > UNEXPLAINED_MM and (
            systematic_mm(before, floor) - remaining) < 0.5 * systematic_mm(before, floor):
        verdict = "unexplained"
    elif selected:
        verdict = selected[0].fit.hypothesis.name
    else:
        verdict = "unexplained" if remaining > UNEXPLAINED_MM else "none"
    groups = _groups(ranked, selected)
    location = _location(robot, final if verdict == "unexplained" else nominal, floor,
                         selected)
    evidence = {
        "frames": len(observations.frames), "frames_skipped": observations.skipped,
        "states": states.count, "segments": int(segments.max() + 1),
        "effective_frames": round(n_eff, 1),
        "element": robot.element_name, "mesh_correction_element": accurate,
        "mesh_correction_rms_mm": round(_surface_rms(correction, robot), 3),
        "rms_without_mesh_correction_mm": round(uncorrected.rms(), 3),
        "rms_nominal_mm": round(before, 3), "rms_final_mm": round(after, 3),
        "systematic_nominal_mm": round(systematic_mm(before, floor), 3),
        "systematic_final_mm": round(remaining, 3),
        "fe_evaluations": problem.evaluations,
        "hypotheses_not_evaluated": skipped,
    }
    return Diagnosis(verdict, floor, tuple(ranked), tuple(selected), groups, location,
                     evidence, nominal, final, states, observations)


def group_states_from(contexts, use_hold: bool) -> States:
    """States from model.effects frame contexts (loading direction and hold time)."""
    from softforce_cli.diagnosis.states import FrameContexts

    return group_states(FrameContexts(
        np.array([c.actuation for c in contexts]), np.array([c.loading for c in contexts]),
        np.array([c.hold_s for c in contexts])), use_hold)


def _without_correction(problem: Problem) -> Fields:
    saved = problem.predictor.correction
    problem.predictor.correction = None
    problem._cache.clear()
    try:
        return problem.fields(())
    finally:
        problem.predictor.correction = saved
        problem._cache.clear()


def _candidate(problem, hypothesis: Hypothesis, nominal: Fields, segments, floor, n_eff,
               others=()) -> Candidate:
    fitted = fit(problem, hypothesis, others, nominal if not others else None)
    result = held_out(fitted, nominal, segments)
    return Candidate(fitted, result, confidence_intervals(fitted, n_eff),
                     clear_improvement(result, floor))


def _best_per_effect(fitted: list[Candidate]) -> list[Candidate]:
    best: dict[str, Candidate] = {}
    for c in fitted:
        name = c.fit.hypothesis.name
        if name not in best or c.heldout.rms_after_mm < best[name].heldout.rms_after_mm:
            best[name] = c
    return sorted(best.values(), key=lambda c: c.heldout.rms_after_mm)


def _forward(problem, ranked, nominal, segments, floor, n_eff, report):
    """The best accepted effect, then the best second one that clearly improves on it."""
    accepted = [c for c in ranked if c.accepted]
    if not accepted:
        return [], nominal
    first = accepted[0]
    selected, final = [first], first.fit.fields
    others = [c for c in ranked if c is not first][:SECOND_CANDIDATES]
    seconds = []
    for i, other in enumerate(others):
        report("second effect", i, len(others))
        seconds.append(_candidate(problem, other.fit.hypothesis, final, segments, floor, n_eff,
                                  (first.fit.effect,)))
    report("second effect", len(others), len(others))
    clear = [c for c in seconds if c.accepted]
    if clear:
        second = min(clear, key=lambda c: c.heldout.rms_after_mm)
        selected.append(second)
        final = second.fit.fields
    return selected, final


def _groups(ranked, selected) -> tuple[tuple[str, ...], ...]:
    """Effects whose held-out residual is within INDISTINCT_MM of a selected one."""
    groups = []
    for chosen in selected:
        near = [c.fit.hypothesis.name for c in ranked if c.accepted and c is not chosen and abs(
            c.heldout.rms_after_mm - chosen.heldout.rms_after_mm) < INDISTINCT_MM]
        if near:
            groups.append((chosen.fit.hypothesis.name, *near))
    return tuple(groups)


def node_systematic_mm(fields: Fields) -> np.ndarray:
    """(s,) per surface node: the weighted mean residual over all frames (mm)."""
    total = fields.count.sum(axis=0)
    return np.divide((fields.count * fields.mean_mm).sum(axis=0), total,
                     out=np.zeros_like(total), where=total > 0)


def _location(robot: Robot, fields: Fields, floor: float, selected) -> dict:
    """Regions, cables and nodes where the residual concentrates (or the selected effect's
    target)."""
    names = region_names(robot)
    surface = robot.mesh.surface_nodes
    labels = region_labels(robot, robot.mesh.nodes_mm[surface])
    node_mean = node_systematic_mm(fields)
    seen = fields.count.sum(axis=0)
    per_region = {}
    for i, name in enumerate(names):
        mask = (labels == i) & (seen > 0)
        if mask.any():
            per_region[name] = float(np.sqrt(np.average(node_mean[mask] ** 2,
                                                        weights=seen[mask])))
    overall = float(np.sqrt(np.average(node_mean**2, weights=np.maximum(seen, 1e-12))))
    regions = sorted((n for n, v in per_region.items() if v > 1.5 * overall),
                     key=lambda n: -per_region[n])
    cables = [spec.name for spec in robot.cable_specs]
    targets = [c.fit.hypothesis.target for c in selected if c.fit.hypothesis.target]
    if targets:
        regions = list(dict.fromkeys([*targets, *regions]))
    top = surface[np.argsort(-np.abs(node_mean))[:10]]
    return {"regions": regions, "cables": [r for r in regions if r in cables],
            "nodes": [int(n) for n in top],
            "region_rms_mm": {k: round(v, 3) for k, v in per_region.items()}}


def _surface_rms(correction: np.ndarray, robot: Robot) -> float:
    values = correction[robot.mesh.surface_nodes]
    return float(np.sqrt(np.mean(np.sum(values**2, axis=1))))
