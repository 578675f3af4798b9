"""The pushing object's axis (vision.contacts.object_axes) and the push direction chosen from
it (estimation.sensing.pushing_directions), against analytic shapes."""

from __future__ import annotations

import numpy as np

from softforce_cli.estimation.sensing import pushing_directions
from softforce_cli.vision.contacts import object_axes


def _rod_top_half(tip: np.ndarray, axis: np.ndarray, rng: np.random.Generator,
                  radius: float = 5.0, length: float = 90.0, noise_mm: float = 0.5
                  ) -> np.ndarray:
    """Points on the upper half (z >= axis) of a rod's surface, running from `tip` back
    against `axis` (the direction it pushes), as an overhead camera sees it, with noise."""
    u = np.cross(axis, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t = rng.uniform(0, length, 4000)
    angle = rng.uniform(0, 2 * np.pi, 4000)
    points = (tip - t[:, None] * axis + radius * (np.cos(angle)[:, None] * u
                                                    + np.sin(angle)[:, None] * v))
    points = points[points[:, 2] >= (tip - t[:, None] * axis)[:, 2]]
    return points + rng.normal(scale=noise_mm, size=points.shape)


def test_a_rods_axis_is_found_and_points_into_the_robot():
    rng = np.random.default_rng(0)
    push = np.array([0.0, -0.611, -0.792])  # the sample probe's direction
    tip = np.array([0.0, 45.0, 90.0])
    rod = _rod_top_half(tip, push, rng)
    axes = object_axes(tip[None], rod)
    angle = np.degrees(np.arccos(np.clip(axes[0] @ push, -1, 1)))
    assert angle < 2.0


def test_a_ball_has_no_axis():
    rng = np.random.default_rng(1)
    ball = rng.normal(size=(3000, 3))
    ball = 15.0 * ball / np.linalg.norm(ball, axis=1, keepdims=True) + [0, 0, 120]
    assert np.isnan(object_axes(np.array([[0.0, 0.0, 105.0]]), ball)).all()
    assert np.isnan(object_axes(np.array([[0.0, 0.0, 0.0]]), np.zeros((0, 3)))).all()


def test_the_push_falls_back_to_the_normal_when_the_axis_is_unusable():
    inward = np.array([[0.0, 0.0, -1.0]] * 3)
    tilted = np.array([0.0, np.sin(0.3), -np.cos(0.3)])
    along_surface = np.array([1.0, 0.0, 0.0])
    axes = np.array([tilted, along_surface, [np.nan] * 3])
    directions = pushing_directions(inward, axes, 60.0)
    np.testing.assert_allclose(directions, [tilted, inward[1], inward[2]])
