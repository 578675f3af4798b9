"""Diagnosis building blocks against independent references (plane geometry, known noise,
a linear problem with a known answer)."""

import numpy as np

from softforce_cli.diagnosis.fitting import Fields, Fit
from softforce_cli.diagnosis.hypotheses import Hypothesis
from softforce_cli.diagnosis.residuals import point_residuals
from softforce_cli.diagnosis.selection import clear_improvement, held_out, noise_floor_mm
from softforce_cli.diagnosis.states import FrameContexts, group_states, trajectory_segments


def test_point_to_plane_residuals_are_the_offsets_along_the_normal():
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.arange(0, 50, 5.0), np.arange(0, 50, 5.0)), -1).reshape(-1, 2)
    surface = np.c_[grid, np.zeros(len(grid))]
    normals = np.tile([0.0, 0.0, 1.0], (len(surface), 1))
    offsets = rng.uniform(-3, 3, 200)
    points = np.c_[rng.uniform(5, 45, (200, 2)), offsets]
    residual, node = point_residuals(points, surface, normals)
    np.testing.assert_allclose(residual, offsets)
    assert np.all(node >= 0)
    far = point_residuals(np.array([[20.0, 20.0, 40.0]]), surface, normals)
    assert np.isnan(far[0][0]) and far[1][0] == -1


def test_states_split_loading_from_unloading_and_segments_are_contiguous():
    actuation = np.array([[0, 0], [0, 0], [5, 0], [5, 0], [10, 0], [5, 0], [5, 0], [0, 0]],
                         dtype=float)
    direction = np.array([[0, 0], [0, 0], [1, 0], [1, 0], [1, 0], [-1, 0], [-1, 0], [-1, 0]])
    states = group_states(FrameContexts(actuation, direction, np.zeros(8)))
    # 0 (never moved), 5 loading, 10, 5 unloading, 0 unloading
    assert states.count == 5
    assert states.of_frame[2] != states.of_frame[5]
    segments = trajectory_segments(states, np.zeros(8, dtype=int))
    assert np.all(np.diff(segments) >= 0) and segments.max() >= 2


def test_noise_floor_recovers_the_frame_noise():
    rng = np.random.default_rng(1)
    states = np.repeat(np.arange(10), 6)
    systematic = rng.normal(0, 2.0, (10, 300))
    mean = systematic[states] + rng.normal(0, 0.7, (60, 300))
    floor = noise_floor_mm(Fields(mean, np.ones_like(mean)), states)
    assert abs(floor - 0.7) < 0.03


def _linear_fit(truth: float, noise: float, seed: int):
    """A one-parameter linear problem: residual = truth * pattern - p * pattern + noise."""
    rng = np.random.default_rng(seed)
    frames, nodes = 48, 200
    pattern = np.tile(np.sin(np.linspace(0, 6, nodes)), (frames, 1))
    nominal = Fields(truth * pattern + rng.normal(0, noise, (frames, nodes)),
                     np.ones((frames, nodes)))
    hypothesis = Hypothesis("stiffness_scale", None, ("scale",), np.zeros(1), np.ones(1),
                            np.array([-10.0]), np.array([10.0]))
    fitted = Fields(nominal.mean_mm - truth * pattern, nominal.count)
    return Fit(hypothesis, np.array([truth]), fitted, -pattern[None]), nominal


def test_held_out_selection_accepts_a_real_effect_and_rejects_noise():
    segments = np.repeat(np.arange(8), 6)
    real, nominal = _linear_fit(3.0, 0.5, 2)
    result = held_out(real, nominal, segments)
    assert result.rms_after_mm < 0.6 < 2.0 < result.rms_before_mm
    assert clear_improvement(result, 0.5)
    # no effect at all: the fit cannot improve what is only noise
    empty, nominal = _linear_fit(0.0, 0.5, 3)
    result = held_out(empty, nominal, segments)
    assert not clear_improvement(result, 0.5)
