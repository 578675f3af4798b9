"""Why the reduced P2 model misreads contact forces in sensing (docs/reduced_model.md).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/reduced_compliance.py   # ~1 minute

At the probes' actuation (cables 5, 0, 5, 0 mm) it compares, on the full P2 equilibrium, the
compliance that sensing uses, with the cables held at their lengths (W_ef - W_ea W_aa^-1 W_af
over the 51 feature normals, and the contact point's own compliance), from the full model's
K, the exact Galerkin projection V^T K V on the reduced basis, and the reduced model's
hyper-reduced (ECSW) tangent K_r, evaluated at x projected on the basis (as the reduced
model sees it) and at x itself (the cables' nodes where the full model has them). The
reduced model is the one that benchmarks/bench_reduced.py trains and caches.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_reduced import reduced_robot
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.mesh import vertex_normals

ACTUATION = np.array([5.0, 0.0, 5.0, 0.0])
# probe points of benchmarks/bench_sense.py and study_sensing.py: mid north bar, west bar,
# apex, south bar
POINTS_MM = np.array([[0, 42, 69], [-45, 2, 74], [0, 0, 110], [0, -25, 92]], dtype=float)


def main() -> None:
    full, reduced = reduced_robot()
    model, space = full.fe_model, full.fe_model.coordinates
    basis = reduced.fe_model.coordinates.basis
    equilibrium = solve_equilibrium(model, full.cable_inputs(ACTUATION))
    x, tensions = equilibrium.positions_mm, equilibrium.cable_tensions_n
    _, tangent = space.forces_and_tangent(x, tensions)
    free_basis = space.project(basis)
    galerkin = free_basis.T @ (tangent @ free_basis)
    # the reduced model only ever sees configurations in its basis' span: x projected
    rest = reduced.fe_model.coordinates.rest
    projected_x = rest + (basis @ (basis.T @ (x - rest).ravel())).reshape(-1, 3)
    moved = np.linalg.norm(projected_x - x, axis=1)
    print(f"x projected on the basis: {np.sqrt(np.mean(moved**2)):.3f} mm RMS, "
          f"{moved.max():.2f} mm at most")
    hyper = {}
    for name, at in (("span", projected_x), ("x", x)):
        _, hyper[name] = reduced.fe_model.coordinates.forces_and_tangent(at, tensions)
        relative = np.linalg.norm(hyper[name] - galerkin) / np.linalg.norm(galerkin)
        print(f"ECSW tangent at {name} vs V^T K V at x: {relative:.2%} (relative Frobenius)")
    eigenvalues = np.linalg.eigvalsh(galerkin)
    print(f"V^T K V eigenvalues (tensions held as forces): smallest {eigenvalues[:2]}, "
          f"largest {eigenvalues[-1]:.3f} N/mm")
    factor = spla.splu(tangent.tocsc())
    zero = space.lift(np.zeros(tangent.shape[0])).ravel()

    def full_solve(columns: np.ndarray) -> np.ndarray:
        projected = np.asarray(space.project(columns))
        return np.column_stack([space.lift(factor.solve(projected[:, j])).ravel() - zero
                                for j in range(projected.shape[1])])

    def reduced_solve(matrix: np.ndarray):
        return lambda columns: basis @ np.linalg.solve(matrix, basis.T @ columns)

    cable_rows = np.asarray(model.cable_jacobian(x))
    normals = vertex_normals(x[: full.mesh.node_count], full.mesh.surface_faces)
    features = full.feature_nodes
    feature_rows = Attachment.at_nodes(features).directional_rows(normals[features],
                                                                  model.node_count)
    surface = full.mesh.surface_nodes

    def held(solve, row) -> tuple[np.ndarray, float]:
        """Feature normal motions and the point's own motion per newton at the point, the
        cables held at their lengths."""
        motions = solve(np.column_stack([cable_rows.T, row.T.toarray()]))
        at_cables = cable_rows @ motions
        tensions = -np.linalg.solve(at_cables[:, :-1], at_cables[:, -1])
        field = motions[:, -1] + motions[:, :-1] @ tensions
        return feature_rows @ field, (row @ field).item()

    print("point (mm) | own compliance full / Galerkin / ECSW at span / ECSW at x (mm/N) | "
          "feature motions vs full: Galerkin / ECSW at span / ECSW at x (relative error)")
    for point in POINTS_MM:
        node = surface[cKDTree(x[surface]).query(point)[1]]
        row = Attachment.at_nodes(np.array([node])).directional_rows(-normals[[node]],
                                                                      model.node_count)
        exact, own = held(full_solve, row)
        projected, own_projected = held(reduced_solve(galerkin), row)
        sampled, own_sampled = held(reduced_solve(hyper["span"]), row)
        at_x, own_at_x = held(reduced_solve(hyper["x"]), row)
        errors = [np.linalg.norm(m - exact) / np.linalg.norm(exact)
                  for m in (projected, sampled, at_x)]
        print(f"{point.astype(int).tolist()} | {own:.1f} / {own_projected:.1f} / "
              f"{own_sampled:.1f} / {own_at_x:.1f} | {errors[0]:.0%} / {errors[1]:.0%} / "
              f"{errors[2]:.0%}")


if __name__ == "__main__":
    main()
