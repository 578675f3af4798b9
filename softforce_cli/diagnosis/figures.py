"""Figures of a diagnosis: the residual map on the robot before and after, and the signature
plot (residual against actuation amplitude, loading direction, hold time and depth)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softforce_cli.diagnosis.pipeline import Diagnosis, node_systematic_mm
from softforce_cli.io.atomic import atomic_path
from softforce_cli.model.robot import Robot


def save_residual_map(robot: Robot, diagnosis: Diagnosis, path: Path, force: bool) -> None:
    """Mean residual per surface node (colour, mm) on the rest shape, nominal and final."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nodes = robot.mesh.nodes_mm[robot.mesh.surface_nodes]
    before = node_systematic_mm(diagnosis.nominal)
    after = node_systematic_mm(diagnosis.final)
    limit = max(float(np.abs(before).max()), 1e-3)
    figure = plt.figure(figsize=(10, 4.5))
    fitted = ", ".join(c.label for c in diagnosis.selected) or "no effect"
    for i, (values, title) in enumerate(((before, "nominal model"),
                                         (after, f"with {fitted}"))):
        axis = figure.add_subplot(1, 2, i + 1, projection="3d")
        art = axis.scatter(*nodes.T, c=values, cmap="coolwarm", vmin=-limit, vmax=limit, s=4)
        axis.set_title(f"{title}: RMS {np.sqrt(np.mean(values**2)):.2f} mm")
        axis.set_xlabel("x (mm)")
        axis.set_ylabel("y (mm)")
        axis.set_zlabel("z (mm)")
    figure.colorbar(art, ax=figure.axes, label="mean normal residual (mm), + outside model")
    with atomic_path(path, force) as temporary:
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)


def save_signature_plot(diagnosis: Diagnosis, path: Path, force: bool) -> None:
    """Per-frame RMS residual (nominal and final) against actuation amplitude, loading
    direction, hold time and mean depth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = diagnosis.observations.frames
    amplitude = np.array([np.abs(f.actuation).sum() for f in frames])
    states = diagnosis.states
    direction = states.direction[states.of_frame].sum(axis=1)
    hold = states.hold_s[states.of_frame]
    depth = np.array([f.depth_mm.mean() for f in frames])

    def per_frame(fields):
        return np.sqrt((fields.count * fields.mean_mm**2).sum(axis=1)
                       / np.maximum(fields.count.sum(axis=1), 1))

    before, after = per_frame(diagnosis.nominal), per_frame(diagnosis.final)
    figure, axes = plt.subplots(1, 4, figsize=(14, 3.5), sharey=True)
    for axis, x, label in zip(axes, (amplitude, direction, hold, depth),
                              ("actuation sum (mm)", "loading direction (sum of signs)",
                               "hold time (s)", "mean depth (mm)"), strict=True):
        axis.scatter(x, before, s=8, label="nominal")
        axis.scatter(x, after, s=8, label="fitted")
        axis.axhline(diagnosis.noise_floor_mm, color="grey", lw=0.8, ls="--")
        axis.set_xlabel(label)
    axes[0].set_ylabel("frame RMS residual (mm)")
    axes[0].legend()
    figure.suptitle(f"verdict: {diagnosis.verdict} (dashed: noise floor)")
    figure.tight_layout()
    with atomic_path(path, force) as temporary:
        figure.savefig(temporary, dpi=110, format="png")
    plt.close(figure)
