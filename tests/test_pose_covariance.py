"""The camera pose's uncertainty from a calibration's markers (calibration.pose_covariance)
against repeated rigid fits of noisy markers, and the static residual left after the pose's
correction within it (diagnosis.residuals.static_after_pose_mm) against scipy's constrained
minimiser and numpy's least squares."""

import numpy as np
import pytest
from scipy.optimize import minimize

from softforce_cli.calibration.pose_covariance import pose_covariance
from softforce_cli.calibration.rigid import fit_rigid_transform
from softforce_cli.diagnosis.residuals import (
    POSE_RADIUS,
    Field,
    static_after_pose_mm,
    static_mm,
)

# nine markers over a finger-like body: long along x, thin across
MARKERS = np.array([[80, -10, 70], [80, 10, 70], [40, -10, 70], [40, 10, 70], [60, -12, 50],
                    [60, 12, 50], [-10, 0, 40], [-10, -15, 60], [-10, 15, 60]], dtype=float)
SIGMA_MM = 0.5


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """Small-angle rotation vector (rad) of a rotation near the identity."""
    return 0.5 * np.array([rotation[2, 1] - rotation[1, 2], rotation[0, 2] - rotation[2, 0],
                           rotation[1, 0] - rotation[0, 1]])


def test_the_pose_covariance_is_the_scatter_of_repeated_rigid_fits():
    rng = np.random.default_rng(3)
    corrections = []
    for _ in range(3000):
        seen = MARKERS + rng.normal(0.0, SIGMA_MM, MARKERS.shape)
        fit = fit_rigid_transform(MARKERS, seen)
        corrections.append(np.r_[_rotation_vector(fit.rotation), fit.translation_mm])
    scatter = np.cov(np.array(corrections).T)
    # residuals whose sum of squares over the 3 n - 6 degrees of freedom is sigma^2
    residuals = np.full(MARKERS.shape, SIGMA_MM * np.sqrt((27 - 6) / 27))
    covariance = pose_covariance(MARKERS, residuals, np.zeros((27, 0)))
    np.testing.assert_allclose(np.sqrt(np.diag(covariance)), np.sqrt(np.diag(scatter)),
                               rtol=0.05)
    # the turn about the body's long axis is the least certain: 0.5 mm over a 10-15 mm lever
    assert np.argmax(np.diag(covariance)[:3]) == 0
    assert np.degrees(np.sqrt(covariance[0, 0])) == pytest.approx(0.7, abs=0.1)


def test_an_input_fitted_with_the_pose_makes_it_less_certain():
    """A cable that bends the body about its long axis (the markers move across it in
    proportion to their distance along it) trades with the turn about that axis: the
    scatter of the pose over repeated fits of the pose and the input, against the
    marginal block."""
    bend = np.zeros_like(MARKERS)
    bend[:, 1] = 0.02 * (MARKERS[:, 0] + 10.0) ** 1.5 / 10.0  # mm across per unit input
    rng = np.random.default_rng(4)
    jacobian = np.c_[np.c_[np.cross(np.eye(3)[0], MARKERS).ravel(),
                           np.cross(np.eye(3)[1], MARKERS).ravel(),
                           np.cross(np.eye(3)[2], MARKERS).ravel()],
                     np.tile(np.eye(3), (9, 1)), bend.ravel()]
    fits = [np.linalg.lstsq(jacobian, rng.normal(0.0, SIGMA_MM, 27), rcond=None)[0][:6]
            for _ in range(4000)]
    residuals = np.full(MARKERS.shape, SIGMA_MM * np.sqrt((27 - 7) / 27))
    covariance = pose_covariance(MARKERS, residuals, bend.reshape(27, 1))
    np.testing.assert_allclose(np.sqrt(np.diag(covariance)), np.std(fits, axis=0), rtol=0.05)
    rigid = pose_covariance(MARKERS, residuals, np.zeros((27, 0))) * (27 - 6) / (27 - 7)
    assert np.all(np.diag(covariance) >= np.diag(rigid) * (1 - 1e-9))
    assert covariance[2, 2] > 1.5 * rigid[2, 2]  # the turn about z, which the bend mimics


