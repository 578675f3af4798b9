"""Algorithm 3, feature matching along normals, against analytic line-surface intersections."""

from __future__ import annotations

import numpy as np

from softforce_cli.vision.feature_matching import match_features
from softforce_cli.vision.settings import VisionSettings

RADIUS = 50.0


def _fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _shifted_sphere_offset(normals: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Where the line x = R n + t n meets the sphere |x - shift| = R, nearest t: the normal
    displacement of feature R n when the sphere moves by `shift`."""
    ns = normals @ shift
    return ns - RADIUS + np.sqrt(RADIUS**2 - shift @ shift + ns**2)


def test_normal_offsets_of_a_shifted_sphere_are_the_analytic_ones():
    normals = _fibonacci_sphere(60)
    features = RADIUS * normals
    shift = np.array([2.0, -1.5, 3.0])
    observed = RADIUS * _fibonacci_sphere(150_000) + shift  # spacing about 0.45 mm
    matches = match_features(features, normals, observed, VisionSettings())
    # all matched: the far side of the sphere is 100 mm away, beyond the 30 mm search
    assert matches.matched.all() and not matches.hidden.any() and not matches.rejected.any()
    expected = _shifted_sphere_offset(normals, shift)
    np.testing.assert_allclose(matches.offset_mm, expected, atol=0.05)
    np.testing.assert_allclose(matches.normal_mm, RADIUS + expected, atol=0.05)
    assert np.all(matches.line_distance_mm < 0.5)
    # the observed point is the mean of the points within match_mean_mm of the line: on the
    # sphere to within its curvature's sagitta over that radius (0.02 mm)
    np.testing.assert_allclose(np.linalg.norm(matches.points_mm - shift, axis=1), RADIUS,
                               atol=0.05)


def test_features_facing_away_from_the_camera_are_hidden():
    normals = _fibonacci_sphere(60)
    observed = RADIUS * _fibonacci_sphere(40_000)
    camera = np.array([0.0, 0.0, 600.0])
    matches = match_features(RADIUS * normals, normals, observed, VisionSettings(),
                             camera_mm=camera)
    facing = np.einsum("ij,ij->i", camera - RADIUS * normals, normals) > 0
    assert 20 < facing.sum() < 40
    # the sphere's own surface lies at every feature, edge-on ones included: all facing match
    np.testing.assert_array_equal(matches.matched, facing)
    np.testing.assert_array_equal(matches.hidden, ~facing)
    assert np.isnan(matches.points_mm[~facing]).all()
    assert np.isnan(matches.normal_mm[~facing]).all()


def test_an_edge_on_feature_does_not_match_the_far_face_of_a_thin_part():
    # a 16 mm slab: its top face (z = 0) has lost its points around the feature, as a face
    # seen nearly edge-on loses its pixels, and the line along the feature's normal meets the
    # bottom face 16 mm inward
    top, bottom = _plane_at(0.0), _plane_at(-16.0)
    holed = np.vstack([top[np.hypot(top[:, 0], top[:, 1]) > 6.0], bottom])
    feature, normal = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    overhead = np.array([0.0, 0.0, 600.0])
    edge_on = 600.0 * np.array([np.sin(np.radians(80.0)), 0.0, np.cos(np.radians(80.0))])
    seen_from_above = match_features(feature, normal, holed, VisionSettings(), overhead)
    assert seen_from_above.matched[0] and seen_from_above.offset_mm[0] == -16.0  # the paper's
    seen_edge_on = match_features(feature, normal, holed, VisionSettings(), edge_on)
    assert seen_edge_on.hidden[0] and not seen_edge_on.matched[0]
    # with its own face there, the edge-on feature matches it; 90 degrees takes none as edge-on
    whole = np.vstack([top, bottom])
    assert match_features(feature, normal, whole, VisionSettings(), edge_on).offset_mm[0] == 0.0
    paper = VisionSettings(match_max_view_deg=90.0)
    assert match_features(feature, normal, holed, paper, edge_on).offset_mm[0] == -16.0


def test_averaged_matches_scatter_less_than_the_nearest_point():
    # a plane sampled every 1 mm with the D415's depth noise at 0.55 m (about 0.3 mm) along
    # its normal: the mean of the 12-13 points within 2 mm of each line scatters about 0.29 times
    # as much as the nearest point (1 / sqrt(12.5)), and neither is biased
    rng = np.random.default_rng(3)
    plane = _plane_at(0.0, half=30.0, step=1.0)
    features = np.column_stack([rng.uniform(-20, 20, (200, 2)), np.zeros(200)])
    normals = np.tile([0.0, 0.0, 1.0], (200, 1))
    offsets = {}
    for radius in (0.0, 2.0):
        draws = []
        for _ in range(20):
            noisy = plane + np.column_stack([rng.uniform(-0.4, 0.4, (len(plane), 2)),
                                             rng.normal(0.0, 0.3, len(plane))])
            draws.append(match_features(features, normals, noisy,
                                        VisionSettings(match_mean_mm=radius)).offset_mm)
        offsets[radius] = np.array(draws)
    nearest, averaged = offsets[0.0].std(), offsets[2.0].std()
    assert 0.25 < nearest < 0.35
    assert averaged < 0.35 * nearest
    assert abs(offsets[0.0].mean()) < 0.02 and abs(offsets[2.0].mean()) < 0.01


def _plane_at(z: float, half: float = 40.0, step: float = 0.5) -> np.ndarray:
    x, y = np.meshgrid(np.arange(-half, half, step), np.arange(-half, half, step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def test_far_matches_are_rejected_and_missing_surfaces_hidden():
    settings = VisionSettings()  # d_m 4, d_l 20, search 30
    features = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (2, 1))
    near = match_features(features, normals, _plane_at(12.0), settings)
    np.testing.assert_allclose(near.offset_mm, [12.0, 12.0])
    assert near.matched.all()
    far = match_features(features, normals, _plane_at(25.0), settings)  # beyond d_l
    assert far.rejected.all() and not far.matched.any() and not far.hidden.any()
    assert np.isnan(far.offset_mm).all()
    gone = match_features(features, normals, _plane_at(35.0), settings)  # beyond the search
    assert gone.hidden.all() and not gone.rejected.any()
    # a surface with a slot around the line: hidden when its edges are more than d_m away
    plane = _plane_at(5.0)
    wide = match_features(features[:1], normals[:1], plane[np.abs(plane[:, 0]) > 5.0], settings)
    assert wide.hidden.all()
    assert not wide.line_distance_mm[0] <= settings.match_line_mm  # NaN: none near the line
    narrow = plane[np.abs(plane[:, 0]) > 3.5]
    assert match_features(features[:1], normals[:1], narrow, settings).matched.all()


def test_no_robot_points_hides_every_feature():
    features = RADIUS * _fibonacci_sphere(10)
    matches = match_features(features, features / RADIUS, np.zeros((0, 3)))
    assert matches.hidden.all() and matches.matched_count == 0
    assert np.isnan(matches.line_distance_mm).all()
