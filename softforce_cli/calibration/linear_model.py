"""The FE model linearised at a configuration and projected on markers and cables (eq. 3-6).

    markers       m      = W_ea lam + delta_e_free                       (3)
    cables        delta  = W_aa lam + delta_a_free                       (4)
    configuration x'     = x + dx_free + K^-1 H_a^T lam                  (6)

One factorisation of K(x) gives all three for any tensions lam, so the calibration loop tries
tensions, fits, and moves the configuration without another solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.compliance import linearize
from softforce_cli.fem.linear_solver import Factorization
from softforce_cli.fem.model import FEModel

# A displacement-controlled cable whose solved tension is below -this goes slack (N).
SLACK_ROUNDOFF_N = 1e-12


@dataclass(frozen=True)
class LinearModel:
    """Eq. 3, 4 and 6 at one configuration x, for k markers and a cables.

    W_ea (3k, a) mm/N, delta_e_free (3k,) mm, W_aa (a, a) mm/N, delta_a_free (a,) mm;
    free_positions_mm (n, 3): x + dx_free; responses (3n, a) mm/N: K^-1 H_a^T;
    factorization: of K(x), reusable for the next configuration's symbolic analysis.
    """

    W_ea: np.ndarray
    delta_e_free: np.ndarray
    W_aa: np.ndarray
    delta_a_free: np.ndarray
    free_positions_mm: np.ndarray
    responses: np.ndarray
    factorization: Factorization

    def markers(self, tensions_n: np.ndarray) -> np.ndarray:
        """(k, 3) marker positions for tensions (a,) (eq. 3)."""
        return (self.W_ea @ tensions_n + self.delta_e_free).reshape(-1, 3)

    def shortenings(self, tensions_n: np.ndarray) -> np.ndarray:
        """(a,) cable shortenings in mm for tensions (a,) (eq. 4)."""
        return self.W_aa @ tensions_n + self.delta_a_free

    def positions(self, tensions_n: np.ndarray) -> np.ndarray:
        """(n, 3) configuration after the update of eq. 6 with tensions (a,)."""
        return self.free_positions_mm + (self.responses @ tensions_n).reshape(-1, 3)

    def inputs(self, control: tuple[str, ...], tensions_n: np.ndarray) -> CableInputs:
        """The cable inputs that tensions (a,) amount to: the tension itself for a
        force-controlled cable, the predicted shortening for a displacement-controlled one."""
        displacement = np.array([c == "displacement" for c in control])
        return CableInputs(control, np.where(displacement, self.shortenings(tensions_n),
                                             tensions_n))

    def tensions(self, inputs: CableInputs) -> np.ndarray:
        """(a,) tensions that meet `inputs` on this linearisation.

        Force-controlled cables pull with their value; displacement-controlled ones take the
        tension that makes eq. 4 give their shortening, or go slack (0) where that tension
        would push: an active set over the few cables, as the static solver does.
        """
        controlled = inputs.displacement_controlled
        tensions = np.where(controlled, 0.0, inputs.values)
        if not controlled.any():
            return tensions
        W = self.W_aa[np.ix_(controlled, controlled)]
        wanted = (inputs.values - self.delta_a_free - self.W_aa[:, ~controlled]
                  @ tensions[~controlled])[controlled]
        taut = np.ones(len(wanted), dtype=bool)
        for _ in range(2 ** len(wanted)):
            lam = np.zeros(len(wanted))
            if taut.any():
                lam[taut] = np.linalg.solve(W[np.ix_(taut, taut)], wanted[taut])
            pushing = lam < -SLACK_ROUNDOFF_N
            stretched = ~taut & (W @ lam < wanted - 1e-12)  # slack cable longer than allowed
            if not pushing.any() and not stretched.any():
                break
            taut = (taut & ~pushing) | stretched
        tensions[controlled] = np.maximum(lam, 0.0)
        return tensions


def linear_model(model: FEModel, positions_mm: np.ndarray, tensions_n: np.ndarray,
                 marker_rows: sp.spmatrix, factorization: Factorization | None = None
                 ) -> LinearModel:
    """Linearise at (positions (n, 3), tensions (a,)) and project on markers (rows H_e)."""
    lin = linearize(model, positions_mm, tensions_n, factorization=factorization)
    actuators = model.cable_jacobian(positions_mm)
    responses = lin.responses(actuators)
    free_positions = positions_mm + lin.free_motion_mm
    return LinearModel(
        W_ea=np.asarray(marker_rows @ responses),
        delta_e_free=np.asarray(marker_rows @ free_positions.ravel()),
        W_aa=np.asarray(actuators @ responses),
        delta_a_free=model.cable_shortenings(positions_mm)
        + np.asarray(actuators @ lin.free_motion_mm.ravel()),
        free_positions_mm=free_positions,
        responses=responses,
        factorization=lin.factorization,
    )
