"""Frames -> distinct actuation states, and contiguous trajectory segments for validation.

A state is what the FE model needs to predict a frame: the cable inputs, the direction each
cable last moved (loading or unloading, for friction) and how long the inputs have been held
(for creep), binned. Frames of one state share one FE solve; a 200-frame recording with holds
has a few dozen states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Inputs closer than this (mm or N) are one state: well below what a camera resolves (a
# 0.05 mm cable change moves the Diamond's surface by about 0.1 mm).
ACTUATION_TOLERANCE = 0.05
# Hold-time bin edges (s): creep follows log time, so the bins are geometric.
HOLD_BINS_S = (0.0, 1.0, 3.0, 9.0, 27.0)
# Trajectory segments for leave-one-segment-out validation: at most this many.
MAX_SEGMENTS = 8


@dataclass(frozen=True)
class FrameContexts:
    """Per-frame context of the inputs (t frames, a cables).

    actuation : (t, a) inputs.
    direction : (t, a) +1 after an increase, -1 after a decrease, 0 before any change.
    hold_s    : (t,) seconds since the inputs last changed.
    """

    actuation: np.ndarray
    direction: np.ndarray
    hold_s: np.ndarray


@dataclass(frozen=True)
class States:
    """Distinct states and which frames they serve.

    actuation : (S, a) inputs of each state.
    direction : (S, a) loading direction of each state.
    hold_s    : (S,) representative hold time (the mean over its frames).
    of_frame  : (t,) state index of each frame.
    """

    actuation: np.ndarray
    direction: np.ndarray
    hold_s: np.ndarray
    of_frame: np.ndarray

    @property
    def count(self) -> int:
        return len(self.actuation)


def frame_contexts(times_s: np.ndarray, actuations: np.ndarray) -> FrameContexts:
    """Direction and hold time of every frame from its time (t,) and inputs (t, a)."""
    actuations = np.asarray(actuations, dtype=float)
    t, a = actuations.shape
    direction = np.zeros((t, a))
    hold = np.zeros(t)
    changed_at = times_s[0] if t else 0.0
    for i in range(1, t):  # a sequential recurrence over frames (t is a few hundred)
        step = actuations[i] - actuations[i - 1]
        moved = np.abs(step) > ACTUATION_TOLERANCE
        direction[i] = np.where(moved, np.sign(step), direction[i - 1])
        if moved.any():
            changed_at = times_s[i]
        hold[i] = times_s[i] - changed_at
    return FrameContexts(actuations, direction, hold)


def group_states(contexts: FrameContexts, use_hold: bool = False) -> States:
    """One state per distinct (rounded inputs, direction[, hold bin]) of the frames."""
    keys = [np.round(contexts.actuation / ACTUATION_TOLERANCE).astype(np.int64),
            contexts.direction.astype(np.int64)]
    if use_hold:
        keys.append(np.digitize(contexts.hold_s, HOLD_BINS_S)[:, None])
    _, first, of_frame = np.unique(np.hstack(keys), axis=0, return_index=True,
                                   return_inverse=True)
    of_frame = of_frame.ravel()
    count = len(first)
    hold = np.bincount(of_frame, weights=contexts.hold_s, minlength=count) / np.bincount(
        of_frame, minlength=count)
    return States(contexts.actuation[first], contexts.direction[first], hold, of_frame)


def trajectory_segments(states: States, recordings: np.ndarray) -> np.ndarray:
    """(t,) segment index of each frame: contiguous runs of frames, cut where the state or the
    recording changes, merged into at most MAX_SEGMENTS blocks of similar length."""
    of_frame = states.of_frame
    t = len(of_frame)
    cuts = np.flatnonzero((np.diff(of_frame) != 0) | (np.diff(recordings) != 0)) + 1
    starts = np.r_[0, cuts]
    count = min(MAX_SEGMENTS, len(starts))
    # pick `count` run starts nearest to evenly spaced frame positions
    targets = np.linspace(0, t, count, endpoint=False)
    chosen = np.unique(starts[np.abs(starts[:, None] - targets[None]).argmin(axis=0)])
    return np.searchsorted(chosen, np.arange(t), side="right") - 1
