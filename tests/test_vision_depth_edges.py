"""Pixels that carry one side of a depth edge's depth in the other side's colour
(vision.depth_edges), on images whose bleed is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter

from softforce_cli.vision.depth_edges import _window_extreme, bled_pixels

BLUE, BROWN = np.array([40, 90, 210]), np.array([150, 118, 84])


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40 x 40 px blue square 50 mm in front of a brown table, with 1 mm of depth noise
    and 2 levels of colour noise -> depth (h, w) uint16, colour (h, w, 3) uint8, the square's
    mask."""
    square = np.zeros((100, 120), dtype=bool)
    square[30:70, 40:80] = True
    depth = np.where(square, 550.0, 600.0) + rng.normal(0.0, 1.0, square.shape)
    color = np.where(square[..., None], BLUE, BROWN) + rng.normal(0.0, 2.0, (*square.shape, 3))
    return (np.rint(depth).astype(np.uint16), np.clip(np.rint(color), 0, 255).astype(np.uint8),
            square)


def test_a_clean_edge_drops_nothing():
    depth, color, _ = _scene(np.random.default_rng(0))
    assert not bled_pixels(depth, color, 2, 10.0, 30.0).any()


@pytest.mark.parametrize("bleed", [1, 2])
def test_the_nearer_depth_bled_past_the_edge_is_found_and_nothing_else(bleed):
    """Edge fattening: the table's pixels within `bleed` px of the square take its depth
    and keep their colour; those are dropped, but for a few at the corners, where the bled
    pixels outnumber the square's in a pixel's window, and nothing else."""
    depth, color, square = _scene(np.random.default_rng(1))
    bled = maximum_filter(square, 2 * bleed + 1) & ~square
    fattened = depth.copy()
    fattened[bled] = 550
    found = bled_pixels(fattened, color, 2, 10.0, 30.0)
    assert not (found & ~bled).any()
    assert np.count_nonzero(found) >= (0.97 if bleed == 1 else 0.95) * np.count_nonzero(bled)


def test_a_colour_registered_off_the_depth_is_found_on_both_sides():
    """The colour image shifted 2 px right of the depth: the square's left 2 columns show the
    table's colour at the square's depth, the 2 table columns right of it the square's
    colour at the table's depth; those are dropped, the rest kept."""
    depth, color, square = _scene(np.random.default_rng(2))
    shifted = np.roll(color, 2, axis=1)
    found = bled_pixels(depth, shifted, 2, 10.0, 30.0)
    expected = np.zeros_like(square)
    expected[30:70, 40:42] = True  # the square in the table's colour
    expected[30:70, 80:82] = True  # the table in the square's colour
    np.testing.assert_array_equal(found, expected)


def test_only_the_window_is_looked_at_and_off_is_off():
    depth, color, square = _scene(np.random.default_rng(3))
    fattened = depth.copy()
    fattened[maximum_filter(square, 5) & ~square] = 550
    left_half = bled_pixels(fattened, color, 2, 10.0, 30.0, window=(0, 0, 60, 100))
    assert left_half.any() and not left_half[:, 60:].any()
    assert not bled_pixels(fattened, color, 0, 10.0, 30.0).any()


@pytest.mark.parametrize("reach", [1, 2, 3])
def test_window_extremes_are_scipys_filters(reach):
    values = np.random.default_rng(reach).integers(0, 65535, (37, 53)).astype(np.uint16)
    size = 2 * reach + 1
    np.testing.assert_array_equal(_window_extreme(values, reach, np.minimum),
                                  minimum_filter(values, size, mode="nearest"))
    np.testing.assert_array_equal(_window_extreme(values, reach, np.maximum),
                                  maximum_filter(values, size, mode="nearest"))
