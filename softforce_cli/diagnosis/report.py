"""diagnosis.json (docs/diagnosis.md) and robot.fitted.toml (the robot file plus the fitted
`[[effect]]` tables, loadable by every command)."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from softforce_cli import __version__
from softforce_cli.diagnosis.fitting import Candidate
from softforce_cli.diagnosis.pipeline import Diagnosis, Final, Screened
from softforce_cli.diagnosis.refit import NoEquilibriumError
from softforce_cli.diagnosis.selection import excess_share, explained_mm, systematic_mm
from softforce_cli.diagnosis.support import rim_heights_mm
from softforce_cli.model.effects import EFFECTS, Effect, effect_toml
from softforce_cli.model.robot import Robot

FORMAT = "softforce.diagnosis"
# JSON has no infinity: an interval bound at infinity (a base stiffness whose compliance
# interval reaches 0, i.e. a rigid clamp) is written as this many units.
INFINITE = 1e12
MODES = {True: "relative to a static baseline per node", False: "absolute"}

# Why two effects of a group leave one signature, for the pairs known to (docs/diagnosis.md);
# keyed by effect names without targets.
GROUP_REASONS: dict[frozenset[str], str] = {
    frozenset({"gravity", "stiffness_scale"}): "with displacement-controlled cables a "
    "heavier body and a softer one sag alike: the shape depends on g / E (a stiffness "
    "scale s is a gravity scale 1 / s)",
    frozenset({"compliant_base", "stiffness_scale"}): "a body that gives at its clamp and a "
    "softer body both sink further under their weight, by shapes this recording does not "
    "tell apart",
    frozenset({"depth_bias", "extrinsic_offset"}): "a depth scale and a camera moved along "
    "its axis shift the robot alike at its depth",
}


def _finite(value: float) -> float | None:
    return round(float(value), 6) if math.isfinite(value) else None


def _bounded(value: float) -> float:
    return round(float(np.clip(value, -INFINITE, INFINITE)), 6)


def _parameters(effect: Effect, free: tuple[str, ...], values: np.ndarray,
                ci95: np.ndarray) -> dict[str, dict[str, Any]]:
    """{name: {value, ci95, unit}} in the effect's own parameters (compliance -> stiffness)."""
    out = {}
    for name, value, interval in zip(free, values, ci95, strict=True):
        if name == "compliance_mm_per_n":  # reported as the spec's stiffness = 1 / compliance
            name = "stiffness_n_per_mm"
            value = effect[name]
            interval = [1.0 / interval[1] if interval[1] > 0 else math.inf,
                        1.0 / interval[0] if interval[0] > 0 else math.inf]
        spec = EFFECTS[effect.name].parameter(name)
        # an interval wider than the physical range (a pair the data cannot separate) is
        # reported as that range
        interval = np.clip(interval, spec.lower, spec.upper)
        out[name] = {"value": _bounded(value), "ci95": [_bounded(v) for v in interval],
                     "unit": spec.unit}
    return out


def _candidate_parameters(candidate: Candidate, values: np.ndarray, ci95: np.ndarray
                          ) -> dict[str, dict[str, Any]]:
    """{name: {value, ci95, unit}} of every hypothesis of a candidate (prefixed by its label
    when there are several)."""
    effects = candidate.effects(values)
    parameters: dict[str, Any] = {}
    for hypothesis, effect, part, part_ci in zip(
            candidate.hypotheses, effects, candidate.split(values),
            np.split(ci95, np.cumsum(candidate.sizes)[:-1]), strict=True):
        prefix = "" if len(effects) == 1 else f"{hypothesis.label}."
        parameters.update({prefix + k: v for k, v in _parameters(
            effect, hypothesis.free, part, part_ci).items()})
    return parameters


