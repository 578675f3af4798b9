"""The first-order model of every state: predicted surface, normals and normal sensitivities.

Basis holds, per state, what the screening needs at the surface nodes: the nominal
prediction (S, n, 3), its unit normals and the normal projection of every sensitivity column
(S, C, n). inputs_for(field) indexes them at a field's entries (diagnosis.hypotheses.Inputs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.background import Table
from softforce_cli.diagnosis.hypotheses import Inputs
from softforce_cli.diagnosis.residuals import Field, surface_normals
from softforce_cli.diagnosis.sensitivities import ColumnSet
from softforce_cli.diagnosis.support import SupportBasis
from softforce_cli.model.effects import FrameContext


@dataclass(frozen=True, eq=False)
class Basis:
    """predicted_mm (S, n, 3), normals (S, n, 3), normal_columns (S, C, n) mm per unit,
    state_inputs (S, a), cable_columns (S, n, a, 3) mm per unit input (node-major: an
    entry gathers its node's a columns in one read); table: the observed
    table (diagnosis.background) or None; support: the plate's screening data
    (diagnosis.support) or None."""

    predicted_mm: np.ndarray
    normals: np.ndarray
    normal_columns: np.ndarray
    column_set: ColumnSet
    of_frame: np.ndarray
    contexts: tuple[FrameContext, ...]
    cables: tuple[str, ...]
    robot_from_camera: RigidTransform
    state_inputs: np.ndarray
    cable_columns: np.ndarray
    table: Table | None = None
    support: SupportBasis | None = None

    def inputs_for(self, field: Field) -> Inputs:
        state = self.of_frame[field.frame]
        return Inputs(field, state, self.normals[state, field.node],
                      self.predicted_mm[state, field.node],
                      self.normal_columns[state, :, field.node].T, self.column_set,
                      self.contexts, self.cables, self.robot_from_camera, self.predicted_mm,
                      self.state_inputs, self.cable_columns, self.table, self.support)


def build_basis(predicted_mm: np.ndarray, columns: np.ndarray, surface_faces: np.ndarray,
                column_set: ColumnSet, of_frame: np.ndarray,
                contexts: tuple[FrameContext, ...], cables: tuple[str, ...],
                robot_from_camera: RigidTransform, state_inputs: np.ndarray,
                table: Table | None = None, support: SupportBasis | None = None) -> Basis:
    """From the predictions (S, n, 3), the sensitivity columns (S, C, n, 3), the states'
    inputs (S, a), the observed table and the plate's screening data."""
    normals = np.stack([surface_normals(p, surface_faces) for p in predicted_mm])
    projected = np.einsum("scni,sni->scn", columns, normals)
    cable = [column_set.index(f"cable.{name}") for name in cables]
    return Basis(predicted_mm, normals, projected, column_set, of_frame, contexts, cables,
                 robot_from_camera, np.asarray(state_inputs, dtype=float),
                 np.ascontiguousarray(columns[:, cable].transpose(0, 2, 1, 3)), table, support)