def test_too_few_markers_leave_the_pose_unbounded():
    assert pose_covariance(MARKERS[:3], np.zeros((3, 3)), np.zeros((9, 0))) is None
    inputs = np.random.default_rng(5).normal(size=(12, 6))  # six inputs: 12 - 6 - 6 = 0 left
    assert pose_covariance(MARKERS[:4], np.zeros((4, 3)), inputs) is None


def _plate_field(values: np.ndarray) -> tuple[Field, np.ndarray, np.ndarray]:
    """A 60 x 30 mm plate of 10 x 5 nodes at z = 40 facing up, its static residual `values`
    (50,) seen in two frames by 1-2 points each, and the nodes' positions and normals."""
    x, y = (v.ravel() for v in np.meshgrid(np.linspace(-30, 30, 10), np.linspace(-15, 15, 5)))
    positions = np.c_[x, y, np.full_like(x, 40.0)]
    normals = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    weight = 1.0 + (x > 0)
    nodes = np.arange(len(x))
    field = Field(np.repeat([0, 1], len(x)), np.tile(nodes, 2), np.tile(values, 2),
                  np.tile(weight, 2))
    return field, positions, normals


def _normal_moves(positions: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(m, 6) each node's move along its normal per unit of (dtheta, dt)."""
    return np.c_[np.cross(positions, normals), normals]


COVARIANCE = np.diag([1e-4, 4e-4, 1e-4, 0.04, 0.04, 0.01])  # 0.6-1.1 degrees, 0.1-0.2 mm


def test_a_pose_error_the_calibration_allows_leaves_no_static_residual():
    field, positions, normals = _plate_field(np.zeros(50))
    tilt = np.array([0.01, -0.02, 0.0, 0.0, 0.0, 0.1])  # 1.5 standard deviations
    field, *_ = _plate_field(_normal_moves(positions, normals) @ tilt)
    assert static_mm(field, 50) > 0.3
    assert static_after_pose_mm(field, 50, positions, normals, COVARIANCE) < 1e-9


def test_a_pose_error_beyond_the_calibration_is_corrected_only_as_far_as_it_allows():
    """Against scipy's constrained minimiser (SLSQP) of the weighted squares over the pose's
    ellipsoid of POSE_RADIUS standard deviations."""
    _, positions, normals = _plate_field(np.zeros(50))
    moves = _normal_moves(positions, normals)
    tilt = np.array([0.05, -0.02, 0.0, 0.0, 0.0, 0.6])  # 5 standard deviations about x
    values = moves @ tilt + 0.2 * np.sin(positions[:, 0] / 7.0)  # and a ripple
    field, *_ = _plate_field(values)
    weight = 1.0 + (positions[:, 0] > 0)
    inverse = np.linalg.pinv(COVARIANCE)

    def squares(pose):
        return np.average((values - moves @ pose) ** 2, weights=weight)

    best = minimize(squares, np.zeros(6), method="SLSQP", constraints=[{
        "type": "ineq", "fun": lambda pose: POSE_RADIUS**2 - pose @ inverse @ pose}],
        options={"ftol": 1e-14, "maxiter": 500})
    left = static_after_pose_mm(field, 50, positions, normals, COVARIANCE)
    assert left == pytest.approx(np.sqrt(best.fun), rel=1e-4)
    assert 0.3 < left < 0.5 * static_mm(field, 50)  # corrected within its ellipsoid only


def test_a_static_bump_is_not_a_pose():
    """A bump on a few nodes (what a hidden mass or a softer arm leaves) is barely taken up:
    the correction is the weighted least-squares rigid fit when the calibration allows it
    (numpy's lstsq), which a local shape escapes."""
    _, positions, normals = _plate_field(np.zeros(50))
    values = 1.5 * np.exp(-np.sum((positions[:, :2] - [20.0, 5.0]) ** 2, axis=1) / 50.0)
    field, *_ = _plate_field(values)
    weight = 1.0 + (positions[:, 0] > 0)
    root = np.sqrt(weight)
    moves = _normal_moves(positions, normals)
    pose = np.linalg.lstsq(moves * root[:, None], values * root, rcond=None)[0]
    expected = np.sqrt(np.average((values - moves @ pose) ** 2, weights=weight))
    loose = np.eye(6)  # a pose hardly known: the plain rigid fit
    assert static_after_pose_mm(field, 50, positions, normals, loose) == pytest.approx(
        expected, rel=1e-6)
    assert expected > 0.6 * static_mm(field, 50)
