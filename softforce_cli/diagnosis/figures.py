"""Figures of a diagnosis: the residual map on the robot before and after, and the signature
plot (residual against actuation amplitude, loading direction, hold time and depth)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softforce_cli.diagnosis.fitting import node_offsets
from softforce_cli.diagnosis.pipeline import Diagnosis
from softforce_cli.diagnosis.residuals import Field, node_systematic_mm
from softforce_cli.io.atomic import atomic_path
from softforce_cli.model.effects import frame_contexts


def _node_values(field: Field, node_count: int, relative: bool) -> tuple[np.ndarray,
                                                                        np.ndarray]:
    """(n,) per mesh node: the RMS over frames of the residual less its static baseline
    (relative), or the mean residual (absolute); and (n,) the points behind it."""
    if not relative:
        return node_systematic_mm(field, node_count)
    varying = field.mean_mm - node_offsets(field.mean_mm, field,
                                           np.ones(len(field.mean_mm), dtype=bool))
    squared = Field(field.frame, field.node, varying**2, field.weight)
    mean_square, weight = node_systematic_mm(squared, node_count)
    return np.sqrt(mean_square), weight


def save_residual_map(diagnosis: Diagnosis, path: Path, force: bool) -> None:
    """The residual per surface node (colour, mm) on the rest shape, nominal and with the
    selected effects: what changes across frames (the RMS less the static baseline per
    node), or the mean residual when the selected effect was accepted on absolute ones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mesh = diagnosis.robot.mesh
    nodes = mesh.nodes_mm
    relative = diagnosis.fitted is None or diagnosis.fitted.screened.relative
    before, seen = _node_values(diagnosis.nominal, mesh.node_count, relative)
    after, seen_after = _node_values(diagnosis.final_field, mesh.node_count, relative)
    limit = max(float(np.abs(before[seen > 0]).max(initial=0.0)), 1e-3)
    colours = dict(cmap="viridis", vmin=0.0, vmax=limit) if relative else dict(
        cmap="coolwarm", vmin=-limit, vmax=limit)
    figure = plt.figure(figsize=(10, 4.5))
    fitted = "no effect" if diagnosis.fitted is None else diagnosis.fitted.candidate.label
    for i, (values, weight, title) in enumerate(((before, seen, "nominal model"),
                                                 (after, seen_after, f"with {fitted}"))):
        axis = figure.add_subplot(1, 2, i + 1, projection="3d")
        shown = weight > 0
        art = axis.scatter(*nodes[shown].T, c=values[shown], s=4, **colours)
        rms = np.sqrt(np.average(values[shown] ** 2, weights=weight[shown])) if shown.any() \
            else 0.0
        axis.set_title(f"{title}: RMS {rms:.2f} mm", fontsize=9)
        axis.set_xlabel("x (mm)")
        axis.set_ylabel("y (mm)")
        axis.set_zlabel("z (mm)")
    label = ("residual across frames, static baseline removed (RMS, mm)" if relative
             else "mean signed distance (mm), + outside model")
    figure.colorbar(art, ax=figure.axes, label=label)
    with atomic_path(path, force) as temporary:
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)


def _per_frame_rms(field: Field, frames: int, relative: bool) -> np.ndarray:
    """(t,) RMS residual of each frame (less the static baseline per node: relative)."""
    values = field.mean_mm
    if relative:
        values = values - node_offsets(values, field, np.ones(len(values), dtype=bool))
    weight = np.bincount(field.frame, weights=field.weight, minlength=frames)
    squares = np.bincount(field.frame, weights=field.weight * values**2, minlength=frames)
    return np.sqrt(np.divide(squares, weight, out=np.zeros(frames), where=weight > 0))


