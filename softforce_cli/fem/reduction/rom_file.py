"""The .rom.npz file: a trained reduction, with the fingerprint of the model it belongs to.

Arrays: basis (3n, r), elements (s,), points (s,), weights (s,), cable_min (a,), cable_max (a,),
gravity_mm_s2 (3,); start_inputs (k, a), start_coordinates (k, r), start_sensitivities
(k, r, a) and start_scale (a,), the equilibria static solves start from (absent in files
from before them, which load with none); `meta`: a JSON string with format, element,
fingerprint, controls, max_force_n, rms_error_mm, max_displacement_mm, young_modulus_mpa and
info (training figures).

The fingerprint hashes what the basis and the sampling are only valid for: the FE nodes and
elements, the element type, the clamped nodes, the law and Poisson's ratio, and the cables'
attachment. Young's modulus is left out on purpose: every law is linear in the Lame
parameters, so at a fixed Poisson's ratio all internal forces scale with E and a reduction
trained at one E holds at any other (a material calibration can refit E and keep the file).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from softforce_cli.errors import ModelError
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.reduction.reduced_model import ReducedModel, Reduction, TrainingBox
from softforce_cli.fem.reduction.starts import StartLibrary
from softforce_cli.io.atomic import atomic_path

FORMAT = "softforce-rom-2"  # 2: sampled quadrature points, not whole elements


def _digest(*parts: object) -> str:
    hasher = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            hasher.update(np.ascontiguousarray(part).tobytes())
            hasher.update(str(part.shape).encode())
        else:
            hasher.update(repr(part).encode())
    return hasher.hexdigest()[:16]


def fingerprint(model: FEModel) -> dict[str, str]:
    """{part: short hash} for mesh, element, supports, material and cables of a full model."""
    cables = [(c.name, c.path.node_indices, np.round(c.path.weights, 9),
               np.round(c.pull_point_mm, 6)) for c in model.cables]
    return {
        "mesh": _digest(np.round(model.rest_nodes_mm, 6), model.tets.astype(np.int64)),
        "element": _digest(model.element.name),
        "supports": _digest(np.asarray(model.fixed_nodes, dtype=np.int64)),
        "material": _digest(model.material.law, round(model.material.poisson_ratio, 9)),
        "cables": _digest(*[p for cable in cables for p in cable]),
    }


def save_reduction(path: Path, reduction: Reduction, force: bool = False) -> None:
    """Write a reduction to `path` (.rom.npz), atomically; OutputExistsError unless force."""
    box = reduction.box
    meta = {
        "format": FORMAT, "element": reduction.element, "fingerprint": reduction.fingerprint,
        "controls": list(box.controls), "max_force_n": box.max_force_n,
        "rms_error_mm": box.rms_error_mm if np.isfinite(box.rms_error_mm) else None,
        "max_displacement_mm": (box.max_displacement_mm
                                if np.isfinite(box.max_displacement_mm) else None),
        "young_modulus_mpa": reduction.young_modulus_mpa, "info": reduction.info,
    }
    starts = reduction.starts
    start_arrays = {} if starts is None else {
        "start_inputs": starts.inputs, "start_coordinates": starts.coordinates,
        "start_sensitivities": starts.sensitivities, "start_scale": starts.scale}
    with atomic_path(Path(path), force=force) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, basis=reduction.basis, elements=reduction.elements,
                 points=reduction.points, weights=reduction.weights,
                 cable_min=box.cable_min, cable_max=box.cable_max,
                 gravity_mm_s2=box.gravity_mm_s2, meta=np.array(json.dumps(meta)),
                 **start_arrays)


def load_reduction(path: Path) -> Reduction:
    """Read a .rom.npz; ModelError naming the file when it is missing or not one."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"reduced model {path} not found; train it with `softforce model "
                         "reduce ROBOT.toml -o FILE.rom.npz`")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
        meta = json.loads(str(arrays["meta"]))
    except (OSError, ValueError, KeyError) as error:
        raise ModelError(f"{path}: not a softforce reduced model ({error}); retrain it with "
                         "`softforce model reduce`") from error
    if meta.get("format") != FORMAT:
        raise ModelError(f"{path}: format {meta.get('format')!r}, expected {FORMAT!r}; retrain "
                         "it with `softforce model reduce`")
    rms, moved = meta["rms_error_mm"], meta.get("max_displacement_mm")
    box = TrainingBox(tuple(meta["controls"]), arrays["cable_min"], arrays["cable_max"],
                      float(meta["max_force_n"]), arrays["gravity_mm_s2"],
                      float("nan") if rms is None else float(rms),
                      float("nan") if moved is None else float(moved))
    starts = _starts(path, arrays) if "start_inputs" in arrays else None
    return Reduction(meta["element"], arrays["basis"], arrays["elements"].astype(np.int64),
                     arrays["points"].astype(np.int64), arrays["weights"], box,
                     dict(meta["fingerprint"]), float(meta["young_modulus_mpa"]),
                     dict(meta["info"]), starts)


def _starts(path: Path, arrays: dict[str, np.ndarray]) -> StartLibrary:
    """The file's start equilibria; ModelError when their shapes disagree with the basis and
    the cables (a damaged file: a solve would fail far from the cause)."""
    try:
        starts = StartLibrary(arrays["start_inputs"], arrays["start_coordinates"],
                              arrays["start_sensitivities"], arrays["start_scale"])
    except KeyError as error:
        raise ModelError(f"{path}: start equilibria incomplete (no {error}); retrain it with "
                         "`softforce model reduce`") from error
    k, a = starts.inputs.shape if starts.inputs.ndim == 2 else (-1, -1)
    r = arrays["basis"].shape[1]
    if (a != len(arrays["cable_min"]) or starts.coordinates.shape != (k, r)
            or starts.sensitivities.shape != (k, r, a) or starts.scale.shape != (a,)):
        raise ModelError(f"{path}: start equilibria do not fit its basis and cables; retrain "
                         "it with `softforce model reduce`")
    return starts


def reduced_model(full: FEModel, reduction: Reduction, source: Path | str = "reduced model"
                  ) -> ReducedModel:
    """The reduced model of `full`; ModelError when the reduction was trained on another
    mesh, element, supports, material law / Poisson's ratio or cables."""
    expected = fingerprint(full)
    differ = [part for part, value in expected.items()
              if reduction.fingerprint.get(part) != value]
    if differ:
        raise ModelError(f"{source} was trained for another model ({', '.join(differ)} "
                         "differ); retrain it with `softforce model reduce ROBOT.toml -o "
                         f"{Path(str(source)).name}`")
    if reduction.basis.shape[0] != 3 * full.node_count:
        raise ModelError(f"{source}: basis for {reduction.basis.shape[0] // 3} nodes, the model "
                         f"has {full.node_count}; retrain it with `softforce model reduce`")
    return ReducedModel(full, reduction)
