"""Offline training of a reduced model: snapshots, POD basis, ECSW sampling, validation."""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import qmc

from softforce_cli.errors import ModelError
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.reduction.ecsw import (
    ECSW_TOLERANCE,
    POINT_TOLERANCE_FACTOR,
    energy_weight,
    force_contributions,
    point_force_contributions,
    point_operators,
    point_tangent_contributions,
    sparse_nnls,
    tangent_contributions,
)
from softforce_cli.fem.reduction.pod import ENERGY_TOLERANCE, pod_basis, projection_errors
from softforce_cli.fem.reduction.reduced_model import (
    ReducedModel,
    ReducedModelWarning,
    Reduction,
    TrainingBox,
)
from softforce_cli.fem.reduction.rom_file import fingerprint
from softforce_cli.fem.reduction.snapshots import (
    MAX_FORCE_N,
    SEED,
    ContactSites,
    TrainingSet,
    actuation_design,
    collect,
    load_training_set,
    save_training_set,
)
from softforce_cli.fem.reduction.starts import grid_levels, start_library
from softforce_cli.fem.statics import PointLoads, solve_equilibrium

# The validation's contact force, as a fraction of max_force_n: a probe's 0.3 N at the
# default 1 N, inside the contact equilibria's range.
VALIDATION_FORCE = 0.3
# A validation error above this fraction of the training's largest shape is reported: on the
# Diamond the sampling holds 0.1 mm (0.7% of 15.7 mm) down to ECSW 3e-2 and breaks at 5e-2
# (3.0 mm, 19%), where its points no longer carry the body's stiffness.
VALIDATION_WARNING_FRACTION = 0.05
# Training presses no closer than this to the clamp (mm): a probe does not reach in there,
# and the stiff clamped region would only take modes.
CLAMP_CLEARANCE_MM = 15.0


@dataclass(frozen=True)
class TrainingSettings:
    """Training knobs, with why.

    energy_tolerance   : POD energy left out (pod.ENERGY_TOLERANCE).
    ecsw_tolerance     : relative residual of the sampled element sums, each state's in the
                         energy norm of its displacement error (ecsw.ECSW_TOLERANCE);
                         0: no hyper-reduction, every quadrature point at weight 1 (the
                         Galerkin projection: exact, an update as costly as the mesh).
    max_modes          : cap on the basis size: the update costs ~ sampled points x r^2
                         (on the Diamond 200 modes read the bench's probes 8.5% off at the
                         median and keep W under its 0.25 N probe within 2-12%, 280 within
                         1-5% at twice the update: docs/reduced_model.md).
    max_elements       : cap on the sampled elements (None: the tolerance decides).
    tangent_directions : reduced directions the tangent is trained along, per response state.
    extra_actuations   : Halton points inside the box besides its structured points.
    response_states    : equilibria where unit-force responses are taken (12: every static
                         snapshot of 4 cables; with 4 of them W_aa erred 19% instead of 13%).
    max_force_n        : largest contact force of the loaded states (N).
    validations        : untrained actuations the result is checked on (full solves), each
                         also under a contact force: the file's rms_error_mm, quoted when
                         a use leaves the box, is over both.
    contact_states     : contact equilibria per static snapshot (snapshots.ContactSites):
                         sensing linearises at loaded states; with them (and the equilibria
                         first in the POD, 200 modes) the reduced coarse p2 Diamond reads the
                         bench's 0.15-0.25 N probes 13.5% off at the median, against 86%
                         before, and 8.5% since their responses come first in the POD
                         (successive_pod; docs/reduced_model.md).
    sample_points      : ECSW down to single quadrature points (a second pass among the
                         sampled elements' points: fewer evaluations per update); False keeps
                         whole elements.
    start_levels       : grid values per cable of the reduced model's own equilibria kept to
                         start static solves given no start (starts.py; levels^a of them,
                         fewer levels for many cables: at most MAX_GRID_STARTS). On the
                         Diamond, 4 levels (256) took the median solve from 5 Newton
                         iterations (the 12 training equilibria alone) to 3, as 5 levels
                         (625) did; 3 levels left 5 on some actuations. 1 keeps the
                         training equilibria only.
    box_fraction       : train over [min, min + fraction (max - min)] of each cable: the
                         robot file's max may fold the accurate (softer) model beyond what
                         the sensing uses (the coarse Diamond's p2 model with one cable at
                         20 mm and the others held needs 25+ Newton steps).
    """

    energy_tolerance: float = ENERGY_TOLERANCE
    ecsw_tolerance: float = ECSW_TOLERANCE
    max_modes: int = 200
    max_elements: int | None = None
    tangent_directions: int = 8
    extra_actuations: int = 2
    response_states: int = 12
    max_force_n: float = MAX_FORCE_N
    validations: int = 2
    box_fraction: float = 1.0
    sample_points: bool = True
    contact_states: int = 3
    start_levels: int = 4


