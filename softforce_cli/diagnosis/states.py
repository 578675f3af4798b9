"""Frames -> distinct actuation states, and contiguous trajectory segments for validation.

A state is what the FE model needs to predict a frame: the cable inputs, the direction each
cable last moved (loading or unloading, for friction) and how long the inputs have been held
(for creep), binned. Frames of one state share one FE solve; a 200-frame recording with holds
has a few dozen states.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softforce_cli.model.effects import FrameContext

# Inputs closer than this (mm or N) are one state: well below what a camera resolves (a
# 0.05 mm cable change moves the Diamond's surface by about 0.1 mm).
ACTUATION_TOLERANCE = 0.05
# Hold-time bin edges (s): creep follows the hold's exponential, resolved on a log scale.
HOLD_BINS_S = (1.0, 3.0, 9.0, 27.0)
# Trajectory segments for leave-one-segment-out validation: at most this many.
MAX_SEGMENTS = 8


@dataclass(frozen=True)
class States:
    """Distinct states and which frames they serve.

    actuation : (S, a) inputs of each state.
    loading   : (S, a) loading direction of each state (+1, -1, 0).
    hold_s    : (S,) mean hold time of its frames.
    of_frame  : (t,) state index of each frame.
    """

    actuation: np.ndarray
    loading: np.ndarray
    hold_s: np.ndarray
    of_frame: np.ndarray

    @property
    def count(self) -> int:
        return len(self.actuation)


def group_states(contexts: Sequence[FrameContext]) -> States:
    """One state per distinct (rounded inputs, loading direction, hold bin) of the frames."""
    actuation = np.array([c.actuation for c in contexts], dtype=float)
    loading = np.array([c.loading for c in contexts], dtype=np.int64)
    hold = np.array([c.hold_s for c in contexts], dtype=float)
    keys = np.hstack([np.round(actuation / ACTUATION_TOLERANCE).astype(np.int64), loading,
                      np.digitize(hold, HOLD_BINS_S)[:, None]])
    _, first, of_frame = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    of_frame = of_frame.ravel()
    count = len(first)
    mean_hold = np.bincount(of_frame, weights=hold, minlength=count) / np.bincount(
        of_frame, minlength=count)
    return States(actuation[first], loading[first], mean_hold, of_frame)


def trajectory_segments(states: States, recordings: np.ndarray) -> np.ndarray:
    """(t,) segment index of each frame: contiguous runs of frames, cut where the state or the
    recording changes, merged into at most MAX_SEGMENTS blocks of similar length."""
    of_frame = states.of_frame
    t = len(of_frame)
    cuts = np.flatnonzero((np.diff(of_frame) != 0) | (np.diff(recordings) != 0)) + 1
    starts = np.r_[0, cuts]
    count = min(MAX_SEGMENTS, len(starts))
    # the run starts nearest to evenly spaced frame positions
    targets = np.linspace(0, t, count, endpoint=False)
    chosen = np.unique(starts[np.abs(starts[:, None] - targets[None]).argmin(axis=0)])
    return np.searchsorted(chosen, np.arange(t), side="right") - 1
