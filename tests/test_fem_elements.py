"""Element-level properties of the P1 tetrahedral FE core: patch test, rigid-body invariance,
tangent consistency, definiteness, and agreement with scikit-fem's linear elasticity."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp
import skfem
from scipy.sparse.linalg import eigsh
from scipy.spatial.transform import Rotation
from skfem.models.elasticity import lame_parameters as skfem_lame_parameters
from skfem.models.elasticity import linear_elasticity

from softforce_cli.fem.attachment import attach_points
from softforce_cli.fem.cables import Cable, CableInputs
from softforce_cli.fem.materials import LAWS, Material, polar_decomposition
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.statics import SolverSettings, solve_equilibrium
from softforce_cli.fem.tet_p1 import shape_gradients
from softforce_cli.model.structured import box_mesh

YOUNG_MPA = 1.0
POISSON = 0.3
# Newton to round-off: the patch test asks for 1e-10 mm, far below the default tolerances.
TIGHT = SolverSettings(step_tolerance_mm=1e-13, force_tolerance_n=1e-13)


def perturbed_box(rng: np.random.Generator, divisions=(3, 3, 3), jitter_mm=0.2):
    """A 3 x 3 x 3 mm box of 1 mm cells whose interior nodes are moved at random.

    Returns nodes (n, 3), tets (m, 4) and the boundary nodes (b,).
    """
    size = np.array(divisions, dtype=float)
    nodes, tets = box_mesh(tuple(size), divisions)
    boundary = np.flatnonzero(np.any((nodes < 1e-9) | (nodes > size - 1e-9), axis=1))
    interior = np.setdiff1d(np.arange(len(nodes)), boundary)
    nodes[interior] += rng.uniform(-jitter_mm, jitter_mm, (len(interior), 3))
    assert (shape_gradients(nodes, tets)[1] > 0).all()  # still a valid mesh
    return nodes, tets, boundary


def make_model(nodes, tets, law, fixed_nodes, cables=()):
    return FEModel(
        rest_nodes_mm=nodes,
        tets=tets,
        material=Material(law, YOUNG_MPA, POISSON),
        fixed_nodes=np.asarray(fixed_nodes, dtype=np.int64),
        node_masses_kg=np.zeros(len(nodes)),
        gravity_mm_s2=np.zeros(3),
        cables=tuple(cables),
    )


def force_scale(model: FEModel) -> float:
    """Nodal force of a unit strain on one element, N: E * (element volume)^(2/3)."""
    return YOUNG_MPA * float(np.mean(model.tet_volumes_mm3)) ** (2 / 3)


# --- patch test -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("law", "strain"),
    [(law, 1e-3) for law in LAWS] + [("linear", 0.5)],
)
@pytest.mark.parametrize("jitter_mm", [0.0, 0.2])
def test_patch_test_reproduces_affine_field(law, strain, jitter_mm):
    rng = np.random.default_rng(1)
    nodes, tets, boundary = perturbed_box(rng, jitter_mm=jitter_mm)
    gradient = np.eye(3) + strain * rng.uniform(-1, 1, (3, 3))
    offset = rng.uniform(-1, 1, 3)
    affine = nodes @ gradient.T + offset
    start = nodes.copy()
    start[boundary] = affine[boundary]  # the clamped nodes stay where they start
    model = make_model(nodes, tets, law, boundary)
    equilibrium = solve_equilibrium(model, CableInputs.slack(0), start_mm=start, settings=TIGHT)
    assert np.abs(equilibrium.positions_mm - affine).max() < 1e-10


@pytest.mark.parametrize("law", LAWS)
def test_affine_field_is_in_equilibrium_at_large_strain(law):
    """Uniform F: every interior node's forces cancel for any law, at any strain (the
    integral of grad N_a over an interior node's patch vanishes)."""
    rng = np.random.default_rng(2)
    nodes, tets, boundary = perturbed_box(rng)
    gradient = np.diag([1.4, 0.8, 1.1]) + 0.2 * rng.uniform(-1, 1, (3, 3))
    model = make_model(nodes, tets, law, boundary)
    forces = model.internal_forces(nodes @ gradient.T)
    interior = np.setdiff1d(np.arange(len(nodes)), boundary)
    assert np.abs(forces[interior]).max() < 1e-12 * np.abs(forces).max()


# --- rigid-body motions -----------------------------------------------------------------


def rigid_motion(nodes, angle_deg, rng):
    axis = rng.normal(size=3)
    rotation = Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis))
    return nodes @ rotation.as_matrix().T + rng.uniform(-10, 10, 3)


@pytest.mark.parametrize("law", ["corotational", "neo-hookean"])
def test_rigid_motion_is_stress_free_for_nonlinear_laws(law):
    rng = np.random.default_rng(3)
    nodes, tets, _ = perturbed_box(rng)
    model = make_model(nodes, tets, law, [])
    moved = rigid_motion(nodes, 40.0, rng)
    # Round-off: Neo-Hookean's I1 - 3 and ln J cancel to ~1e-16 (measured -4e-18 E V, and
    # 1e-30 E V corotational); a 1% stretch would give ~1e-4 E V.
    assert abs(model.strain_energy(moved)) < 1e-13 * YOUNG_MPA * model.tet_volumes_mm3.sum()
    # measured 1.2e-14 of the force scale for both laws
    assert np.abs(model.internal_forces(moved)).max() < 1e-12 * force_scale(model)


