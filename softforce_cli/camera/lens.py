"""Lens distortion: where a ray through the optical centre meets the image, and back.

Coordinates are normalised: a ray (x, y, 1) in the optical frame, and the distorted point
(xd, yd) whose pixel is (fx xd + cx, fy yd + cy). The models are the ones a
foxglove.CameraCalibration (ROS's sensor_msgs/CameraInfo) names, with OpenCV's formulas,
and the ones librealsense reports:

| model (other names) | coefficients |
|---|---|
| `plumb_bob` (librealsense `brown_conrady`) | k1 k2 p1 p2 k3 |
| `rational_polynomial` | k1 k2 p1 p2 k3 k4 k5 k6 |
| `kannala_brandt` (ROS `equidistant`, librealsense `kannala_brandt4`) | k1 k2 k3 k4 |
| `modified_brown_conrady` (librealsense `inverse_brown_conrady`) | k1 k2 p1 p2 k3 |

librealsense 2.5x projects and deprojects its `inverse_brown_conrady` as the modified model
(tangential terms on the radially distorted point), and so aligns depth to such a colour
stream.

Each model is a closed form from the ray to the pixel (distort); the pixel's ray (undistort)
is solved by Newton's method. Fewer coefficients than a model takes are read as the rest
being 0 (a `plumb_bob` D of 4 values has no k3).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

COEFFICIENT_COUNTS = {
    "plumb_bob": 5,
    "rational_polynomial": 8,
    "kannala_brandt": 4,
    "modified_brown_conrady": 5,
}
# other names of the same models (ROS's and librealsense's)
ALIASES = {"equidistant": "kannala_brandt", "brown_conrady": "plumb_bob",
           "kannala_brandt4": "kannala_brandt", "inverse_brown_conrady": "modified_brown_conrady"}
# Newton's method for the direction without a closed form: far below a pixel's 1e-3
TOLERANCE = 1e-10
MAX_ITERATIONS = 30


class LensModelError(ValueError):
    """A distortion model softforce does not know, or coefficients it cannot take."""


@dataclass(frozen=True)
class LensDistortion:
    """A lens' distortion model and its coefficients (D of a camera_info).

    model        : one of COEFFICIENT_COUNTS (or an ALIASES name, stored as its model).
    coefficients : the model's coefficients in its order, padded with zeros to its count.
    """

    model: str
    coefficients: tuple[float, ...]

    @classmethod
    def from_camera_info(cls, model: str, coefficients: Iterable[float]
                         ) -> LensDistortion | None:
        """The distortion a camera_info names; None when every coefficient is 0 (whatever
        the model, the image is then a pinhole one). LensModelError for an unknown model or
        more non-zero coefficients than it takes (librealsense pads its 4 to 5 with a 0)."""
        values = tuple(float(c) for c in coefficients)
        if not any(values):
            return None
        name = model.strip().lower()
        name = ALIASES.get(name, name)
        if name not in COEFFICIENT_COUNTS:
            known = ", ".join([*COEFFICIENT_COUNTS, *ALIASES])
            raise LensModelError(f"distortion model {model!r} is not one softforce knows "
                                 f"({known})")
        count = COEFFICIENT_COUNTS[name]
        if any(values[count:]):
            raise LensModelError(f"distortion model {name} takes {count} coefficients, "
                                 f"got {len(values)}")
        if not np.all(np.isfinite(values)):
            raise LensModelError(f"distortion coefficients must be finite, got {values}")
        return cls(name, (values + (0.0,) * count)[:count])


def distort(distortion: LensDistortion, x: np.ndarray, y: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Rays (x, y, 1) -> the distorted normalised points (xd, yd) where they meet the image;
    x, y (...) float arrays of one shape."""
    c = distortion.coefficients
    if distortion.model == "kannala_brandt":
        r = np.hypot(x, y)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1.0 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3]))))
        # theta_d / r -> 1 on the axis (theta ~ r there)
        scale = np.divide(theta_d, r, out=np.ones_like(r), where=r > 1e-12)
        return x * scale, y * scale
    if distortion.model == "rational_polynomial":
        r2 = x * x + y * y
        radial = ((1.0 + r2 * (c[0] + r2 * (c[1] + r2 * c[4])))
                  / (1.0 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))))
        return _tangential(c[2], c[3], x, y, r2, x * radial, y * radial)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (c[0] + r2 * (c[1] + r2 * c[4]))
    if distortion.model == "modified_brown_conrady":
        # librealsense: the tangential terms act on the radially distorted point, with the
        # undistorted radius
        return _tangential(c[2], c[3], x * radial, y * radial, r2, x * radial, y * radial)
    return _tangential(c[2], c[3], x, y, r2, x * radial, y * radial)


def undistort(distortion: LensDistortion, xd: np.ndarray, yd: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Distorted normalised points (xd, yd) -> the rays (x, y, 1) that meet the image there:
    the inverse of distort, by Newton's method from the points themselves (a lens moves
    them little), its 2x2 Jacobian by central differences; NaN where it does not converge
    (a pixel no ray of the model reaches)."""
    tx, ty = np.asarray(xd, dtype=float), np.asarray(yd, dtype=float)
    x, y = tx.copy(), ty.copy()
    step = 1e-6
    for _ in range(MAX_ITERATIONS):
        ex, ey = (a - b for a, b in zip(distort(distortion, x, y), (tx, ty), strict=True))
        if np.all(np.abs(ex) + np.abs(ey) < TOLERANCE):
            return x, y
        ax, ay = distort(distortion, x + step, y)
        bx, by = distort(distortion, x - step, y)
        cx, cy = distort(distortion, x, y + step)
        dx, dy = distort(distortion, x, y - step)
        j11, j21 = (ax - bx) / (2 * step), (ay - by) / (2 * step)
        j12, j22 = (cx - dx) / (2 * step), (cy - dy) / (2 * step)
        det = j11 * j22 - j12 * j21
        with np.errstate(divide="ignore", invalid="ignore"):
            x = x - (j22 * ex - j12 * ey) / det
            y = y - (j11 * ey - j21 * ex) / det
    fx, fy = distort(distortion, x, y)
    missed = ~(np.abs(fx - tx) + np.abs(fy - ty) < 100 * TOLERANCE)
    return np.where(missed, np.nan, x), np.where(missed, np.nan, y)


def _tangential(p1: float, p2: float, x: np.ndarray, y: np.ndarray, r2: np.ndarray,
                radial_x: np.ndarray, radial_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """radial (x, y) plus the decentring terms of (x, y) at squared radius r2."""
    return (radial_x + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            radial_y + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
