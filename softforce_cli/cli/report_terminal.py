"""The report's terminal summary as rich renderables (the command prints them)."""

from __future__ import annotations

from rich.console import Group, RenderableType
from rich.table import Table as RichTable
from rich.text import Text

from softforce_cli.estimation.summary import poor_fit_text
from softforce_cli.report.diagnosis_file import Diagnosis
from softforce_cli.report.overview import STATUS_MEANINGS, Overview
from softforce_cli.report.truth import TruthReport


def sense_summary(overview: Overview, truth: TruthReport | None) -> RenderableType:
    parts: list[RenderableType] = []
    rate = f"{overview.frames_per_s:.1f} frames/s" + (
        "" if overview.rate_measured else " (from the frames' times)")
    parts.append(Text(f"{overview.frames} frames over {overview.duration_s:.2f} s, "
                      f"{overview.ok} ok, {len(overview.contacts)} contacts; {rate}"))
    if overview.camera is not None:
        parts.append(Text(f"camera {overview.camera}"))
    if overview.poor_fit_frames:
        parts.append(Text(poor_fit_text(overview.poor_fit_frames), style="yellow"))
    if overview.skipped:
        skipped = RichTable(title="frames skipped", title_justify="left")
        for name in ("status", "frames", "why"):
            skipped.add_column(name)
        for status, count in overview.skipped.items():
            skipped.add_row(status, str(count), STATUS_MEANINGS.get(status, ""))
        parts.append(skipped)
    if overview.contacts:
        contacts = RichTable(title="force per contact (N)", title_justify="left")
        for name in ("contact", "frames", "min", "median", "max", "from (s)", "to (s)"):
            contacts.add_column(name, justify="right")
        for c in overview.contacts:
            contacts.add_row(str(c.contact), str(c.frames), f"{c.force_min_n:.4f}",
                             f"{c.force_median_n:.4f}", f"{c.force_max_n:.4f}",
                             f"{c.first_s:.2f}", f"{c.last_s:.2f}")
        parts.append(contacts)
    if overview.stage_median_ms:
        stages = RichTable(title="median time per frame (ms)", title_justify="left")
        for name in overview.stage_median_ms:
            stages.add_column(name, justify="right")
        stages.add_row(*(f"{v:.1f}" for v in overview.stage_median_ms.values()))
        parts.append(stages)
    if truth is not None:
        parts.append(truth_summary(truth))
    return Group(*parts)


def truth_summary(truth: TruthReport) -> RenderableType:
    s = truth.statistics

    def number(key: str, unit: str = "", scale: float = 1.0) -> str:
        value = s[key]
        return "n/a" if value is None else f"{scale * value:.3g}{unit}"

    table = RichTable(title=f"against the ground truth ({truth.path.name})",
                      title_justify="left")
    for name in ("located", "location error median / max (mm)",
                 "intensity error median / p90", "phantoms (max N)"):
        table.add_column(name, justify="right")
    table.add_row(f"{s['located']}/{s['true_contacts']}",
                  f"{number('location_error_median_mm')} / {number('location_error_max_mm')}",
                  f"{number('intensity_error_median', ' %', 100)} / "
                  f"{number('intensity_error_p90', ' %', 100)}",
                  f"{s['phantoms']} ({s['max_phantom_n']:.3g})")
    return table


def diagnosis_summary(diagnosis: Diagnosis) -> RenderableType:
    location = diagnosis.location
    where = "; ".join(f"{kind} {', '.join(map(str, names))}" for kind, names in
                      (("regions", location.regions), ("cables", location.cables)) if names)
    head = Text(f"verdict: {diagnosis.verdict}" + (f" (at {where})" if where else "")
                + f"; noise floor {diagnosis.noise_floor_mm:.3f} mm", style="bold")
    table = RichTable(title="effects, ranked (held-out residual RMS, mm)", title_justify="left")
    for name in ("effect", "before", "after", "removed", "parameters (95 % CI)"):
        table.add_column(name, justify="left" if name in ("effect", "parameters (95 % CI)")
                         else "right", overflow="fold")
    for e in diagnosis.effects:
        # plain Text: a pair's parameters name their targets in brackets, not rich markup
        table.add_row(Text(e.label), f"{e.heldout_rms_before_mm:.3f}",
                      f"{e.heldout_rms_after_mm:.3f}", f"{100 * e.improvement:.0f} %",
                      Text("; ".join(f"{p.name} {p.value:.4g} {p.unit} [{p.ci95[0]:.4g}, "
                                     f"{p.ci95[1]:.4g}]" for p in e.parameters)))
    return Group(head, table) if diagnosis.effects else head