def train(model: FEModel, controls: tuple[str, ...], low: np.ndarray, high: np.ndarray,
          feature_nodes: np.ndarray, feature_normals: np.ndarray, surface_nodes: np.ndarray,
          settings: TrainingSettings = TrainingSettings(),
          progress: Callable[[int, int], None] | None = None,
          cache: Path | None = None, sites: ContactSites | None = None) -> Reduction:
    """Train a reduction of `model` over the actuation box [low, high] (a,) in each cable's
    control units, with responses at the feature nodes (p,) along their normals (p, 3), and
    contact equilibria pressing at `sites` (settings.contact_states per static snapshot).

    The snapshots (nearly all the time) are kept in `cache` (npz) when given, and reused by a
    later run on the same model, box and settings: a training stopped after them resumes there.
    """
    started = time.perf_counter()
    actuations = actuation_design(low, high, settings.extra_actuations)
    total = 2 * len(actuations) + 3 + settings.validations

    def step(done: int) -> None:
        if progress is not None:
            progress(done, total)

    key = "|".join([json.dumps(fingerprint(model), sort_keys=True), repr(controls),
                    np.round(actuations, 9).tobytes().hex(), repr(settings.max_force_n),
                    repr(settings.response_states), repr(np.asarray(feature_nodes).tolist()),
                    "" if sites is None else f"{sites.per_state}:{sites.nodes.tobytes().hex()}"])
    data = None if cache is None else load_training_set(cache, key)
    if data is None:
        data = collect(model, controls, actuations, feature_nodes, feature_normals,
                       settings.max_force_n, settings.response_states,
                       lambda done, _: step(done), sites)
        if cache is not None:
            save_training_set(cache, data, key)
    snapshots_s = time.perf_counter() - started
    rest = model.rest_nodes_mm.ravel()
    states = data.states_mm
    states = states.reshape(len(states), -1).T - rest[:, None]
    # the loaded states' responses before the unloaded ones (successive_pod)
    basis, singular = successive_pod([states, data.contact_responses, data.responses],
                                     settings.energy_tolerance, settings.max_modes)
    columns = np.hstack([states, data.contact_responses, data.responses])
    worst_projection = float(projection_errors(basis, columns).max())
    step(2 * len(actuations) + 1)
    pod_s = time.perf_counter() - started - snapshots_s
    elements, points, weights, residual = sample(model, basis, data, settings, controls)
    step(2 * len(actuations) + 2)
    ecsw_s = time.perf_counter() - started - snapshots_s - pod_s
    # the true equilibria (not the first-order loaded states, which extrapolate)
    equilibria = np.concatenate([data.positions_mm, data.contact_mm]) - model.rest_nodes_mm
    moved = float(np.sqrt(np.mean(np.sum(equilibria**2, axis=2), axis=1)).max())
    box = TrainingBox(tuple(controls), np.asarray(low, float), np.asarray(high, float),
                      data.max_force_n, np.asarray(model.gravity_mm_s2, float), float("nan"),
                      moved)
    info = {
        "modes": int(basis.shape[1]), "sampled_elements": len(np.unique(elements)),
        "sampled_points": len(points), "elements": len(model.tets),
        "points": len(model.tets) * model.shape_gradients.shape[1],
        "snapshot_columns": int(columns.shape[1]),
        "static_snapshots": len(actuations), "contact_snapshots": len(data.contact_mm),
        "energy_tolerance": settings.energy_tolerance,
        "worst_projection_error": worst_projection,
        "ecsw_tolerance": settings.ecsw_tolerance,
        "ecsw_residual": residual,
        "singular_values": singular[: 2 * basis.shape[1]].tolist(),
        "snapshots_s": snapshots_s, "pod_s": pod_s, "ecsw_s": ecsw_s,
    }
    reduction = Reduction(model.element.name, basis, elements, points, weights, box,
                          fingerprint(model), model.material.young_modulus_mpa, info)
    starts = start_library(ReducedModel(model, reduction), tuple(controls), data.actuations,
                           data.positions_mm, box.cable_min, box.cable_max,
                           grid_levels(settings.start_levels, len(controls)))
    reduction = dataclasses.replace(reduction, starts=starts)
    step(2 * len(actuations) + 3)
    info["starts_s"] = time.perf_counter() - started - snapshots_s - pod_s - ecsw_s
    info["start_equilibria"] = len(starts.inputs)
    errors = validate(model, reduction, controls, low, high, surface_nodes,
                      settings.validations, lambda done: step(total - settings.validations
                                                              + done), sites)
    rms = float(np.sqrt(np.mean(np.square(errors)))) if len(errors) else float("nan")
    if rms > VALIDATION_WARNING_FRACTION * moved:
        warnings.warn(f"the reduced model is {rms:.2g} mm RMS off its full model at untrained "
                      f"actuations ({100 * rms / moved:.0f}% of its training's largest shape, "
                      f"{moved:.3g} mm): its sampling is too loose; retrain with a smaller ECSW "
                      "tolerance (--ecsw-tolerance) or more modes", ReducedModelWarning,
                      stacklevel=2)
    info.update(validation_rms_mm=errors.tolist(),
                validation_s=(time.perf_counter() - started - snapshots_s - pod_s - ecsw_s
                              - info["starts_s"]),
                total_s=time.perf_counter() - started)
    return dataclasses.replace(reduction, box=dataclasses.replace(box, rms_error_mm=rms),
                               info=info)