def effect_entry(item: Final | Screened, floor_mm: float, selected: bool,
                 with_mesh: Final | None = None) -> dict[str, Any]:
    """One ranked effect: the last of its hypotheses, the one it adds to the effects before
    it (a second effect is refitted with the first: its entry holds both's parameters).
    With `with_mesh` (pipeline._with_the_mesh), the values, intervals and held-out error are
    that fit's, and its allowance and the fit alone are in evidence.mesh_allowance."""
    screened = item.screened if isinstance(item, Final) else item
    candidate = screened.candidate
    reported = item if with_mesh is None else with_mesh
    own = sum(candidate.sizes)
    parameters = _candidate_parameters(candidate, reported.values[:own], reported.ci95[:own])
    held = reported.heldout
    added = candidate.hypotheses[-1]
    entry = {
        "name": added.name,
        "target": added.target,
        "label": candidate.label,
        "parameters": parameters,
        "heldout_rms_before_mm": _finite(held.rms_before_mm),
        "heldout_rms_after_mm": _finite(held.rms_after_mm),
        "evidence": {
            "selected": selected,
            "accepted": item.accepted if isinstance(item, Final) else None,
            "refitted": isinstance(item, Final),
            "mode": MODES[screened.relative],
            # the residuals it was judged on: the point clouds', or the markers' (a camera
            # effect the clouds cannot see, diagnosis.markers)
            "channel": screened.channel,
            "segment_gain_z": _finite(held.gain_z()),
            "excess_share": _finite(excess_share(held, floor_mm)),
            "explained_mm": _finite(explained_mm(held)),
            # with the mesh's allowance, the solves of both fits
            "fe_solves": (item.refit.solves + (0 if with_mesh is None else
                                                with_mesh.refit.solves)
                          if isinstance(item, Final) else 0),
            # values the exact model could not follow, after which the refit pulled back
            "no_equilibrium": ([str(e) for e in item.refit.unreached]
                               if isinstance(item, Final) else []),
            # its fit solved the frames in turn, each from the one before, as the body moves
            # (a creeping body that tips over: refit.ExactModel.followed)
            "followed_frames": isinstance(item, Final) and item.refit.prediction.followed,
            "table_misfit_mm": (None if item.table_misfit_mm is None
                                else round(item.table_misfit_mm, 3)),
            # what it leaves of the residual that changes across frames (a refitted
            # absolute effect must explain that too to be named)
            "heldout_relative_after_mm": (
                _finite(item.relative_heldout.rms_after_mm)
                if isinstance(item, Final) and item.relative_heldout is not None else None),
        },
    }
    if with_mesh is not None:
        (allowance,) = _parameters(with_mesh.candidate.effects(with_mesh.values)[-1],
                                   with_mesh.candidate.hypotheses[-1].free,
                                   with_mesh.values[own:], with_mesh.ci95[own:]).values()
        entry["evidence"]["mesh_allowance"] = {
            "stiffness_scale": allowance,
            "alone": {"parameters": _candidate_parameters(candidate, item.values, item.ci95),
                      "heldout_rms_after_mm": _finite(item.heldout.rms_after_mm)}}
    return entry


def diagnosis_document(diagnosis: Diagnosis, inputs: dict[str, Any]) -> dict[str, Any]:
    """The diagnosis.json document (also of an interrupted run: `interrupted`, `stage`)."""
    floor = diagnosis.floor_for
    chosen = {id(f) for f in diagnosis.selected}
    refitted = {(f.screened.key) for f in diagnosis.finals}
    ranked: list[dict[str, Any]] = [effect_entry(f, floor(f), True, diagnosis.with_mesh.get(f))
                                    for f in diagnosis.selected]
    ranked += [effect_entry(f, floor(f), False) for f in diagnosis.finals
               if id(f) not in chosen]
    seen = set(refitted)
    for s in diagnosis.screened:  # the best target of every other effect and mode
        if s.key not in seen:
            seen.add(s.key)
            ranked.append(effect_entry(s, floor(s), False))
    selected = {id(f.screened) for f in diagnosis.selected}
    ranked += [effect_entry(s, floor(s), False) for s in diagnosis.marker_screened
               if id(s) not in selected]
    return {
        "format": FORMAT,
        "version": 1,
        "softforce_version": __version__,
        "inputs": inputs,
        "interrupted": diagnosis.interrupted,
        "stage": diagnosis.stage,
        "verdict": diagnosis.verdict,
        "noise_floor_mm": _finite(diagnosis.noise_floor_mm),
        "effects": ranked,
        "indistinguishable_groups": diagnosis.groups,
        "location": diagnosis.location,
        "evidence": diagnosis.evidence,
        "summary": summary_lines(diagnosis),
    }


