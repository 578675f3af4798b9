"""Least squares of one or two hypotheses' parameters on residual entries, and their held-out
error by leaving trajectory segments out.

A Candidate is a tuple of hypotheses fitted together (one effect, or two in forward
selection): its shift is the sum of theirs, its parameters theirs concatenated. The fit is
bounded nonlinear least squares (scipy's trust-region reflective) of the point-weighted
residual r - shift(p) over the entries of the training frames. Every evaluation is a few
vector operations on the first-order model (diagnosis.hypotheses): no FE solve.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.background import Table
from softforce_cli.diagnosis.hypotheses import Hypothesis, Inputs
from softforce_cli.diagnosis.residuals import Field

# Grid points of a one-parameter fit's start (over its screening range).
GRID_POINTS = 17


@dataclass(frozen=True)
class Candidate:
    """Hypotheses fitted together."""

    hypotheses: tuple[Hypothesis, ...]

    @property
    def label(self) -> str:
        return " + ".join(h.label for h in self.hypotheses)

    @property
    def sizes(self) -> list[int]:
        return [len(h.free) for h in self.hypotheses]

    @property
    def start(self) -> np.ndarray:
        return np.concatenate([h.start for h in self.hypotheses])

    @property
    def lower(self) -> np.ndarray:
        return np.concatenate([h.lower for h in self.hypotheses])

    @property
    def upper(self) -> np.ndarray:
        return np.concatenate([h.upper for h in self.hypotheses])

    def split(self, values: np.ndarray) -> list[np.ndarray]:
        return np.split(np.asarray(values, dtype=float), np.cumsum(self.sizes)[:-1])

    def effects(self, values: np.ndarray) -> tuple:
        return tuple(h.effect(v) for h, v in zip(self.hypotheses, self.split(values),
                                                 strict=True))

    def plate_height_mm(self, values: np.ndarray) -> float | None:
        """The height (mm) of the candidate's plate under the body at `values`
        (support_contact), None without one."""
        heights = [e["table_z_mm"] for e in self.effects(values) if e.name == "support_contact"]
        return heights[0] if heights else None

    def shift(self, values: np.ndarray, inputs: Inputs) -> np.ndarray:
        """(E,) the summed normal shift of every hypothesis at `values`."""
        parts = self.split(values)
        return sum(h.shift(v, inputs) for h, v in zip(self.hypotheses, parts, strict=True))

    @property
    def moves_camera(self) -> bool:
        """Whether a hypothesis is a sensor effect (the only kind that moves the table)."""
        return any(h.kind == "sensor" for h in self.hypotheses)

    def table_misfit_mm(self, values: np.ndarray, inputs: Inputs) -> float | None:
        """RMS (mm) of the observed table's height the candidate leaves unexplained (a
        physics effect explains none of it); None without a table."""
        if inputs.table is None:
            return None
        return inputs.table.misfit_mm(self.effects(values), inputs.robot_from_camera)

    def table_left_mm(self, values: np.ndarray, table: Table | None,
                      robot_from_camera: RigidTransform) -> np.ndarray | None:
        """(g,) mm: the observed table's height at its grid points less what the candidate's
        camera explains, the rows a camera effect's fit adds to the robot's; None for a
        candidate that moves no camera, or without a table."""
        if table is None or not self.moves_camera:
            return None
        return table.left_mm(self.effects(values), robot_from_camera)


@dataclass(frozen=True)
class TableRows:
    """The observed table as least-squares rows of a camera effect's fit at some values: its
    height left unexplained (g,) mm, d shift / d value (g, k), and each row's weight."""

    left_mm: np.ndarray
    jacobian: np.ndarray
    weight: float

    def cost(self) -> float:
        """Weighted sum of squares (mm^2 in the robot's point weights)."""
        return float(self.weight * self.left_mm @ self.left_mm)


def table_row_weight(candidate: Candidate, table: Table | None, robot_weight: float) -> float:
    """Each table grid point's least-squares weight in a camera effect's fit, given the
    robot entries' total point weight: the table counts as much as the robot, shared among
    its grid points; 0 for a candidate that moves no camera, or without a table."""
    if table is None or not candidate.moves_camera:
        return 0.0
    return robot_weight / len(table.observed_mm)


def table_rows(candidate: Candidate, table: Table | None, robot_from_camera: RigidTransform,
               values: np.ndarray, robot_weight: float) -> TableRows | None:
    """The table's rows of a camera effect's fit at `values` (the robot entries' total point
    weight `robot_weight`), their Jacobian by central differences (the camera's model is
    exact); None when the candidate moves no camera, or without a table."""
    left = candidate.table_left_mm(values, table, robot_from_camera)
    if left is None:
        return None
    # the left heights fall as the shift rises
    jacobian = -_central_differences(
        candidate, values, lambda v: candidate.table_left_mm(v, table, robot_from_camera))
    return TableRows(left, jacobian, table_row_weight(candidate, table, robot_weight))


