"""The coordinates a static solve and a linearisation work in, for full and reduced models.

Both models describe a configuration by full node positions x (n, 3), which is what every
caller sees; the solver works in c generalised coordinates with x = x_0 + T q:

- the full model's T selects the free dofs (q are the free nodal coordinates), and its
  tangent is the sparse K(x) over them, factorised by fem.linear_solver;
- a reduced model's T = V is a basis (3n, r), and its tangent V^T K(x) V is dense (r, r)
  (fem.reduction.reduced_model).

fem.statics and fem.compliance are written once against this protocol: residuals are
T^T (f_ext - g(x) + H^T lam), cable rows are H T, and a solution dq lifts to T dq. A static
solve moves through `State`s, configurations that evaluate forces, tangent and cables from q
without forming the node positions (a reduced model's lift V q reads all of V, more than
the rest of an evaluation); its Equilibrium keeps the final State and lifts it when its
node positions are first read (fem.statics). A sensing loop holds its
configuration as a State too (estimation.linear_model) and asks it for the few nodes it
looks at (State.nodes_mm), so a reduced model never lifts there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
import scipy.sparse as sp

from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.linear_solver import Factorization

if TYPE_CHECKING:
    from softforce_cli.fem.model import FEModel
    from softforce_cli.fem.statics import PointLoads


class Factor(Protocol):
    """A factorised tangent: solve() takes (c,) or (c, k); refactor() a new tangent."""

    def solve(self, rhs: np.ndarray) -> np.ndarray: ...

    def refactor(self, matrix) -> Factor: ...


class State(Protocol):
    """A configuration x = x_0 + T q that a static solve moves through (fem.statics)."""

    @property
    def positions_mm(self) -> np.ndarray:
        """(n, 3) mm: the node positions (lifted when first asked for)."""
        ...

    def moved(self, step: np.ndarray, alpha: float) -> State:
        """The configuration x + alpha T step, for step (c,)."""
        ...

    def energy_and_forces(self) -> tuple[float, np.ndarray]:
        """Elastic energy (mJ) and T^T g(x) (c,) N."""
        ...

    def tangent(self, tensions_n: np.ndarray):
        """T^T (K(x) + K_cables) T (c, c) N/mm for tensions (a,) N (the forces are known from
        energy_and_forces)."""
        ...

    def forces_and_tangent(self, tensions_n: np.ndarray):
        """T^T g(x) (c,) N and T^T (K(x) + K_cables) T (c, c) N/mm: a linearisation's two
        evaluations in one pass of the law."""
        ...

    def cables(self) -> tuple[np.ndarray, np.ndarray]:
        """Cable shortenings (a,) mm and their rows H T (a, c), dense."""
        ...

    def nodes_mm(self, nodes: np.ndarray) -> np.ndarray:
        """(k, 3) mm: the positions of some nodes (k,), without lifting the others."""
        ...

    def reactions(self, external_n: np.ndarray, tensions_n: np.ndarray) -> np.ndarray:
        """(k, 3) N the supports exert on the clamped nodes, under dead loads external_n
        (n, 3) N (gravity and point loads) and cable tensions (a,) N."""
        ...


class Coordinates(Protocol):
    """Generalised coordinates q of a model, x = x_0 + T q (T: (3n, c))."""

    @property
    def size(self) -> int: ...

    def lift(self, values: np.ndarray) -> np.ndarray:
        """T v: (c,) or (c, k) -> (3n,) or (3n, k)."""
        ...

    def project(self, vectors: np.ndarray) -> np.ndarray:
        """T^T v: (3n,) or (3n, k) -> (c,) or (c, k)."""
        ...

    def project_rows(self, rows) -> np.ndarray:
        """H T: rows (k, 3n), dense or sparse -> (k, c), sparse only for sparse rows of the
        full model."""
        ...

    def project_loads(self, loads: PointLoads | None) -> np.ndarray:
        """T^T (gravity + loads) (c,) N: the dead loads in these coordinates."""
        ...

    # A static solve ends when its Newton step's largest coordinate is below this (mm),
    # unless its settings ask for another tolerance (fem.statics.SolverSettings)
    step_tolerance_mm: float
    # Whether a static solution keeps its last factorised tangent, for a next solve that
    # continues from it (fem.statics.Equilibrium.tangent): a reduced model's dense LU is
    # r x r; a full P2 model's sparse factor is 50-120 MB (the 47,520-dof truth Diamond),
    # which every cached solution would hold (simulate caches its truth states).
    keeps_tangent: bool

    def state(self, positions_mm: np.ndarray | None = None) -> State:
        """The configuration of the form x_0 + T q nearest to positions (n, 3) (None: the
        rest configuration), to start a static solve from."""
        ...

    def start(self, inputs: CableInputs) -> State:
        """Where a static solve at cable inputs starts when it is given no start: the rest
        configuration, or what the coordinates predict for the inputs."""
        ...

    def cables(self, positions_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cable shortenings (a,) mm and their rows H T (a, c), dense, at positions (n, 3)."""
        ...

    def energy_and_forces(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray]:
        """Elastic energy (mJ) and T^T g(x) (c,) N at positions (n, 3)."""
        ...

    def forces_and_tangent(self, positions_mm: np.ndarray, tensions_n: np.ndarray):
        """T^T g(x) (c,) N and T^T (K(x) + K_cables) T (c, c) N/mm at positions (n, 3)."""
        ...

    def factorize(self, tangent, previous: Factor | None = None) -> Factor:
        """Factors of a tangent, reusing `previous`'s analysis when given."""
        ...

    def check_load(self, inputs: CableInputs, external_n: np.ndarray) -> None:
        """Warn (warnings.warn) when cable inputs and external forces (n, 3) N are outside
        what the coordinates were built for."""
        ...

    def check_solution(self, state: State) -> None:
        """Warn (warnings.warn) when a static solution lies outside what the coordinates
        were built for."""
        ...


