"""The report's figures as PNG files (matplotlib): charts and the robot's projections."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

from softforce_cli.io.atomic import atomic_path
from softforce_cli.report.charts import Chart
from softforce_cli.report.scene import ContactScene

# (horizontal axis, vertical axis, name) of the three projections, robot frame
PROJECTIONS = ((0, 1, "top (x-y)"), (0, 2, "front (x-z)"), (1, 2, "side (y-z)"))
AXIS_NAMES = "xyz"


def save_chart_png(chart: Chart, path: Path, force: bool = False) -> None:
    figure, axes = plt.subplots(figsize=(8, 4.5), dpi=100)
    bottom: np.ndarray | None = None
    categorical = any(t.kind == "bar" and t.x.dtype.kind in "US" for t in chart.traces)
    width = 0.8 / max(1, sum(t.kind == "bar" for t in chart.traces))
    for index, trace in enumerate(chart.traces):
        if trace.kind == "bar":
            x = np.arange(len(trace.x)) if categorical else trace.x
            if chart.stacked:
                base = np.zeros(len(trace.y)) if bottom is None else bottom
                axes.bar(x, trace.y, bottom=base, label=trace.name)
                bottom = base + np.nan_to_num(trace.y)
            else:
                axes.bar(x + (index - 0.5 * (len(chart.traces) - 1)) * width, trace.y, width,
                         label=trace.name)
            if categorical:
                axes.set_xticks(x, trace.x, rotation=20)
        elif trace.kind == "markers":
            axes.plot(trace.x, trace.y, "o", ms=5, label=trace.name)
        else:
            axes.plot(trace.x, trace.y, "-o", ms=3, label=trace.name)
    if chart.reference is not None:
        value, label = chart.reference
        axes.axhline(value, color="black", ls="--", lw=1, label=label)
    if chart.diagonal:
        values = np.concatenate([np.r_[t.x, t.y] for t in chart.traces] or [np.zeros(1)])
        span = [0.0, float(np.nanmax(values, initial=0.0)) * 1.05 or 1.0]
        axes.plot(span, span, color="grey", ls=":", label="estimated = true")
    axes.set(title=chart.title, xlabel=chart.x_label, ylabel=chart.y_label)
    axes.grid(alpha=0.3)
    if chart.traces:
        axes.legend(fontsize=8)
    _save(figure, path, force)


def save_projections_png(scene: ContactScene, path: Path, force: bool = False) -> None:
    """Three orthographic projections of the robot's surface with the contacts and their
    force arrows (drawn ending at the contact, pushing)."""
    figure, panels = plt.subplots(1, 3, figsize=(15, 5.2), dpi=100)
    triangles = scene.shape.surface_mm
    scale = scene.arrow_mm_per_n
    for axes, (h, v, name) in zip(panels, PROJECTIONS, strict=True):
        axes.add_collection(PolyCollection(triangles[:, :, [h, v]], facecolors="#9db7e0",
                                           edgecolors="#6f8fc0", linewidths=0.2, alpha=0.35))
        if len(scene.nodes):
            nodes = scene.shape.positions_mm[scene.nodes]
            axes.scatter(nodes[:, h], nodes[:, v], s=12, c="crimson", label="located nodes")
        if len(scene.points_mm):
            tails = scene.points_mm - scale * scene.forces_n
            axes.quiver(tails[:, h], tails[:, v], scale * scene.forces_n[:, h],
                        scale * scene.forces_n[:, v], angles="xy", scale_units="xy", scale=1,
                        color="black", width=0.004)
            dots = axes.scatter(scene.points_mm[:, h], scene.points_mm[:, v], s=25,
                                c=scene.magnitudes_n, cmap="viridis", zorder=3,
                                label="contacts")
            figure.colorbar(dots, ax=axes, label="force (N)", shrink=0.8)
        axes.autoscale_view()
        axes.set_aspect("equal")
        axes.set(title=name, xlabel=f"{AXIS_NAMES[h]} (mm)", ylabel=f"{AXIS_NAMES[v]} (mm)")
    figure.suptitle(scene.title)
    _save(figure, path, force)


def _save(figure: plt.Figure, path: Path, force: bool) -> None:
    figure.tight_layout()
    with atomic_path(Path(path), force=force) as tmp:
        figure.savefig(tmp, format="png")
    plt.close(figure)