def check_trainable(robot) -> None:
    """ModelError unless the robot (model.robot.Robot) has cables, each with a finite
    [min, max]: the training spans their actuation box."""
    if not robot.cable_specs:
        raise ModelError(f"{robot.config.source}: the robot has no [[cable]]; a reduced model "
                         "is trained over its cables' actuation box, so sense and calibrate "
                         "it with its full model")
    for spec in robot.cable_specs:
        if not np.isfinite(spec.max) or not np.isfinite(spec.min):
            raise ModelError(f"{robot.config.source}: cable {spec.name!r} has no finite min/max;"
                             " set both in the robot file: they are the box a reduced model is "
                             "trained over")


def train_robot(robot, settings: TrainingSettings = TrainingSettings(),
                progress: Callable[[int, int], None] | None = None,
                cache: Path | None = None) -> Reduction:
    """Train a reduction of a Robot's full FE model (model.robot.Robot, its element) over the
    cables' [min, max] box; ModelError where check_trainable finds none."""
    check_trainable(robot)
    specs = robot.cable_specs
    low = np.array([c.min for c in specs], dtype=float)
    high = np.array([c.max for c in specs], dtype=float)
    high = low + settings.box_fraction * (high - low)
    return train(robot.full_fe_model, tuple(c.control for c in specs), low, high,
                 robot.feature_nodes, robot.feature_normals, robot.mesh.surface_nodes,
                 settings, progress, cache, contact_sites(robot, settings.contact_states))