def summary_lines(diagnosis: Diagnosis) -> list[str]:
    """The human-readable summary: what was found, where, how much better, the mesh."""
    if diagnosis.verdict is None:
        return [f"interrupted during {diagnosis.stage}: no verdict"]
    evidence = diagnosis.evidence
    lines = []
    if diagnosis.selected:
        for final in diagnosis.selected:
            floor = diagnosis.floor_for(final)
            with_mesh = diagnosis.with_mesh.get(final)
            entry = effect_entry(final, floor, True, with_mesh)
            markers = final.screened.channel == "markers"
            lines.append(f"{final.candidate.label}: {_values_text(entry['parameters'])}; "
                         f"held-out residual {'of the markers ' if markers else ''}"
                         f"{entry['heldout_rms_before_mm']:.2f} -> "
                         f"{entry['heldout_rms_after_mm']:.2f} mm "
                         f"({MODES[final.screened.relative]}), noise floor {floor:.2f} mm")
            if with_mesh is not None:
                allowance = entry["evidence"]["mesh_allowance"]
                alone = allowance["alone"]
                lines.append(
                    f"{final.candidate.label}: fitted with this mesh's own stiffness error "
                    f"alongside, which it takes up when fitted alone (a body "
                    f"{allowance['stiffness_scale']['value']:.3g} as stiff, between 1 and the "
                    f"{1 / diagnosis.mesh_bracket.load_scale:.3g} of the other quadratic "
                    f"element on the mesh); alone: {_values_text(alone['parameters'])}, "
                    f"held-out {alone['heldout_rms_after_mm']:.2f} mm")
            if diagnosis.mesh_rest and final is diagnosis.fitted:
                lines.append(static_beyond_line(diagnosis) if diagnosis.mesh_rest_static
                             else mesh_rest_line(diagnosis))
            if markers:
                lines.append("seen by the markers only: the point clouds show no structured "
                             "mismatch (a camera turned about its axis or moved sideways "
                             "slides the surfaces along themselves)")
    elif diagnosis.mismatch_within_mesh:
        lines.append(mismatch_within_mesh_line(diagnosis))
    elif diagnosis.verdict == "none":
        beyond = "beyond the mesh's own error" if diagnosis.within_mesh else "clearly"
        lines.append(f"no effect of the library improves the held-out fit {beyond}: the model "
                     f"explains the recording to {evidence['rms_nominal_mm']:.2f} mm RMS "
                     f"(noise floor {diagnosis.noise_floor_mm:.2f} mm)")
    else:
        where = ", ".join(diagnosis.location.get("regions", [])) or "the whole body"
        lines.append(f"a structured mismatch ({evidence['systematic_final_mm']:.2f} mm above "
                     f"the noise floor) that no effect of the library explains, in {where}")
        if diagnosis.partial:
            # the figures that decide a name: what changes across frames (selection), and
            # what stays the same in every frame (pipeline._static_limit)
            lines.append(f"{', '.join(diagnosis.partial)} fits part of it, too little to name "
                         "(what changes across frames, held-out relative to a static "
                         f"baseline: {evidence['heldout_relative_nominal_mm']:.2f} -> "
                         f"{evidence['heldout_relative_final_mm']:.2f} mm, noise floor "
                         f"{diagnosis.noise_floor_mm:.2f} mm"
                         + (f"; what stays the same in every frame: "
                            f"{_static_left(evidence)} left, more than the "
                            f"{evidence['static_limit_mm']:.2f} mm this mesh's own error "
                            "explains" if evidence["static_beyond_limit"] else "")
                         + "): physics outside the library?"
                         + (f" (it leaves more than half of what this mesh's two quadratic "
                            f"elements disagree by with its values: {bracket.relative_mm:.2f} mm "
                            f"across frames, {bracket.static_mm:.2f} mm static)"
                            if (bracket := diagnosis.fit_bracket) is not None else ""))
    if diagnosis.within_mesh:
        bracket = diagnosis.mesh_bracket
        lines.append(f"{', '.join(diagnosis.within_mesh)} fits it, but not beyond this mesh's "
                     f"own error: the other quadratic element on the same mesh deforms "
                     f"{bracket.load_scale:.3g} times as much, {bracket.surface_rms_mm:.2f} mm "
                     "RMS away, and the two bracket the converged body (docs/locking.md); the "
                     "mesh is the likely cause, not named (a finer mesh would tell)")
    if len(diagnosis.camera_with_mesh_mm) > 1:
        compared = ", ".join(f"{label} {mm:.2f}" for label, mm in
                             sorted(diagnosis.camera_with_mesh_mm.items(), key=lambda kv: kv[1]))
        lines.append("the camera effects, each fitted with the mesh's own error (a body up to "
                     f"{diagnosis.mesh_bracket.load_scale:.3g} times as compliant, as the other "
                     f"quadratic element on this mesh): held-out {compared} mm")
    lines += [plate_resolution_line(diagnosis.robot, height) for final in diagnosis.selected
              if (height := final.candidate.plate_height_mm(final.values)) is not None]
    for group in diagnosis.groups:
        lines.append(f"this data cannot tell apart: {', '.join(group)} ({group_reason(group)})")
    lines += [unreached_line(final) for final in diagnosis.finals if final.refit.unreached]
    if evidence["jumps_in_holds"]:
        followed = any(final.refit.prediction.followed for final in diagnosis.selected)
        lines.append(jumps_line(evidence["jumps_in_holds"], len(diagnosis.observations.recordings),
                                followed))
    if (evidence.get("prediction_element") != evidence.get("element")
            and evidence["rms_given_element_mm"] > 1.5 * evidence["rms_nominal_mm"]):
        lines.append(f"the robot's {evidence['element']} mesh alone leaves "
                     f"{evidence['rms_given_element_mm']:.2f} mm RMS (locking, "
                     f"docs/locking.md): diagnosed with {evidence['prediction_element']} "
                     f"elements on the same mesh ({evidence['rms_nominal_mm']:.2f} mm); "
                     "use the robot with element = \"p2\" for sensing")
    return lines


