"""The mesh's own uncertainty at a fitted effect: how far the robot's two quadratic elements
(P2, too stiff on a coarse mesh, and P2-P0, a little too soft: together they bracket the
converged body, docs/locking.md) disagree with the effect's fitted values, along the surface
normals where the camera saw the robot.

solves.element_bracket measures it once, unactuated and without effects; it grows where an
effect takes the body towards an instability. A Diamond 30% softer than its file hangs near
its buckling load under gravity: there its two elements disagree by 12-38 mm in what changes
across the recording's states (0.1-0.4 mm at the file's stiffness), and the coarse P2 model
follows another branch than a finer body (docs/diagnosis.md, "Limits"). What a fit leaves
well inside that disagreement is the mesh's, not missing physics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.refit import ExactModel, Prediction, Refit
from softforce_cli.diagnosis.residuals import (
    Field,
    node_rms,
    node_systematic_mm,
    surface_normals,
)
from softforce_cli.diagnosis.selection import systematic_mm

# What a named effect may leave, as a share of the elements' disagreement at its fit, to
# leave it to the mesh. The coarse P2 Diamond is about a fifth of the bracket from the
# 6.5 mm P2 body: 0.25-0.34 mm against 1.29-1.60 mm at the file's stiffness, 0.73-7.8 mm
# against 4.7-56 mm at 0.7 of it (the states of docs/diagnosis.md's study, 2026-12-01), so
# half is a margin of two.
MESH_REST_SHARE = 0.5


@dataclass(frozen=True)
class FitBracket:
    """The two elements' disagreement at a fit, along the observed surface's normals,
    weighted as the residual's entries, and what the fit leaves of the residual, both over
    the frames of the states where the other element has an equilibrium near the fit's: what
    changes across frames (each node's mean over the frames removed, RMS) and what every
    frame shares (those means' RMS), in mm; the states solved, and those without such an
    equilibrium (there the two elements of the mesh disagree beyond measure: the fit's rest
    there is left to the mesh)."""

    relative_mm: float
    static_mm: float
    rest_relative_mm: float
    rest_static_mm: float
    groups: int
    unsolved: int

    def leaves_across(self, floor_mm: float, share: float = 1.0) -> bool:
        """Whether what is left across frames, above the noise floor, is within `share` of
        what the elements disagree by there."""
        return systematic_mm(self.rest_relative_mm, floor_mm) <= share * self.relative_mm

    def leaves_static(self, share: float = 1.0) -> bool:
        """Whether what every frame shares is within `share` of the elements' disagreement."""
        return self.rest_static_mm <= share * self.static_mm

    def explains_rest(self, floor_mm: float, relative_named: bool, static_named: bool) -> bool:
        """Whether what the fit leaves, across frames (above the noise floor) and in every
        frame, is within MESH_REST_SHARE of this disagreement, where it is too much to name
        the fit on its own (`relative_named`, `static_named`: held-out, all frames)."""
        return ((relative_named or self.leaves_across(floor_mm, MESH_REST_SHARE))
                and (static_named or self.leaves_static(MESH_REST_SHARE)))

    def explains_static_beyond(self, nominal: FitBracket, floor_mm: float,
                               static_named: bool) -> bool:
        """Whether the fit's rest is the mesh's where the nominal model's mismatch (`nominal`,
        the nominal_bracket) exceeds the mesh's own error only in what every frame shares:
        what changes across frames then asked for no explanation, and the fit may leave there
        as much as the elements disagree by (above the noise floor), not MESH_REST_SHARE of
        it, with what every frame shares within explains_rest's bound (`static_named`: within
        the mesh's error at rest). A camera moved 3 mm sideways in the converged body, seen at
        640x480: 0.12 mm across frames above the noise both before and after its fit, where
        the elements disagree by 0.17-0.18 mm; 1.6 mm static before, 0.27 mm after."""
        return (nominal.leaves_across(floor_mm) and not nominal.leaves_static()
                and self.leaves_across(floor_mm)
                and (static_named or self.leaves_static(MESH_REST_SHARE)))

    def holds_mismatch(self, floor_mm: float) -> bool:
        """Whether what is left is no larger than the disagreement itself, in both parts: the
        two elements bracket the converged body, so the robot's element is no further from it
        than from the other element. A bound for the nominal model's mismatch
        (nominal_bracket); a fit is held to MESH_REST_SHARE."""
        return self.leaves_across(floor_mm) and self.leaves_static()

    def as_dict(self) -> dict:
        return {"relative_mm": round(self.relative_mm, 3), "static_mm": round(self.static_mm, 3),
                "rest_relative_mm": round(self.rest_relative_mm, 3),
                "rest_static_mm": round(self.rest_static_mm, 3),
                "states_without_equilibrium": self.unsolved}


def fit_bracket(exact: ExactModel, fitted: Refit) -> FitBracket | None:
    """The FitBracket at a refit's last exact evaluation (the other element solved once per
    group of frames, from this element's equilibrium), with its physics alone (a camera's
    shift is not the mesh's: both elements are solved again without it); None for a camera
    alone or fewer than two groups solved."""
    candidate, values, prediction, field = (fitted.candidate, fitted.evaluated,
                                            fitted.prediction, fitted.field)
    if candidate.moves_camera:
        kept = [h.kind != "sensor" for h in candidate.hypotheses]
        if not any(kept):
            return None
        parts = candidate.split(values)
        candidate = Candidate(tuple(h for h, k in zip(candidate.hypotheses, kept, strict=True)
                                    if k))
        values = np.concatenate([v for v, k in zip(parts, kept, strict=True) if k])
        solve = exact.followed if prediction.followed else exact.predict
        prediction = solve(candidate, values)
    return _bracket(exact, exact.other_element(candidate, values, prediction), prediction,
                    field)


def nominal_bracket(exact: ExactModel) -> FitBracket | None:
    """The FitBracket of the nominal model (no effect): the two elements' disagreement at
    the robot file's own physics, and the nominal residual as what is left; None with fewer
    than two groups solved."""
    prediction = exact.nominal_prediction
    return _bracket(exact, exact.other_element(None, None, prediction), prediction,
                    exact.nominal_field)


def _bracket(exact: ExactModel, others: list[np.ndarray | None], prediction: Prediction,
             field: Field) -> FitBracket | None:
    """The FitBracket of a prediction, the other element's nodes per group (None: not
    solved) and the residual field left there."""
    solved = np.array([positions is not None for positions in others])
    if solved.sum() < 2:
        return None
    faces = exact.solutions.robot.mesh.surface_faces
    accurate = prediction.positions_mm
    moved = np.stack([np.zeros_like(accurate[g]) if positions is None
                      else (positions - accurate[g])
                      * surface_normals(accurate[g], faces)
                      for g, positions in enumerate(others)]).sum(axis=-1)  # (G, n)
    group = prediction.of_frame[field.frame]
    kept = solved[group]
    rest = Field(field.frame[kept], field.node[kept], field.mean_mm[kept], field.weight[kept])
    apart = Field(rest.frame, rest.node, moved[group[kept], rest.node], rest.weight)
    node_count = accurate.shape[1]
    return FitBracket(*_across_and_static(apart, node_count),
                      *_across_and_static(rest, node_count), int(solved.sum()),
                      int((~solved).sum()))


def _across_and_static(field: Field, node_count: int) -> tuple[float, float]:
    """(what changes across frames, what every frame shares) of a field's entries (mm): the
    RMS with each node's mean removed, and the RMS of those means (residuals.static_mm)."""
    mean, weight = node_systematic_mm(field, node_count)
    return field.rms(shift=mean[field.node]), node_rms(mean, weight, weight > 0)
