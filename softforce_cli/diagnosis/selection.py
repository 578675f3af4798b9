"""Held-out error, the noise floor, and which effects the data supports.

Validation leaves one trajectory segment out at a time (contiguous frames, never random
frames: neighbouring frames share their state and noise, so a random split would flatter any
fit), refits the effect's parameters on the rest (linearised at the full fit) and measures the
residual on the segment left out. An effect is accepted only when its held-out improvement is
clear: beyond twice its standard error over segments (an effective sample size that counts
segments, not frames) and a fixed share of the excess over the noise floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softforce_cli.diagnosis.fitting import Fields, Fit, linear_step

# An accepted effect removes at least this share of the held-out mean square above the noise
# floor: a smaller gain is within what the mesh correction and the law leave (measured on
# clean recordings, docs/diagnosis.md).
MIN_EXCESS_REDUCTION = 0.3
# ... and at least this much held-out RMS (mm): far below what a camera resolves otherwise.
MIN_RMS_GAIN_MM = 0.15
# A systematic residual (RMS above the floor) larger than this after the best model is a
# structured mismatch nothing in the library explains.
UNEXPLAINED_MM = 1.0


@dataclass(frozen=True)
class HeldOut:
    """Held-out residuals of one fit: rms_before_mm (nominal) and rms_after_mm (fitted) over
    every segment left out, and per-segment mean-square gains (K,)."""

    rms_before_mm: float
    rms_after_mm: float
    gains: np.ndarray

    @property
    def gain_z(self) -> float:
        """Mean segment gain over its standard error (the segments are the samples)."""
        k = len(self.gains)
        spread = self.gains.std(ddof=1) / np.sqrt(k) if k > 1 else np.inf
        return float(self.gains.mean() / spread) if spread > 0 else np.inf


def noise_floor_mm(fields: Fields, of_frame: np.ndarray) -> float:
    """The frame-to-frame scatter of the residual field within states (mm): what a perfect
    model still leaves per frame and node. Bias-corrected for the state means removed."""
    mean, count = fields.mean_mm, fields.count
    squares, dof = 0.0, 0.0
    for s in np.unique(of_frame):
        rows = of_frame == s
        if rows.sum() < 2:
            continue
        w = count[rows]
        total = w.sum(axis=0)
        centre = np.divide((w * mean[rows]).sum(axis=0), total, out=np.zeros_like(total),
                           where=total > 0)
        squares += float(np.sum(w * (mean[rows] - centre) ** 2))
        # each node seen in n frames loses one of its n frames to its mean
        seen = (w > 0).sum(axis=0)
        dof += float(np.sum(np.where(seen > 1, total * (seen - 1) / np.maximum(seen, 1), 0)))
    return float(np.sqrt(squares / dof)) if dof > 0 else float("nan")


def effective_sample_size(fields: Fields) -> float:
    """Frames worth of independent evidence: t (1 - rho) / (1 + rho) with rho the lag-one
    autocorrelation of the per-frame mean residual."""
    weights = fields.count.sum(axis=1)
    series = np.divide((fields.count * fields.mean_mm).sum(axis=1), weights,
                       out=np.zeros_like(weights), where=weights > 0)
    t = len(series)
    if t < 3 or np.ptp(series) == 0:
        return float(t)
    centred = series - series.mean()
    rho = float(np.clip(centred[1:] @ centred[:-1] / (centred @ centred), -0.95, 0.95))
    return float(t * (1 - rho) / (1 + rho))


def held_out(fit_: Fit, nominal: Fields, segments: np.ndarray) -> HeldOut:
    """Leave each segment out, refit (linearised at the full fit), predict it."""
    fields, jacobian = fit_.fields, fit_.jacobian
    before_sq = after_sq = weight = 0.0
    gains = []
    for k in np.unique(segments):
        out = segments == k
        train = ~out
        step = linear_step(fields.mean_mm, fields.count, jacobian, rows=train)
        hypothesis = fit_.hypothesis
        step = np.clip(fit_.values + step, hypothesis.lower, hypothesis.upper) - fit_.values
        predicted = fields.mean_mm[out] + np.tensordot(step, jacobian[:, out], axes=1)
        w = fields.count[out]
        w_nominal = nominal.count[out]
        b = float(np.sum(w_nominal * nominal.mean_mm[out] ** 2))
        a = float(np.sum(w * predicted**2))
        before_sq, after_sq, weight = before_sq + b, after_sq + a, weight + w.sum()
        gains.append((b / max(w_nominal.sum(), 1)) - (a / max(w.sum(), 1)))
    return HeldOut(float(np.sqrt(before_sq / weight)), float(np.sqrt(after_sq / weight)),
                   np.array(gains))


def clear_improvement(result: HeldOut, floor_mm: float) -> bool:
    """True when the held-out gain is beyond noise and a real share of the excess."""
    excess = result.rms_before_mm**2 - floor_mm**2
    gain = result.rms_before_mm**2 - result.rms_after_mm**2
    return bool(result.gain_z > 2.0
                and result.rms_before_mm - result.rms_after_mm > MIN_RMS_GAIN_MM
                and excess > 0 and gain > MIN_EXCESS_REDUCTION * excess)


def systematic_mm(rms_mm: float, floor_mm: float) -> float:
    """The RMS residual above the noise floor: sqrt(rms^2 - floor^2), 0 when below."""
    return float(np.sqrt(max(rms_mm**2 - floor_mm**2, 0.0)))


def confidence_intervals(fit_: Fit, effective_frames: float) -> np.ndarray:
    """(k, 2) 95% intervals of the free parameters from the Gauss-Newton covariance, the
    residual variance inflated by frames / effective frames (correlated frames)."""
    fields, jacobian = fit_.fields, fit_.jacobian
    k = len(jacobian)
    flat = jacobian.reshape(k, -1)
    w = fields.count.ravel()
    normal = (flat * w) @ flat.T
    frames = len(fields.mean_mm)
    sigma2 = float(np.sum(w * fields.mean_mm.ravel() ** 2) / max(w.sum() - k, 1))
    inflation = frames / max(effective_frames, 1.0)
    # weights count points: the points of one node in one frame share its error, so the
    # variance is per node-frame (count 1), not per point
    per_point = w.sum() / max(np.count_nonzero(w), 1)
    covariance = np.linalg.pinv(normal) * sigma2 * inflation * per_point
    half = 1.96 * np.sqrt(np.clip(np.diag(covariance), 0, None))
    return np.stack([fit_.values - half, fit_.values + half], axis=1)