def test_linear_law_has_spurious_energy_under_finite_rotation():
    """Why the corotational law exists: the linear law's strain sym(R) - I of a rotation by
    theta is (cos theta - 1)(I - n n^T), so its energy is 2 (cos theta - 1)^2 (lambda + mu)
    per unit volume: second order in the strain, not zero."""
    rng = np.random.default_rng(4)
    nodes, tets, _ = perturbed_box(rng)
    model = make_model(nodes, tets, "linear", [])
    lam, mu = model.material.lame
    volume = model.tet_volumes_mm3.sum()

    def spurious(theta_deg):  # the analytic energy above, mJ
        return volume * 2 * (np.cos(np.radians(theta_deg)) - 1) ** 2 * (lam + mu)

    energy_40 = model.strain_energy(rigid_motion(nodes, 40.0, rng))
    assert energy_40 == pytest.approx(spurious(40.0), rel=1e-10)
    # 0.105 E V here, the energy of a 46% uniaxial strain: clearly not zero.
    assert energy_40 > 0.01 * YOUNG_MPA * volume
    assert np.abs(model.internal_forces(rigid_motion(nodes, 40.0, rng))).max() > 0.1 * (
        force_scale(model)
    )
    # Infinitesimal rotations are free to first order: energy ~ theta^4.
    small = model.strain_energy(rigid_motion(nodes, 0.01, rng))
    assert small == pytest.approx(spurious(0.01), rel=1e-4)
    assert small < 1e-15 * YOUNG_MPA * volume


# --- tangent consistency ----------------------------------------------------------------


def deformed_state(nodes, rng, amplitude_mm=0.15):
    """Node positions with strains of order 0.3: a random, clearly nonlinear state."""
    return nodes @ np.diag([1.2, 0.9, 1.05]).T + rng.uniform(-1, 1, nodes.shape) * amplitude_mm


@pytest.mark.parametrize("law", LAWS)
def test_stiffness_is_derivative_of_internal_forces(law):
    rng = np.random.default_rng(5)
    nodes, tets, _ = perturbed_box(rng)
    fixed = np.flatnonzero(nodes[:, 0] < 1e-9)
    model = make_model(nodes, tets, law, fixed)
    positions = deformed_state(nodes, rng)
    _, stiffness = model.internal_forces_and_stiffness(positions)
    free = model.free_dofs
    step = 1e-6  # mm: central differences, truncation ~1e-12, round-off ~1e-10 relative
    for _ in range(3):
        direction = np.zeros(3 * len(nodes))
        direction[free] = rng.normal(size=len(free))

        def forces(sign, d=direction):
            moved = positions + sign * step * d.reshape(-1, 3)
            return model.internal_forces(moved).ravel()[free]

        difference = (forces(+1) - forces(-1)) / (2 * step)
        exact = stiffness @ direction[free]
        assert np.abs(difference - exact).max() < 1e-6 * np.abs(exact).max()


@pytest.mark.parametrize("law", LAWS)
def test_internal_forces_are_gradient_of_energy(law):
    rng = np.random.default_rng(6)
    nodes, tets, _ = perturbed_box(rng)
    model = make_model(nodes, tets, law, [])
    positions = deformed_state(nodes, rng)
    forces = model.internal_forces(positions)
    direction = rng.normal(size=nodes.shape)
    step = 1e-6
    slope = (
        model.strain_energy(positions + step * direction)
        - model.strain_energy(positions - step * direction)
    ) / (2 * step)
    assert slope == pytest.approx(np.sum(forces * direction), rel=1e-6)


def test_cable_geometric_stiffness_is_derivative_of_cable_forces():
    """-d(H_a^T lam)/dx equals the cables' geometric stiffness (a 2-point cable)."""
    rng = np.random.default_rng(7)
    nodes, tets, _ = perturbed_box(rng)
    path = attach_points(nodes, tets, np.array([[2.6, 1.4, 1.6], [1.3, 1.7, 1.2]]))
    cable = Cable.through("test", path, np.array([-5.0, 1.5, 1.5]), nodes)
    fixed = np.flatnonzero(nodes[:, 0] < 1e-9)
    model = make_model(nodes, tets, "linear", fixed, cables=[cable])
    positions = deformed_state(nodes, rng, amplitude_mm=0.05)
    tension = np.array([0.7])
    free = model.free_dofs
    stiffness = model.cable_stiffness(positions, tension)
    step = 1e-6
    direction = np.zeros(3 * len(nodes))
    direction[free] = rng.normal(size=len(free))

    def cable_forces(sign):
        moved = positions + sign * step * direction.reshape(-1, 3)
        return (model.cable_jacobian(moved).T @ tension)[free]

    difference = (cable_forces(+1) - cable_forces(-1)) / (2 * step)
    exact = -(stiffness @ direction[free])
    assert np.abs(difference - exact).max() < 1e-6 * np.abs(exact).max()
    # and H_a is the gradient of the shortening
    delta_slope = (
        model.cable_shortenings(positions + step * direction.reshape(-1, 3))
        - model.cable_shortenings(positions - step * direction.reshape(-1, 3))
    ) / (2 * step)
    assert delta_slope[0] == pytest.approx(
        (model.cable_jacobian(positions) @ direction)[0], rel=1e-7
    )