def mesh_rest_line(diagnosis: Diagnosis) -> str:
    """The summary's line for a fit named though it leaves more than the noise, since the
    mesh's two quadratic elements disagree by more than twice that with it (fit_bracket)."""
    bracket = diagnosis.fit_bracket
    states = bracket.groups + bracket.unsolved
    unsolved = (f"; in the other {bracket.unsolved} of the {states} states the other element "
                "has no equilibrium near it" if bracket.unsolved else "")
    return (f"it leaves {bracket.rest_relative_mm:.2f} mm across frames (noise floor "
            f"{diagnosis.noise_floor_mm:.2f} mm) and {bracket.rest_static_mm:.2f} mm static "
            f"in {bracket.groups} states, less than half of what this mesh's two quadratic "
            f"elements disagree by there with the fitted values ({bracket.relative_mm:.2f} mm "
            f"across frames, {bracket.static_mm:.2f} mm static{unsolved}): the mesh cannot "
            "resolve the body there and is the likely cause of the rest (a finer mesh would "
            "tell)")


def _static_left(evidence: dict) -> str:
    """The static residual a fit leaves, and what the camera pose cannot account for of it
    where the calibration's markers let the pose move (pipeline._static_left_mm)."""
    final, left = evidence["static_final_mm"], evidence["static_after_pose_mm"]
    return (f"{final:.2f} mm" if left == final else
            f"{final:.2f} mm ({left:.2f} mm beyond the camera pose its calibration allows)")