class FreeDofs:
    """The full model's coordinates: q are the free nodal coordinates (T selects them)."""

    def __init__(self, model: FEModel) -> None:
        self.model = model
        self.free = model.free_dofs

    @property
    def size(self) -> int:
        return len(self.free)

    def lift(self, values: np.ndarray) -> np.ndarray:
        out = np.zeros((3 * self.model.node_count, *np.shape(values)[1:]))
        out[self.free] = values
        return out

    def project(self, vectors: np.ndarray) -> np.ndarray:
        return np.asarray(vectors)[self.free]

    def project_rows(self, rows):
        if sp.issparse(rows):
            return rows.tocsc()[:, self.free].tocsr()
        return np.asarray(rows)[:, self.free]

    def project_loads(self, loads: PointLoads | None) -> np.ndarray:
        forces = self.model.gravity_forces_n
        if loads is not None:
            forces = forces + loads.nodal(self.model.node_count)
        return forces.ravel()[self.free]

    step_tolerance_mm = 1e-7  # far below any camera's noise (D415: ~1 mm)
    keeps_tangent = False  # a sparse factor is large (Coordinates.keeps_tangent)

    def state(self, positions_mm: np.ndarray | None = None) -> NodalState:
        start = self.model.rest_nodes_mm if positions_mm is None else positions_mm
        return NodalState(self, np.array(start, dtype=float))

    def start(self, inputs: CableInputs) -> NodalState:
        """The rest configuration: the full model keeps no equilibria to predict from."""
        return self.state()

    def cables(self, positions_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (self.model.cable_shortenings(positions_mm),
                self.model.cable_jacobian(positions_mm)[:, self.free])

    def energy_and_forces(self, positions_mm: np.ndarray) -> tuple[float, np.ndarray]:
        energy, forces = self.model.energy_and_forces(positions_mm)
        return energy, forces.ravel()[self.free]

    def forces_and_tangent(self, positions_mm: np.ndarray, tensions_n: np.ndarray
                           ) -> tuple[np.ndarray, sp.csr_matrix]:
        internal, stiffness = self.model.internal_forces_and_stiffness(positions_mm)
        tangent = stiffness + self.model.cable_stiffness(positions_mm, tensions_n)
        return internal.ravel()[self.free], tangent

    def factorize(self, tangent: sp.spmatrix, previous: Factor | None = None) -> Factor:
        return Factorization(tangent) if previous is None else previous.refactor(tangent)

    def check_load(self, inputs: CableInputs, external_n: np.ndarray) -> None:
        """The full model holds for any load: nothing to check."""

    def check_solution(self, state: State) -> None:
        """The full model holds for any solution: nothing to check."""


class NodalState:
    """A State of the full model: the node positions themselves."""

    def __init__(self, space: FreeDofs, positions_mm: np.ndarray) -> None:
        self.space = space
        self.positions_mm = positions_mm

    def moved(self, step: np.ndarray, alpha: float) -> NodalState:
        return NodalState(self.space,
                          self.positions_mm + alpha * self.space.lift(step).reshape(-1, 3))

    def energy_and_forces(self) -> tuple[float, np.ndarray]:
        return self.space.energy_and_forces(self.positions_mm)

    def tangent(self, tensions_n: np.ndarray) -> sp.csr_matrix:
        return self.forces_and_tangent(tensions_n)[1]

    def forces_and_tangent(self, tensions_n: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        return self.space.forces_and_tangent(self.positions_mm, tensions_n)

    def cables(self) -> tuple[np.ndarray, np.ndarray]:
        return self.space.cables(self.positions_mm)

    def nodes_mm(self, nodes: np.ndarray) -> np.ndarray:
        return self.positions_mm[nodes]

    def reactions(self, external_n: np.ndarray, tensions_n: np.ndarray) -> np.ndarray:
        model = self.space.model
        cables = (model.cable_jacobian(self.positions_mm).T @ tensions_n).reshape(-1, 3)
        total = external_n + cables - model.internal_forces(self.positions_mm)
        return -total[model.fixed_nodes]