# --- definiteness -----------------------------------------------------------------------


@pytest.mark.parametrize("law", LAWS)
@pytest.mark.parametrize("deformed", [False, True])
def test_stiffness_is_symmetric_positive_definite_when_clamped(law, deformed):
    rng = np.random.default_rng(8)
    nodes, tets = box_mesh((4.0, 2.0, 2.0), (4, 2, 2))
    fixed = np.flatnonzero(nodes[:, 0] < 1e-9)
    model = make_model(nodes, tets, law, fixed)
    positions = nodes + (0.01 * rng.uniform(-1, 1, nodes.shape) if deformed else 0.0)
    positions[fixed] = nodes[fixed]
    _, stiffness = model.internal_forces_and_stiffness(positions)
    scale = np.abs(stiffness).max()
    assert np.abs(stiffness - stiffness.T).max() <= 1e-12 * scale
    smallest = eigsh(stiffness, k=1, which="SA", return_eigenvectors=False)[0]
    assert smallest > 0
    assert smallest == pytest.approx(np.linalg.eigvalsh(stiffness.toarray())[0], rel=1e-8)


def test_unclamped_stiffness_has_exactly_six_rigid_modes():
    nodes, tets, _ = perturbed_box(np.random.default_rng(9))
    model = make_model(nodes, tets, "linear", np.array([], dtype=np.int64))
    _, stiffness = model.internal_forces_and_stiffness(nodes)
    eigenvalues = np.linalg.eigvalsh(stiffness.toarray())
    assert np.all(np.abs(eigenvalues[:6]) < 1e-12 * eigenvalues[-1])
    assert eigenvalues[6] > 1e-4 * eigenvalues[-1]


# --- independent reference: scikit-fem ---------------------------------------------------


def test_linear_stiffness_equals_scikit_fem():
    rng = np.random.default_rng(10)
    nodes, tets, _ = perturbed_box(rng)
    lam, mu = skfem_lame_parameters(YOUNG_MPA, POISSON)
    assert Material("linear", YOUNG_MPA, POISSON).lame == pytest.approx((lam, mu), rel=1e-15)

    basis = skfem.Basis(
        skfem.MeshTet(nodes.T.copy(), tets.T.copy()), skfem.ElementVector(skfem.ElementTetP1())
    )
    reference = skfem.asm(linear_elasticity(lam, mu), basis).tocsr()
    # skfem numbers dof (node, component) as nodal_dofs[component, node]; ours is 3 node + i.
    ours_of_skfem = np.empty(basis.N, dtype=np.int64)
    ours_of_skfem[basis.nodal_dofs.T.ravel()] = np.arange(basis.N)
    permutation = sp.csr_matrix(
        (np.ones(basis.N), (ours_of_skfem, np.arange(basis.N))), shape=(basis.N, basis.N)
    )
    reference = permutation @ reference @ permutation.T

    # Ours over every dof (no clamped node), at the rest state.
    model = make_model(nodes, tets, "linear", np.array([], dtype=np.int64))
    _, ours = model.internal_forces_and_stiffness(nodes)
    assert ours.shape == reference.shape == (3 * len(nodes),) * 2
    assert np.abs(ours - reference).max() < 1e-13 * np.abs(reference).max()


# --- polar decomposition ----------------------------------------------------------------


def test_polar_decomposition_matches_scipy_to_round_off():
    """The scaled Newton iteration, stopped after its first step under
    POLAR_CONVERGED_STEP, gives scipy's polar factors to round-off for stretches from 0.1 to
    10, and a proper rotation for inverted elements (where scipy's factor reflects)."""
    rng = np.random.default_rng(3)
    count = 400
    rotations = Rotation.random(2 * count, random_state=4).as_matrix()
    stretches = np.exp(rng.uniform(np.log(0.1), np.log(10.0), (count, 3)))
    F = rotations[:count] * stretches[:, None, :] @ rotations[count:]
    inverted = F[:20] * np.array([1.0, 1.0, -1.0])  # det < 0: one direction flipped
    R, S = polar_decomposition(np.concatenate([F, inverted]))
    for k in range(count):
        R_ref, S_ref = scipy.linalg.polar(F[k], side="right")
        np.testing.assert_allclose(R[k], R_ref, atol=1e-13)
        np.testing.assert_allclose(S[k], S_ref, atol=1e-12 * stretches[k].max())
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-13)
    np.testing.assert_allclose(R.transpose(0, 2, 1) @ R, np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-13)
    np.testing.assert_allclose(R @ S, np.concatenate([F, inverted]), atol=1e-12 * 10)
