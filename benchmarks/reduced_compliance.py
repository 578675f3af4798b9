"""Why the reduced P2 model misread contact forces in sensing (docs/reduced_model_history.md).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/reduced_compliance.py [--bases] [--soft]

At the probes' actuation (cables 5, 0, 5, 0 mm) it compares, on the full P2 equilibrium, the
compliance that sensing uses, with the cables held at their lengths (W_ef - W_ea W_aa^-1 W_af
over the 51 feature normals, and the contact point's own compliance), from the full model's
K, the exact Galerkin projection V^T K V on the reduced basis, and the reduced model's
hyper-reduced (ECSW) tangent K_r, evaluated at x projected on the basis (as the reduced
model sees it) and at x itself (the cables' nodes where the full model has them). The
reduced model is the one that benchmarks/bench_reduced.py trains and caches.

--bases (2 minutes) rebuilds POD bases from the cached training snapshots with the
held-cable responses (W's Schur-complement fields, formed from each response state's free
and cable responses) and compares the Galerkin compliance of each at x and at x projected on
it (the exact tangent there: no hyper-reduction). --soft splits the change of the soft
held-cable direction's stiffness q^T K q between x and x projected on the reduced model's
basis over the elements and the cables.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_reduced import CACHE, reduced_robot
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.reduction.ecsw import tangent_contributions
from softforce_cli.fem.reduction.pod import pod_basis, projection_errors
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.mesh import vertex_normals

ACTUATION = np.array([5.0, 0.0, 5.0, 0.0])
# probe points of benchmarks/bench_sense.py and study_sensing.py: mid north bar, west bar,
# apex, south bar
POINTS_MM = np.array([[0, 42, 69], [-45, 2, 74], [0, 0, 110], [0, -25, 92]], dtype=float)


class Probe:
    """The full P2 equilibrium at ACTUATION and the held-cable compliance at POINTS_MM."""

    def __init__(self, full, model) -> None:
        self.model, self.space = model, model.coordinates
        equilibrium = solve_equilibrium(model, full.cable_inputs(ACTUATION))
        self.x, self.tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
        _, self.tangent = self.space.forces_and_tangent(self.x, self.tensions)
        self.factor = spla.splu(self.tangent.tocsc())
        self.zero = self.space.lift(np.zeros(self.tangent.shape[0])).ravel()
        self.cable_rows = np.asarray(model.cable_jacobian(self.x))
        normals = vertex_normals(self.x[: full.mesh.node_count], full.mesh.surface_faces)
        features = full.feature_nodes
        self.feature_rows = Attachment.at_nodes(features).directional_rows(
            normals[features], model.node_count)
        surface = full.mesh.surface_nodes
        nodes = surface[cKDTree(self.x[surface]).query(POINTS_MM)[1]]
        self.rows = [Attachment.at_nodes(np.array([n])).directional_rows(-normals[[n]],
                                                                         model.node_count)
                     for n in nodes]
        self.exact = [self.held(self.full_solve, row) for row in self.rows]

    def full_solve(self, columns: np.ndarray) -> np.ndarray:
        projected = np.asarray(self.space.project(columns))
        return np.column_stack([self.space.lift(self.factor.solve(projected[:, j])).ravel()
                                - self.zero for j in range(projected.shape[1])])

    def held(self, solve, row) -> tuple[np.ndarray, float, np.ndarray]:
        """Feature normal motions, the point's own motion and the whole field (3n,) per
        newton at the point, the cables held at their lengths."""
        motions = solve(np.column_stack([self.cable_rows.T, row.T.toarray()]))
        at_cables = self.cable_rows @ motions
        tensions = -np.linalg.solve(at_cables[:, :-1], at_cables[:, -1])
        field = motions[:, -1] + motions[:, :-1] @ tensions
        return self.feature_rows @ field, (row @ field).item(), field

    def errors(self, solve) -> tuple[list[float], list[float]]:
        """Relative errors of the feature motions and the own compliances through `solve`."""
        errors, owns = [], []
        for row, (exact, _, _) in zip(self.rows, self.exact, strict=True):
            motions, own, _ = self.held(solve, row)
            errors.append(float(np.linalg.norm(motions - exact) / np.linalg.norm(exact)))
            owns.append(own)
        return errors, owns

    def projected(self, basis: np.ndarray, rest: np.ndarray) -> np.ndarray:
        return rest + (basis @ (basis.T @ (self.x - rest).ravel())).reshape(-1, 3)


def reduced_solve(basis: np.ndarray, matrix: np.ndarray):
    return lambda columns: basis @ np.linalg.solve(matrix, basis.T @ columns)


def _row(label: str, errors: list[float], owns: list[float]) -> str:
    return (f"{label} | {', '.join(f'{e:.0%}' for e in errors)} | "
            f"{', '.join(f'{o:.1f}' for o in owns)}")


def compare_tangents(probe: Probe, reduced) -> None:
    """The table of docs/reduced_model_history.md ("Why"): exact Galerkin and ECSW tangents."""
    basis = reduced.fe_model.coordinates.basis
    free_basis = probe.space.project(basis)
    galerkin = free_basis.T @ (probe.tangent @ free_basis)
    projected_x = probe.projected(basis, reduced.fe_model.coordinates.rest)
    moved = np.linalg.norm(projected_x - probe.x, axis=1)
    print(f"x projected on the basis: {np.sqrt(np.mean(moved**2)):.3f} mm RMS, "
          f"{moved.max():.2f} mm at most")
    eigenvalues = np.linalg.eigvalsh(galerkin)
    print(f"V^T K V eigenvalues (tensions held as forces): smallest {eigenvalues[:2]}, "
          f"largest {eigenvalues[-1]:.3f} N/mm")
    print(f"own compliances of the full model (mm/N): "
          f"{', '.join(f'{own:.1f}' for _, own, _ in probe.exact)}")
    print("tangent | feature motions vs full (relative error) | own compliance (mm/N)")
    print(_row("exact Galerkin V^T K V at x", *probe.errors(reduced_solve(basis, galerkin))))
    for name, at in (("x projected", projected_x), ("x", probe.x)):
        _, hyper = reduced.fe_model.coordinates.forces_and_tangent(at, probe.tensions)
        relative = np.linalg.norm(hyper - galerkin) / np.linalg.norm(galerkin)
        print(_row(f"ECSW at {name} ({relative:.2%} from V^T K V at x)",
                   *probe.errors(reduced_solve(basis, hyper))))


def compare_bases(probe: Probe, reduced) -> None:
    """POD bases with the held-cable responses, Galerkin at x and at x projected on each."""
    cached = np.load(CACHE / "p2.snapshots.npz")
    responses, states = cached["responses"], cached["response_states"]
    positions, loaded = cached["positions_mm"], cached["loaded_mm"]
    rest = reduced.fe_model.coordinates.rest
    per_state = responses.shape[1] // len(states)
    cables = probe.cable_rows.shape[0]
    held = []
    for j, index in enumerate(states):
        block = responses[:, j * per_state:(j + 1) * per_state]
        free, pulled = block[:, :-cables], block[:, -cables:]
        rows = np.asarray(probe.model.cable_jacobian(positions[index]))
        held.append(free - pulled @ np.linalg.solve(rows @ pulled, rows @ free))
    held = np.hstack(held)
    cable_responses = np.hstack([responses[:, (j + 1) * per_state - cables:(j + 1) * per_state]
                                 for j in range(len(states))])
    statics = np.hstack([(positions.reshape(len(positions), -1) - rest.ravel()).T,
                         (loaded.reshape(len(loaded), -1) - rest.ravel()).T])
    bases = {
        "trained (free responses), 120 modes": reduced.fe_model.coordinates.basis,
        "held + cable responses, 120 modes": pod_basis(
            np.hstack([statics, held, cable_responses]), max_modes=120)[0],
        "held + free responses, 120 modes": pod_basis(
            np.hstack([statics, held, responses]), max_modes=120)[0],
        "held + free responses, 160 modes": pod_basis(
            np.hstack([statics, held, responses]), max_modes=160)[0],
    }
    print("basis | held responses' worst projection error | x projected (mm RMS) | "
          "Galerkin at x: errors; own | Galerkin at x projected: errors; own")
    for name, basis in bases.items():
        free_basis = probe.space.project(basis)
        at_x = free_basis.T @ (probe.tangent @ free_basis)
        projected_x = probe.projected(basis, rest)
        _, tangent = probe.space.forces_and_tangent(projected_x, probe.tensions)
        at_span = free_basis.T @ (tangent @ free_basis)
        moved = np.sqrt(np.mean(np.sum((projected_x - probe.x) ** 2, axis=1)))
        print(f"{name} | {projection_errors(basis, held).max():.3f} | {moved:.3f} | "
              f"{_row('', *probe.errors(reduced_solve(basis, at_x)))[3:]} | "
              f"{_row('', *probe.errors(reduced_solve(basis, at_span)))[3:]}")


def soft_direction(probe: Probe, reduced) -> None:
    """q^T K q of the held-cable field of a push at mid north bar, at x and at x projected
    on the reduced basis, split over the elements and the cables."""
    basis = reduced.fe_model.coordinates.basis
    q = probe.exact[0][2] / np.linalg.norm(probe.exact[0][2])
    free_q = probe.space.project(q[:, None])
    projected_x = probe.projected(basis, reduced.fe_model.coordinates.rest)
    _, projected_tangent = probe.space.forces_and_tangent(projected_x, probe.tensions)
    totals, elements = [], []
    for tangent, at in ((probe.tangent, probe.x), (projected_tangent, projected_x)):
        totals.append((free_q.T @ (tangent @ free_q)).item())
        elements.append(tangent_contributions(probe.model, q[:, None], at, np.ones((1, 1)))[0])
    change = elements[1] - elements[0]
    share = np.cumsum(np.sort(np.abs(change))[::-1]) / np.abs(change).sum()
    print(f"q^T K q (N/mm, |q| = 1): {totals[0]:.3g} at x, {totals[1]:.3g} at x projected; "
          f"elements {elements[0].sum():.3g} -> {elements[1].sum():.3g}, cables "
          f"{totals[0] - elements[0].sum():.3g} -> {totals[1] - elements[1].sum():.3g}")
    print(f"the elements' change: {np.abs(change).sum():.3g} in absolute sum; the 10, 50 "
          f"and 200 largest of {len(change)} carry {share[9]:.0%}, {share[49]:.0%}, "
          f"{share[199]:.0%} of it")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--bases", action="store_true")
    parser.add_argument("--soft", action="store_true")
    args = parser.parse_args()
    full, reduced = reduced_robot()
    probe = Probe(full, full.fe_model)
    compare_tangents(probe, reduced)
    if args.bases:
        compare_bases(probe, reduced)
    if args.soft:
        soft_direction(probe, reduced)


if __name__ == "__main__":
    main()
