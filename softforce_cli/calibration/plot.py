"""The residual per iteration of a calibration (the paper's Fig. 6), as a PNG."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from softforce_cli.io.atomic import atomic_path


def save_residual_plot(histories: Mapping[str, Sequence[float]], path: Path,
                       force: bool = False, title: str = "Calibration residual") -> None:
    """One line per labelled residual history (mm per outer iteration), log scale, to `path`.

    Written atomically; an existing file only with `force`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    for label, history in histories.items():
        values = [max(float(v), 1e-12) for v in history]
        axes.semilogy(range(1, len(values) + 1), values, marker="o", markersize=3, label=label)
    axes.set_xlabel("iteration (outer, I1)")
    axes.set_ylabel("residual RMS (mm)")
    axes.set_title(title)
    axes.grid(True, which="both", alpha=0.3)
    if len(histories) > 1 or any(histories):
        axes.legend()
    figure.tight_layout()
    path = Path(path)
    with atomic_path(path, force=force) as tmp:
        figure.savefig(tmp, format=path.suffix.lstrip(".") or "png")
    plt.close(figure)