def static_beyond_line(diagnosis: Diagnosis) -> str:
    """The summary's line for a fit named though it leaves more than the noise across
    frames, since without it only what every frame shares was beyond the mesh's own error
    (FitBracket.explains_static_beyond)."""
    fitted, floor = diagnosis.fit_bracket, diagnosis.noise_floor_mm
    return (f"without it the model is {_nominal_against_mesh(diagnosis)}: only the shape "
            f"every frame shares was beyond the mesh's own error; with it "
            f"{fitted.rest_static_mm:.2f} mm static is left, and "
            f"{systematic_mm(fitted.rest_relative_mm, floor):.2f} mm across frames, the mesh's "
            f"(its elements disagree by {fitted.relative_mm:.2f} mm there with the fitted "
            "values; a finer mesh would tell)")


def mismatch_within_mesh_line(diagnosis: Diagnosis) -> str:
    """The summary's line for `none` where a mismatch no effect names is no larger than the
    mesh's own error (pipeline._mismatch_within_mesh)."""
    partial = (f"; {', '.join(diagnosis.partial)} fits part of it, too little to name"
               if diagnosis.partial else "")
    return (f"the model explains the recording to {diagnosis.evidence['rms_nominal_mm']:.2f} mm "
            f"RMS, within this mesh's own error: it is {_nominal_against_mesh(diagnosis)}"
            f"{partial}: the mesh is the likely cause, not physics (a finer mesh would tell)")


def _nominal_against_mesh(diagnosis: Diagnosis) -> str:
    """"X mm above the noise across frames ... disagree by A and B mm" of the nominal model
    against its two elements' disagreement (diagnosis.nominal_bracket)."""
    bracket, floor = diagnosis.nominal_bracket, diagnosis.noise_floor_mm
    return (f"{systematic_mm(bracket.rest_relative_mm, floor):.2f} mm above the noise across "
            f"frames (noise floor {floor:.2f} mm) and {bracket.rest_static_mm:.2f} mm static "
            f"from the recording, where this mesh's two quadratic elements disagree by "
            f"{bracket.relative_mm:.2f} and {bracket.static_mm:.2f} mm")


def _values_text(parameters: dict[str, dict[str, Any]]) -> str:
    """"name = value [low, high] unit, ..." of an entry's parameters."""
    return ", ".join(f"{k} = {v['value']:.4g} [{v['ci95'][0]:.4g}, {v['ci95'][1]:.4g}]"
                     f"{' ' + v['unit'] if v['unit'] else ''}" for k, v in parameters.items())


def fitted_robot_toml(robot_file: Path, diagnosis: Diagnosis, output_dir: Path) -> str:
    """The robot file's text with paths made relative to output_dir and the selected effects
    appended as `[[effect]]` tables (none for `none` / `unexplained`)."""
    text = Path(robot_file).read_text()
    base = Path(robot_file).resolve().parent

    def relocate(match: re.Match) -> str:
        path = (base / match.group(2)).resolve()
        return f'{match.group(1)}"{Path(os.path.relpath(path, output_dir.resolve())).as_posix()}"'

    # [mesh] path and reduced are relative to the robot file: rebase them on the output
    text = re.sub(r'(?m)^(\s*(?:path|reduced)\s*=\s*)"([^"]+)"', relocate, text)
    fitted = diagnosis.fitted
    if fitted is None:
        return text
    with_mesh = diagnosis.with_mesh.get(fitted)
    reported = fitted if with_mesh is None else with_mesh
    tables = [effect_toml(e) for e in reported.candidate.effects(reported.values)]
    if with_mesh is not None:
        # the mesh's own error, fitted with the effects: it belongs to this mesh
        tables[-1] = ("# this mesh's own stiffness error, fitted with the effects above "
                      "(diagnosis.json: evidence.mesh_allowance); leave it out on a finer "
                      "mesh\n" + tables[-1])
    # the file's own [[effect]] tables were left out of the diagnosis: the fitted ones replace
    # them (an effect table holds single-line keys up to the next table header)
    text = re.sub(r"(?ms)^\[\[effect\]\]\n.*?(?=^\[|\Z)", "", text)
    header = f"\n# fitted by softforce diagnose {__version__} (diagnosis.json)\n"
    return text.rstrip("\n") + "\n" + header + "\n".join(tables)