def judged_residuals(entries: Field, left: np.ndarray, jacobian: np.ndarray, relative: bool
                     ) -> tuple[Field, np.ndarray]:
    """The residual left (E,) mm and Jacobian (E, k) a fit is judged on, at `entries`: less
    their static offsets per node (over all entries) when the fit is relative to them."""
    if relative:
        everything = np.ones(len(left), dtype=bool)
        left = left - node_offsets(left, entries, everything)
        jacobian = jacobian - node_offsets(jacobian, entries, everything)
    return Field(entries.frame, entries.node, left, entries.weight), jacobian


def node_offsets(values: np.ndarray, field: Field, mask: np.ndarray) -> np.ndarray:
    """Per entry, the point-weighted mean of `values` (E,) or (E, k) over the entries in
    `mask` at the same node (the static baseline of that node); NaN where the node has no
    entry in `mask`."""
    nodes = int(field.node.max()) + 1 if len(field.node) else 0
    w = np.where(mask, field.weight, 0.0)
    total = np.bincount(field.node, weights=w, minlength=nodes)
    flat = values.reshape(len(w), -1)
    sums = np.stack([np.bincount(field.node, weights=w * c, minlength=nodes) for c in flat.T],
                    axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / total[:, None]
    return means[field.node].reshape(values.shape)


def fit_values(candidate: Candidate, inputs: Inputs, field: Field, relative: bool,
               mask: np.ndarray | None = None, start: np.ndarray | None = None) -> np.ndarray:
    """(k,) parameters minimising sum w (r - shift(p) [- o])^2 over the entries of `field`
    in `mask` (default all), `field` having the entries of inputs.field. relative: with a
    free static offset o per node (the baseline the model's own discretisation leaves), so
    only what changes across frames counts. A camera effect is fitted to the observed table's
    height too (inputs.table, diagnosis.background; table_row_weight)."""
    mask = np.ones(len(field.mean_mm), dtype=bool) if mask is None else mask
    root = np.sqrt(field.weight[mask])
    lower, upper = candidate.lower, candidate.upper

    table_root = np.sqrt(table_row_weight(candidate, inputs.table, root @ root))

    def residual(values: np.ndarray) -> np.ndarray:
        left = field.mean_mm - candidate.shift(values, inputs)
        if relative:
            left = left - node_offsets(left, field, mask)
        on_table = candidate.table_left_mm(values, inputs.table, inputs.robot_from_camera)
        if on_table is None:
            return root * left[mask]
        return np.concatenate([root * left[mask], table_root * on_table])

    if start is not None:
        x0 = np.clip(start, lower, upper)
    elif len(lower) == 1:
        # one parameter: the best of a grid first (one-sided effects start on a bound and
        # may be non-smooth there: slack, play)
        grid = np.linspace(lower[0], upper[0], GRID_POINTS)
        costs = [float(np.sum(residual(np.array([v])) ** 2)) for v in grid]
        x0 = grid[[int(np.argmin(costs))]]
    else:
        # off the bounds, where a one-sided difference cannot leave them
        x0 = np.clip(candidate.start, lower + 0.01 * (upper - lower),
                     upper - 0.01 * (upper - lower))
    result = least_squares(residual, x0, bounds=(lower, upper), x_scale="jac",
                           diff_step=1e-4, max_nfev=60)
    return result.x


@dataclass(frozen=True)
class HeldOut:
    """Held-out residuals over every segment left out (mm, point-weighted RMS): before (the
    nominal model) and after (the candidate refitted without the segment), and per segment
    (K,) the mean squares before and after."""

    rms_before_mm: float
    rms_after_mm: float
    before_ms: np.ndarray
    after_ms: np.ndarray

    @property
    def gains(self) -> np.ndarray:
        """(K,) per segment: mean-square improvement (mm^2)."""
        return self.before_ms - self.after_ms

    def gain_z(self, baseline: HeldOut | None = None) -> float:
        """Mean segment gain (over `baseline`'s after, default the nominal model) divided by
        its standard error, the segments as independent samples."""
        gains = (self.before_ms if baseline is None else baseline.after_ms) - self.after_ms
        k = len(gains)
        spread = gains.std(ddof=1) / np.sqrt(k) if k > 1 else np.inf
        if spread > 0:
            return float(gains.mean() / spread)
        return 0.0 if gains.mean() == 0 else float(np.inf * np.sign(gains.mean()))


def held_out(candidate: Candidate, inputs: Inputs, field: Field, segments: np.ndarray,
             values: np.ndarray, relative: bool, jacobian: np.ndarray | None = None,
             nominal: Field | None = None) -> HeldOut:
    """Leave each segment (frames, never random ones) out, refit on the rest from `values`,
    and measure the segment; relative: the static offsets too are fitted on the rest only
    (entries of nodes the rest never saw are left out).

    field's entries are residuals at `values` when a jacobian (E, k) is given (the exact
    residuals of a refitted candidate: the refit is then its linearisation there), else the
    nominal residuals (the fold refits are full fits of the first-order model). `nominal`
    (default `field`) gives the before figures.
    """
    nominal = field if nominal is None else nominal
    entry_segment = segments[field.frame]
    nominal_segment = segments[nominal.frame]
    before, after, weights = [], [], []
    for k in np.unique(segments):
        out = entry_segment == k
        train = ~out
        if jacobian is None:
            folded = fit_values(candidate, inputs, field, relative, train, values)
            left = field.mean_mm - candidate.shift(folded, inputs)
        else:
            J = jacobian
            r = field.mean_mm
            if relative:
                J = J - node_offsets(J, field, train)
                r = r - node_offsets(r, field, train)
            usable = train & np.isfinite(r) & np.all(np.isfinite(J), axis=1)
            table = table_rows(candidate, inputs.table, inputs.robot_from_camera, values,
                               float(field.weight[usable].sum()))
            step = _linear_step(Field(field.frame, field.node, r, field.weight), J, usable,
                                table)
            step = np.clip(values + step, candidate.lower, candidate.upper) - values
            left = field.mean_mm - jacobian @ step
        after.append(_segment_ms(left, field, train, out, relative))
        was = nominal_segment == k
        before.append(_segment_ms(nominal.mean_mm, nominal, ~was, was, relative))
        weights.append(nominal.weight[was].sum())
    weights = np.array(weights)
    before, after = np.array(before), np.array(after)
    return HeldOut(float(np.sqrt(weights @ before / weights.sum())),
                   float(np.sqrt(weights @ after / weights.sum())), before, after)


def _segment_ms(left: np.ndarray, field: Field, train: np.ndarray, out: np.ndarray,
                relative: bool) -> float:
    """Mean square (mm^2) over the `out` entries of residuals `left` (E,), less the static
    offsets fitted on `train` when relative."""
    if relative:
        left = left - node_offsets(left, field, train)
    keep = out & np.isfinite(left)
    w = field.weight[keep]
    return float(np.sum(w * left[keep] ** 2) / max(w.sum(), 1e-12))


def _linear_step(field: Field, jacobian: np.ndarray, mask: np.ndarray,
                 table: TableRows | None = None) -> np.ndarray:
    """(k,) argmin sum w (r - J d)^2 over the entries in mask (and the table's rows), the
    shortest such step where the entries do not determine it: a fold that leaves out the
    only segment whose inputs the candidate moves (a north cable 4 mm slack, pulled past
    its slack in one segment alone) has J = 0 there and steps nowhere."""
    w = field.weight[mask]
    J = jacobian[mask]
    normal = (J * w[:, None]).T @ J
    right = (J * w[:, None]).T @ field.mean_mm[mask]
    if table is not None:
        normal = normal + table.weight * table.jacobian.T @ table.jacobian
        right = right + table.weight * table.jacobian.T @ table.left_mm
    normal += 1e-12 * np.trace(normal) * np.eye(len(normal))
    return np.linalg.lstsq(normal, right, rcond=None)[0]


def shift_jacobian(candidate: Candidate, inputs: Inputs, values: np.ndarray) -> np.ndarray:
    """(E, k) d shift / d parameter at `values` (central differences of the first-order model,
    scaled to each parameter's screening range)."""
    return _central_differences(candidate, values, lambda v: candidate.shift(v, inputs))


def _central_differences(candidate: Candidate, values: np.ndarray,
                         function: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """(m, k) d function / d parameter at `values` (function: (k,) -> (m,)), each step
    1e-4 of the parameter's screening range, within its bounds."""
    span = candidate.upper - candidate.lower
    columns = []
    for j in range(len(values)):
        step = 1e-4 * span[j]
        up, down = values.copy(), values.copy()
        up[j] = min(values[j] + step, candidate.upper[j])
        down[j] = max(values[j] - step, candidate.lower[j])
        columns.append((function(up) - function(down)) / (up[j] - down[j]))
    return np.stack(columns, axis=1)