def save_signature_plot(diagnosis: Diagnosis, path: Path, force: bool) -> None:
    """Per-frame RMS residual (nominal and fitted) against actuation amplitude, loading
    direction, hold time and mean depth, with the noise floor; relative to the static
    baseline per node unless the selected effect was accepted on absolute residuals. A
    camera effect judged on the markers gets their signature instead (_marker_signature)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = (_marker_signature(diagnosis, plt)
              if diagnosis.selected and diagnosis.selected[0].screened.channel == "markers"
              else _cloud_signature(diagnosis, plt))
    with atomic_path(path, force) as temporary:
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)


def _cloud_signature(diagnosis: Diagnosis, plt):
    """The clouds' per-frame RMS against actuation, loading, hold time and depth."""
    frames = diagnosis.observations.frames
    amplitude = np.array([np.abs(f.actuation).sum() for f in frames])
    contexts = frame_contexts(diagnosis.observations.times_s, diagnosis.observations.actuations)
    loading = np.array([c.loading.sum() for c in contexts])
    hold = np.array([c.hold_s for c in contexts])
    depth = np.array([f.depth_mm.mean() for f in frames])
    relative = diagnosis.fitted is None or diagnosis.fitted.screened.relative
    before = _per_frame_rms(diagnosis.nominal, len(frames), relative)
    after = _per_frame_rms(diagnosis.final_field, len(frames), relative)
    figure, axes = plt.subplots(1, 4, figsize=(14, 3.5), sharey=True)
    for axis, x, label in zip(axes, (amplitude, loading, hold, depth),
                              ("actuation sum (mm)", "loading direction (sum of signs)",
                               "hold time (s)", "mean depth (mm)"), strict=True):
        axis.scatter(x, before, s=10, label="nominal")
        axis.scatter(x, after, s=10, label="fitted")
        axis.axhline(diagnosis.noise_floor_mm, color="grey", lw=0.8, ls="--")
        axis.set_xlabel(label)
    axes[0].set_ylabel("frame RMS residual (mm)" + (", static baseline removed" if relative
                                                     else ""))
    axes[0].legend()
    figure.suptitle(f"verdict: {diagnosis.verdict} (dashed: noise floor)")
    figure.tight_layout()
    return figure


def _marker_signature(diagnosis: Diagnosis, plt):
    """The markers' evidence for a camera effect: each marker's mean residual seen from
    above (arrows, magnified), nominal and with the effect, and each frame's marker RMS
    against the markers' noise floor."""
    field, inputs = diagnosis.markers, diagnosis.marker_inputs
    chosen = diagnosis.selected[0]
    after = field.mean_mm - chosen.candidate.shift(chosen.values, inputs)
    marker = field.node // 3
    count = int(marker.max()) + 1
    entries = np.bincount(marker, minlength=count) / 3

    def per_marker(values: np.ndarray) -> np.ndarray:  # (k, 3) mean over frames
        sums = np.zeros((count, 3))
        np.add.at(sums, (marker, field.node % 3), values)
        return sums / np.maximum(entries, 1)[:, None]

    where = per_marker(inputs.positions[np.arange(len(marker)), field.node % 3])
    before_mean, after_mean = per_marker(field.mean_mm), per_marker(after)
    seen = entries > 0
    span = float(np.ptp(where[seen, :2], axis=0).max(initial=1.0))
    scale = 0.15 * span / max(float(np.abs(before_mean[seen, :2]).max(initial=0.0)), 1e-6)
    figure, (top, rms) = plt.subplots(1, 2, figsize=(11, 4.5))
    for mean, colour, label in ((before_mean, "C0", "nominal"),
                                (after_mean, "C1", f"with {chosen.candidate.label}")):
        top.quiver(where[seen, 0], where[seen, 1], mean[seen, 0], mean[seen, 1],
                   color=colour, angles="xy", scale_units="xy", scale=1.0 / scale,
                   label=label)
    top.scatter(where[seen, 0], where[seen, 1], s=8, color="k")
    top.set_aspect("equal")
    top.set_xlabel("x (mm)")
    top.set_ylabel("y (mm)")
    top.set_title(f"markers' mean residual from above, x {scale:.0f}", fontsize=9)
    top.legend(fontsize=8)
    frames = len(diagnosis.observations.frames)
    for values, label in ((field.mean_mm, "nominal"), (after, "fitted")):
        per_frame = _per_frame_rms(Field(field.frame, field.node, values, field.weight),
                                   frames, relative=False)
        rms.scatter(np.arange(frames), per_frame, s=10, label=label)
    rms.axhline(diagnosis.marker_floor_mm, color="grey", lw=0.8, ls="--")
    rms.set_xlabel("frame")
    rms.set_ylabel("markers' RMS residual per coordinate (mm)")
    rms.legend()
    figure.suptitle(f"verdict: {diagnosis.verdict}, seen by the markers (dashed: their "
                    "noise floor)")
    figure.tight_layout()
    return figure
