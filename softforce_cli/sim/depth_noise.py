"""Sensor model of an Intel RealSense D415: what its aligned depth and colour look like.

Turns an ideal RenderedView (softforce_cli.sim.render) into the uint16 depth in mm and uint8
colour a D415 delivers: axial noise growing with the square of the distance, 1 mm
quantisation, holes where the right imager cannot see the point (stereo occlusion shadow and
the invalid band at the image's left edge), holes at grazing incidence and at depth edges, a
minimum and maximum range, and colour noise. Pure functions; randomness only through the
`np.random.Generator` passed in, drawn in a fixed order, so one seed gives one image.

Sources (docs/virtual_camera.md has the details):
[1] Grunnet-Jepsen, Sweetser, Woodfill, "Tuning depth cameras for best performance" (PDF title
    "Best-Known-Methods for Tuning Intel RealSense D400 Depth Cameras for Best Performance"),
    Intel RealSense white paper, rev 1.9: RMS depth error = z^2 * subpixel / (f * baseline),
    subpixel about 0.08 for a well textured scene; MinZ = f * baseline / 126 (126 disparities).
[2] "Intel RealSense D400 Series Product Family Datasheet", Intel document 337029: D415 stereo
    baseline 55 mm, range up to about 10 m, the left imager as depth reference and the
    invalid depth band of width f * baseline / z pixels on the left of the image.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.special import ndtri

from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.sim.render import RenderedView

UINT16_MAX = 65535
NOTHING_DEPTH_MM = 1e9  # stands for "no surface" (infinitely far) in the edge test


@dataclass(frozen=True)
class D415Noise:
    """Parameters of the D415 sensor model, each with the reason for its default.

    subpixel_px            : RMS disparity error of the stereo matcher in pixels. 0.08 is the
                             typical value [1] gives for a well textured scene (the projector
                             on, good exposure); poorer texture raises it.
    baseline_mm            : distance between the two IR imagers: 55 mm on the D415 ([2]).
    max_disparity_px       : disparities the D4 ASIC searches (126 by default, [1]); sets the
                             minimum range MinZ = f * baseline / max_disparity_px.
    max_depth_mm           : farthest reported depth, about 10 m for a D415 ([2]).
    grazing_cos_drop       : cos(incidence) below which the matcher finds no valid match:
                             0.2, i.e. surfaces within about 12 degrees of the viewing ray,
                             whose texture is foreshortened five-fold (a modelling choice).
    grazing_cos_keep       : cos(incidence) above which grazing is harmless: 0.35 (70 deg);
                             the drop probability falls smoothly (smoothstep) in between.
    edge_jump_mm           : a pixel whose 3x3 neighbourhood spans more than this in ideal depth
                             lies on a depth edge, where the correlation window mixes two
                             surfaces: 15 mm (several sigma at 0.6 m; a modelling choice).
    edge_drop_probability  : chance such an edge pixel is invalid: 0.9, as the D415's
                             second-peak and left-right checks reject most mixed windows
                             (a modelling choice).
    stereo_occlusion       : invalidate points the right imager cannot see: the shadow to the
                             left of nearer objects and the invalid band on the image's left
                             edge (the depth is referenced to the left imager, [2]).
    dropout_probability    : chance of an isolated invalid pixel anywhere; 0 by default
                             (a textured-projector D415 rarely drops pixels on matte surfaces).
    color_sigma            : RMS noise of each colour channel in levels: 2, a well lit indoor
                             scene at low gain (a modelling choice).
    """

    subpixel_px: float = 0.08
    baseline_mm: float = 55.0
    max_disparity_px: float = 126.0
    max_depth_mm: float = 10000.0
    grazing_cos_drop: float = 0.2
    grazing_cos_keep: float = 0.35
    edge_jump_mm: float = 15.0
    edge_drop_probability: float = 0.9
    stereo_occlusion: bool = True
    dropout_probability: float = 0.0
    color_sigma: float = 2.0

    def scaled(self, depth_noise_scale: float) -> D415Noise:
        """These parameters with the axial depth noise multiplied by `depth_noise_scale` (>= 0):
        sigma_z is proportional to subpixel_px, so only that changes; holes, quantisation and
        colour noise stay, and the random draws keep their order (one seed, the same holes).
        A scale of 1 leaves every value, and so every draw, bit-identical."""
        if depth_noise_scale < 0:
            raise ValueError(f"depth noise scale must be >= 0, got {depth_noise_scale}")
        return replace(self, subpixel_px=self.subpixel_px * depth_noise_scale)


def axial_sigma_mm(depth_mm: np.ndarray, focal_px: float, noise: D415Noise) -> np.ndarray:
    """RMS depth error of a stereo camera (Intel's formula, [1]).

    depth_mm (...) float mm, focal_px the depth image's fx -> (...) float64 mm:
    sigma_z = z^2 * subpixel / (f * baseline); at z = 580 mm and f = 615 px, about 0.8 mm.
    """
    depth = np.asarray(depth_mm, dtype=float)
    return depth**2 * noise.subpixel_px / (focal_px * noise.baseline_mm)


def min_depth_mm(focal_px: float, noise: D415Noise) -> float:
    """Nearest depth the stereo search can match, MinZ = f * baseline / max disparity ([1])."""
    return focal_px * noise.baseline_mm / noise.max_disparity_px


def grazing_drop_probability(cos_incidence: np.ndarray, noise: D415Noise) -> np.ndarray:
    """(...) cos of the incidence angle -> (...) float64 probability that the pixel is a hole.

    1 below grazing_cos_drop, 0 above grazing_cos_keep, a smoothstep in between.
    """
    span = noise.grazing_cos_keep - noise.grazing_cos_drop
    t = np.clip((np.asarray(cos_incidence, dtype=float) - noise.grazing_cos_drop) / span, 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def _range_3x3(values: np.ndarray) -> np.ndarray:
    """(h, w) -> (h, w) max minus min over each 3x3 neighbourhood, borders replicated."""
    padded = np.pad(values, 1, mode="edge")
    row_max = np.maximum(np.maximum(padded[:, :-2], padded[:, 1:-1]), padded[:, 2:])
    row_min = np.minimum(np.minimum(padded[:, :-2], padded[:, 1:-1]), padded[:, 2:])
    high = np.maximum(np.maximum(row_max[:-2], row_max[1:-1]), row_max[2:])
    low = np.minimum(np.minimum(row_min[:-2], row_min[1:-1]), row_min[2:])
    return high - low


def depth_edge_mask(depth_mm: np.ndarray, jump_mm: float) -> np.ndarray:
    """(h, w) depth, 0 = nothing -> (h, w) bool, True on surface pixels whose 3x3
    neighbourhood spans more than `jump_mm`; a neighbour with no surface counts as infinitely
    far, so silhouettes against empty space are edges too."""
    # float32 (resolution 1e-4 mm at 1 m) halves the memory traffic of the six passes.
    far = np.where(depth_mm > 0, depth_mm, NOTHING_DEPTH_MM).astype(np.float32)
    return (depth_mm > 0) & (_range_3x3(far) > jump_mm)


def stereo_occlusion_mask(depth_mm: np.ndarray, focal_px: float, baseline_mm: float) -> np.ndarray:
    """(h, w) depth, 0 = nothing -> (h, w) bool, True where the right imager cannot see the
    surface point that the left (reference) imager sees.

    The right imager sits baseline_mm along +x, so a point at column u appears in it at
    r = u - f * baseline / z. It is hidden when a pixel further right, u' > u, lands at or
    left of it (r' <= r: a nearer surface in front), or when r < 0 (outside the right image:
    the invalid band on the left edge). Pixels with no surface are infinitely far (r = u).
    """
    h, w = depth_mm.shape
    column = np.arange(w, dtype=float)
    disparity = np.divide(
        focal_px * baseline_mm, depth_mm, out=np.zeros((h, w)), where=depth_mm > 0
    )
    right_column = column - disparity
    # min over u' > u of r(u'): a reversed running minimum, shifted by one column.
    running_min = np.minimum.accumulate(right_column[:, ::-1], axis=1)[:, ::-1]
    min_to_the_right = np.concatenate([running_min[:, 1:], np.full((h, 1), np.inf)], axis=1)
    hidden = (right_column >= min_to_the_right) | (right_column < 0.0)
    return hidden & (depth_mm > 0)


def hole_probability(
    depth_mm: np.ndarray, cos_incidence: np.ndarray, focal_px: float, noise: D415Noise
) -> np.ndarray:
    """(h, w) ideal depth and incidence -> (h, w) float64 probability that a pixel reads 0.

    Certain where there is no surface, out of range or (if enabled) in the stereo occlusion
    shadow; otherwise the largest of the grazing, depth-edge and random dropout chances.
    """
    probability = np.maximum(
        grazing_drop_probability(cos_incidence, noise), noise.dropout_probability
    )
    edge = depth_edge_mask(depth_mm, noise.edge_jump_mm)
    probability = np.where(edge, np.maximum(probability, noise.edge_drop_probability), probability)
    # No surface (depth 0) is nearer than MinZ, so out of range too.
    certain = (depth_mm < min_depth_mm(focal_px, noise)) | (depth_mm > noise.max_depth_mm)
    if noise.stereo_occlusion:
        certain |= stereo_occlusion_mask(depth_mm, focal_px, noise.baseline_mm)
    return np.where(certain, 1.0, probability)


def noisy_depth_mm(
    depth_mm: np.ndarray,
    cos_incidence: np.ndarray,
    focal_px: float,
    rng: np.random.Generator,
    noise: D415Noise = D415Noise(),
) -> np.ndarray:
    """Ideal depth (h, w) float mm (0 = nothing) -> (h, w) uint16 mm as a D415 reports it.

    Gaussian axial noise of sigma axial_sigma_mm, rounding to whole millimetres, then holes
    (0) drawn with hole_probability. Draws a normal then a uniform field, both (h, w).
    """
    depth = np.asarray(depth_mm, dtype=float)
    measured = depth + axial_sigma_mm(depth, focal_px, noise) * rng.standard_normal(depth.shape)
    quantised = np.clip(np.rint(measured), 0, UINT16_MAX).astype(np.uint16)
    holes = rng.random(depth.shape) < hole_probability(depth, cos_incidence, focal_px, noise)
    quantised[holes] = 0
    return quantised


@lru_cache(maxsize=4)
def _rounded_gaussian_table(sigma: float) -> np.ndarray:
    """(65536,) int16 inverse CDF of rint(sigma * N(0, 1)) at the centres of 65536 equal
    probability bins: indexing it with uniform uint16 draws samples the rounded Gaussian
    (probabilities within about 2/65536 of exact, tails cut beyond 4.2 sigma)."""
    quantiles = ndtri((np.arange(65536) + 0.5) / 65536)
    table = np.rint(sigma * quantiles).astype(np.int16)
    table.setflags(write=False)
    return table


def noisy_color(
    color: np.ndarray, rng: np.random.Generator, noise: D415Noise = D415Noise()
) -> np.ndarray:
    """(h, w, 3) uint8 -> (h, w, 3) uint8 with Gaussian noise of color_sigma levels, rounded
    and clipped.

    For integer levels c, rint(c + sigma N) = c + rint(sigma N), so the rounded noise is drawn
    directly from a table (one uint16 draw per channel), five times faster than normals.
    """
    draws = rng.integers(0, 65536, size=color.shape, dtype=np.uint16)
    noisy = color.astype(np.int16) + _rounded_gaussian_table(float(noise.color_sigma)).take(draws)
    return np.clip(noisy, 0, 255).astype(np.uint8)


def apply_d415(
    view: RenderedView,
    intrinsics: CameraIntrinsics,
    rng: np.random.Generator,
    noise: D415Noise = D415Noise(),
) -> tuple[np.ndarray, np.ndarray]:
    """An ideal view -> (depth (h, w) uint16 mm, colour (h, w, 3) uint8) as a D415 gives them.

    The depth is aligned to the colour image, so the disparity uses the colour image's fx.
    Draws depth noise, then holes, then colour noise from `rng`: one seed, one image pair.
    """
    depth = noisy_depth_mm(view.depth_mm, view.cos_incidence, intrinsics.fx, rng, noise)
    return depth, noisy_color(view.color, rng, noise)