def successive_pod(groups: list[np.ndarray], tolerance: float, max_modes: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal basis (d, r) and singular values: the POD of each group of snapshot
    columns (d, c_i) in turn, with the span of the groups before it taken out, each to the
    energy tolerance, r capped at max_modes (the earlier groups first).

    Training passes the equilibria, then the responses at the contact equilibria, then the
    unloaded responses. One POD of everything lets the responses, 50 times as many as the
    equilibria, take the modes: on the coarse p2 Diamond such a basis missed the equilibria
    by only 0.05 mm, yet its Galerkin solutions were 1.1 mm off (the body's soft modes take
    up the stiff local error); with the equilibria first, 0.03-0.08 mm. Sensing linearises
    at loaded states, whose compliance the contact equilibria's responses hold: with them
    before the unloaded responses, 200 modes (integrated exactly) put W_ef and W_af under
    the bench's 0.25 N probe 8.3% and 12.7% off instead of 19.0% and 29.5%, as 280 modes in
    the other order did (docs/reduced_model.md, "The basis' capacity").
    """
    basis = groups[0][:, :0]
    singular = []
    for group in groups:
        if basis.shape[1] >= max_modes:
            break
        if not group.shape[1]:  # no contact equilibria trained
            continue
        rest = group - basis @ (basis.T @ group)
        modes, values = pod_basis(rest, tolerance, max_modes - basis.shape[1])
        basis = np.hstack([basis, modes])
        singular.append(values)
    stacked = basis
    basis, _ = np.linalg.qr(stacked)
    basis[~np.any(stacked != 0.0, axis=1)] = 0.0  # clamped dofs stay exactly clamped
    return basis, np.concatenate(singular)


def contact_sites(robot, per_state: int) -> ContactSites:
    """The surface nodes of a Robot farther than CLAMP_CLEARANCE_MM from every clamped node
    (where a probe can press), with their outward normals at rest; per_state contact
    equilibria per static snapshot."""
    nodes = robot.mesh.surface_nodes
    rest = robot.mesh.nodes_mm
    clamped = cKDTree(rest[robot.fixed_nodes])
    distance, _ = clamped.query(rest[nodes])
    nodes = nodes[distance > CLAMP_CLEARANCE_MM]
    return ContactSites(nodes, robot.mesh.vertex_normals[nodes], per_state)


def sample(model: FEModel, basis: np.ndarray, data: TrainingSet, settings: TrainingSettings,
           controls: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """ECSW in two passes: (elements (s,), points (s,), weights (s,), relative residual),
    each state's blocks in the energy norm of its displacement error (energy_norms).

    The first pass picks elements among the whole mesh; the second picks single quadrature
    points among those elements' points against the same (whole-mesh) targets. The update
    costs ~ 9 r^2 per evaluated point, and an element carries 4 (P2) or 5 (P2-P0) of them, of
    which a few suffice: the second pass cuts the update several times for the same error.
    """
    if settings.ecsw_tolerance <= 0.0:
        return (*every_point(model), 0.0)
    states = projected_states(model, basis, data.states_mm)
    norms = energy_norms(model, basis, states, data.state_tensions_n, controls)

    def whole(x: np.ndarray, directions: np.ndarray | None) -> np.ndarray:
        if directions is None:
            return force_contributions(model, basis, x)
        return tangent_contributions(model, basis, x, directions)

    C, b, targets = ecsw_system(basis, data, states, norms, settings.tangent_directions, whole)
    factor = POINT_TOLERANCE_FACTOR if settings.sample_points else 1.0
    first = sparse_nnls(C, b, factor * settings.ecsw_tolerance, settings.max_elements)
    del C
    candidates = first.elements
    if not settings.sample_points:
        per_element = model.shape_gradients.shape[1]
        return (np.repeat(candidates, per_element), np.tile(np.arange(per_element),
                len(candidates)), np.repeat(first.weights, per_element),
                first.relative_residual)
    operators = point_operators(model, basis, candidates)

    def pointwise(x: np.ndarray, directions: np.ndarray | None) -> np.ndarray:
        if directions is None:
            return point_force_contributions(model, operators, candidates, x)
        return point_tangent_contributions(model, operators, candidates, x, directions)

    C, b, _ = ecsw_system(basis, data, states, norms, settings.tangent_directions, pointwise,
                          targets)
    second = sparse_nnls(C, b, settings.ecsw_tolerance)
    per_element = operators.shape[1]
    return (candidates[second.elements // per_element], second.elements % per_element,
            second.weights, second.relative_residual)


def every_point(model: FEModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(elements (s,), points (s,), weights (s,)): every quadrature point of the mesh at
    weight 1, the reduced model then being the exact Galerkin projection."""
    elements, per_element = model.shape_gradients.shape[:2]
    return (np.repeat(np.arange(elements), per_element),
            np.tile(np.arange(per_element), elements), np.ones(elements * per_element))


def projected_states(model: FEModel, basis: np.ndarray, states_mm: np.ndarray) -> np.ndarray:
    """(k, n, 3) mm: states (k, n, 3) projected on the basis, where the reduced model sees
    them."""
    rest = model.rest_nodes_mm
    moved = (states_mm - rest).reshape(len(states_mm), -1)
    return rest + ((moved @ basis) @ basis.T).reshape(states_mm.shape)


def energy_norms(model: FEModel, basis: np.ndarray, states_mm: np.ndarray,
                  tensions_n: np.ndarray, controls: tuple[str, ...]) -> list[np.ndarray | None]:
    """ecsw.energy_weight at each state (k, n, 3) mm with its cable tensions (k, a) N: the
    full model's tangent (cables' geometric stiffness included) on the basis, its taut
    displacement-controlled cables held."""
    free = basis[model.free_dofs]
    inputs = CableInputs(controls, np.zeros(len(controls)))
    weights = []
    for x, tensions in zip(states_mm, tensions_n, strict=True):
        _, stiffness = model.internal_forces_and_stiffness(x)
        stiffness = stiffness + model.cable_stiffness(x, tensions)
        rows = model.cable_jacobian(x)[inputs.held(tensions)] @ basis
        weights.append(energy_weight(free.T @ (stiffness @ free), rows))
    return weights


def ecsw_system(basis: np.ndarray, data: TrainingSet, states_mm: np.ndarray,
                norms: list[np.ndarray | None], directions: int,
                contributions: Callable[[np.ndarray, np.ndarray | None], np.ndarray],
                targets: list[np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """C (rows, columns), b (rows,) of the ECSW fit, and the blocks' exact targets.

    Blocks: the reduced internal forces at every training state (data.states_mm, projected:
    states_mm; contact equilibria included; their tangents are not fitted: along 2 or 8
    directions each they made the loaded cases worse, docs/reduced_model.md), and the reduced
    tangents along the leading reduced response directions at the response states;
    `contributions(x, Q or None)` gives a block's columns (elements or points). A block is
    weighted by its state's energy norm (norms, aligned with the states; None: its own
    norm) and scaled to unit norm so that every state counts alike. The targets are the
    columns' sums unless given (the whole mesh's sums, when the columns are a subset).
    """
    r = basis.shape[1]
    per_state = data.responses.shape[1] // len(data.response_states)

    def blocks() -> Iterator[tuple[np.ndarray, int]]:
        """(block (r, columns), the index of its state), made one state at a time: C is
        filled as they come, never held twice (2.6 GB at 1e-3 on the coarse Diamond)."""
        for owner, x in enumerate(states_mm):
            yield contributions(x, None), owner
        for j, index in enumerate(data.response_states):
            reduced = basis.T @ data.responses[:, j * per_state:(j + 1) * per_state]
            leading = np.linalg.svd(reduced, full_matrices=False)[0][:, :directions]
            moved = contributions(states_mm[index], leading)
            for part in (np.split(moved, leading.shape[1]) if r else []):
                yield part, int(index)

    count = len(states_mm) + len(data.response_states) * min(directions, r)
    used_targets: list[np.ndarray] = []
    C = b = None
    rows = 0
    for k, (block, owner) in enumerate(blocks()):
        target = block.sum(axis=1) if targets is None else targets[k]
        used_targets.append(target)
        if norms[owner] is not None:
            block, target = norms[owner] @ block, norms[owner] @ target
        norm = float(np.linalg.norm(target))
        if norm == 0.0:
            continue
        if C is None:
            # r rows a block at most: an energy norm keeps r - c (c taut cables held)
            C = np.empty((count * r, block.shape[1]))
            b = np.empty(len(C))
        np.divide(block, norm, out=C[rows:rows + len(block)])
        b[rows:rows + len(block)] = target / norm
        rows += len(block)
    if C is None:
        return np.zeros((0, 0)), np.zeros(0), used_targets
    return C[:rows], b[:rows], used_targets


def validate(model: FEModel, reduction: Reduction, controls: tuple[str, ...], low: np.ndarray,
             high: np.ndarray, surface_nodes: np.ndarray, count: int,
             progress: Callable[[int], None], sites: ContactSites | None = None
             ) -> np.ndarray:
    """(count,) or (2 count,) RMS surface displacement error (mm) of the reduced model against
    the full one at untrained actuations (Halton points of another seed), then, with `sites`,
    at each of them under a contact force of VALIDATION_FORCE times max_force_n into a site
    of another draw (what sensing asks of the model)."""
    if count == 0 or not len(low):
        return np.zeros(0)
    reduced = ReducedModel(model, reduction)
    points = low + qmc.Halton(len(low), seed=SEED + 1).random(count) * (high - low)
    rng = np.random.default_rng(SEED + 1)
    cases: list[tuple[CableInputs, PointLoads | None]] = [
        (CableInputs(controls, values), None) for values in points]
    if sites is not None and len(sites.nodes):
        for inputs, _ in list(cases):
            site = rng.integers(len(sites.nodes))
            force = -VALIDATION_FORCE * reduction.box.max_force_n * sites.normals[site]
            cases.append((inputs, PointLoads(Attachment.at_nodes(sites.nodes[[site]]),
                                             force[None])))
    errors = []
    for i, (inputs, loads) in enumerate(cases):
        full = solve_equilibrium(model, inputs, loads).positions_mm[surface_nodes]
        approx = solve_equilibrium(reduced, inputs, loads).positions_mm[surface_nodes]
        errors.append(float(np.sqrt(np.mean(np.sum((full - approx) ** 2, axis=1)))))
        progress(min(i + 1, count))
    return np.array(errors)
