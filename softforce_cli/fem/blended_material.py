"""A material whose energy is a blend of two hyperelastic laws: psi = (1 - b) psi_1 + b psi_2.

Both laws agree to first order at F = I (fem.materials), so the blend keeps the small-strain
response and moves only the large-strain one: the material_nonlinearity effect
(model.effects) with b from 0 (the first law) to 1 (the second). Energy, stress and tangent
are the same blend, so the tangent stays the exact Hessian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.fem.materials import Material


@dataclass(frozen=True)
class BlendedMaterial:
    """(1 - blend) first + blend second; `first` and `second` share E and nu.

    Has Material's interface (law, young_modulus_mpa, poisson_ratio, lame, energy_and_stress,
    stress_and_tangent), so FEModel takes it as its material.
    """

    first: Material
    second: Material
    blend: float

    def __post_init__(self) -> None:
        if (self.first.young_modulus_mpa, self.first.poisson_ratio) != (
                self.second.young_modulus_mpa, self.second.poisson_ratio):
            raise ValueError("blended laws must share Young's modulus and Poisson's ratio")
        if not 0.0 <= self.blend <= 1.0:
            raise ValueError(f"blend {self.blend} must be in [0, 1]")

    @property
    def law(self) -> str:
        return f"{self.first.law}+{self.blend:g}*{self.second.law}"

    @property
    def young_modulus_mpa(self) -> float:
        return self.first.young_modulus_mpa

    @property
    def poisson_ratio(self) -> float:
        return self.first.poisson_ratio

    @property
    def lame(self) -> tuple[float, float]:
        return self.first.lame

    def energy_and_stress(self, F: np.ndarray, part: str = "all"
                          ) -> tuple[np.ndarray, np.ndarray]:
        """Energy density (m,) MPa and P (m, 3, 3) MPa at F (m, 3, 3)."""
        e1, p1 = self.first.energy_and_stress(F, part)
        e2, p2 = self.second.energy_and_stress(F, part)
        b = self.blend
        return (1 - b) * e1 + b * e2, (1 - b) * p1 + b * p2

    def stress_and_tangent(self, F: np.ndarray, part: str = "all"
                           ) -> tuple[np.ndarray, np.ndarray]:
        """P (m, 3, 3) MPa and A (m, 3, 3, 3, 3) MPa at F (m, 3, 3)."""
        p1, a1 = self.first.stress_and_tangent(F, part)
        p2, a2 = self.second.stress_and_tangent(F, part)
        b = self.blend
        return (1 - b) * p1 + b * p2, (1 - b) * a1 + b * a2