def jumps_line(jumps: list[dict], recordings: int, followed: bool = False) -> str:
    """The summary's line for frames whose points jumped with the inputs held
    (evidence.jumps_in_holds, diagnosis.jumps); `followed`: the selected fit solved the
    frames in turn, as the body moves (refit.ExactModel.followed)."""
    where = "; ".join(
        f"frame {jump['frame']}" + (f" of recording {jump['recording'] + 1}" if recordings > 1
                                    else "")
        + f" ({jump['moved_mm']:.1f} mm, {jump['typical_mm']:.1f} mm in the other holds)"
        for jump in jumps)
    if followed:
        return (f"the robot jumps with its inputs held: {where}. The fitted model, solved "
                "frame by frame from each frame's shape to the next, passes a fold "
                "(snaps through) and follows the body there")
    return (f"the robot jumps with its inputs held: {where}. It snapped through (passed a "
            "fold), or the robot or the camera moved; the model is solved near its nominal "
            "equilibria and follows no such jump, so what is fitted after it is not to be "
            "trusted")


def unreached_line(final: Final) -> str:
    """Where a refit stopped because the exact model has no equilibrium further on: the mesh,
    not the body, may be what leaves the mismatch there."""
    first = final.refit.unreached[0]
    where = f" ({first})" if isinstance(first, NoEquilibriumError) else f": {first}"
    values = ", ".join(f"{name} = {value:.4g}" for name, value in zip(
        (f"{h.label}.{p}" if len(final.candidate.hypotheses) > 1 else p
         for h in final.candidate.hypotheses for p in h.free), final.values, strict=True))
    return (f"{final.candidate.label}: the model has no equilibrium near the recording "
            f"further on{where}, so its fit stopped at {values}: a snap-through of this "
            "mesh may be what leaves the mismatch (a finer mesh would tell)")


def plate_resolution_line(robot: Robot, height_mm: float) -> str:
    """What a plate's fitted height is resolved to on this mesh (support.rim_heights_mm)."""
    below, above = (f"{h:.2f} mm" if h is not None else "none"
                    for h in rim_heights_mm(robot, height_mm))
    return (f"support_contact: a plate props the nodes above it at rest and lets the others "
            f"through, so its prediction jumps where its height passes a node's; this mesh's "
            f"nearest to {height_mm:.2f} mm rest at {below} (below) and {above} (above): the "
            "height is resolved to that spacing, not to its interval (a finer mesh would "
            "tell)")


def group_reason(group: list[str]) -> str:
    """Why the effects of a group (labels) are one signature on this recording."""
    names = frozenset(label.split("[")[0] for label in group)
    if len(names) == 1:
        return ("the recording loads these regions or cables together: a trajectory that "
                "moves them apart would separate them")
    known = [reason for pair, reason in GROUP_REASONS.items() if pair <= names]
    return "; ".join(known) if known else (
        "their held-out errors per trajectory segment differ by less than 2 standard "
        "errors, or by 1% or less: a recording that loads them differently would separate "
        "them")
