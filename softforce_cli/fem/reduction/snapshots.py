"""Training data for a reduced model, from the full (accurate-element) model.

Four kinds of snapshots, all in the full model:
- static equilibria over the actuation box (with the model's gravity): the rest, each cable
  at its max, each pair of neighbouring cables at their max, all at mid-range, and a few
  Halton points inside the box;
- linear responses K^-1 H^T to unit forces along x, y, z at every feature point and to every
  cable, at a few of those equilibria: the columns the compliance W is made of;
- loaded states: each equilibrium plus the first-order response to one or two contact forces
  pressing along the inward normal at random feature points (up to max_force_n);
- contact equilibria: at each static equilibrium, the nonlinear equilibria under one or two
  forces pressing along the inward normal at random surface nodes (anywhere a probe may
  touch, not only at features), and there the responses to the features' normal rows, the
  cables and the contacts themselves: sensing linearises at such loaded states, where the
  compliance differs from the unloaded one by tens of percent under a few tenths of a newton.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import qmc

from softforce_cli.errors import SolverError
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.cables import CableInputs
from softforce_cli.fem.compliance import linearize
from softforce_cli.fem.coordinates import Factor
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.processes import map_on_cores
from softforce_cli.fem.statics import (
    Equilibrium,
    PointLoads,
    SolverSettings,
    solve_by_continuation,
    solve_equilibrium,
)
from softforce_cli.io.atomic import atomic_path

# Contact forces in training reach this by default (N): the paper's heaviest weight, 1.06 N.
MAX_FORCE_N = 1.0
SEED = 20181016  # fixed: training is reproducible
# A training solve that needs more Newton iterations than this is retried in smaller steps
# (a converging one takes ~10 from rest); failing fast saves minutes on a quadratic mesh.
ATTEMPT = SolverSettings(max_iterations=20)
# The loaded states of each static equilibrium: this many contacts pressing at once.
LOADED_CONTACTS = (1, 2)


@dataclass(frozen=True)
class TrainingSet:
    """Snapshots of a full model.

    actuations     : (S, a) cable inputs of the static snapshots (control units).
    positions_mm   : (S, n, 3) their equilibria.
    tensions_n     : (S, a) their cable tensions.
    responses      : (3n, R) mm/N unit-force and cable responses at the response states.
    response_rows  : (R0, 3n) the feature rows H (3 per feature) the responses were asked for
                     (cable rows follow them in `responses`, a per state).
    response_states: (t,) indices of the static snapshots where responses were taken.
    loaded_mm      : (L, n, 3) equilibria plus first-order contact responses.
    max_force_n    : the largest contact force used.
    contact_mm     : (C, n, 3) nonlinear equilibria under contact forces.
    contact_tensions_n : (C, a) their cable tensions.
    contact_responses : (3n, Rc) responses at them, contact_columns per state (the features'
                     normal rows, the cables, then the state's contacts zero-padded to two).
    """

    actuations: np.ndarray
    positions_mm: np.ndarray
    tensions_n: np.ndarray
    responses: np.ndarray
    response_states: np.ndarray
    loaded_mm: np.ndarray
    max_force_n: float
    contact_mm: np.ndarray
    contact_tensions_n: np.ndarray
    contact_responses: np.ndarray

    @property
    def contact_columns(self) -> int:
        """Responses per contact equilibrium (contact_responses is split by it)."""
        return self.contact_responses.shape[1] // max(len(self.contact_mm), 1)

    @property
    def states_mm(self) -> np.ndarray:
        """(S + L + C, n, 3): the static, loaded and contact states, in that order."""
        return np.concatenate([self.positions_mm, self.loaded_mm, self.contact_mm])

    @property
    def state_tensions_n(self) -> np.ndarray:
        """(S + L + C, a): the cable tensions at states_mm, a loaded state's those of the
        equilibrium it extrapolates from."""
        return np.concatenate([self.tensions_n,
                               np.repeat(self.tensions_n, len(LOADED_CONTACTS), axis=0),
                               self.contact_tensions_n])


def actuation_design(low: np.ndarray, high: np.ndarray, extra: int = 2) -> np.ndarray:
    """(S, a) training actuations in the box [low, high]^a: low, each cable at high alone,
    each pair of neighbouring cables (i, i + 1 mod a) at high, all at mid-range, and `extra`
    scrambled Halton points (fixed seed)."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    a = len(low)
    rows = [low.copy()]
    for i in range(a):
        row = low.copy()
        row[i] = high[i]
        rows.append(row)
    if a > 2:
        for i in range(a):
            row = low.copy()
            row[[i, (i + 1) % a]] = high[[i, (i + 1) % a]]
            rows.append(row)
    if a > 1:
        rows.append(0.5 * (low + high))
    if extra and a:
        rows.extend(low + qmc.Halton(a, seed=SEED).random(extra) * (high - low))
    return np.unique(np.array(rows).reshape(-1, a), axis=0)


def response_state_indices(actuations: np.ndarray, count: int = 4) -> np.ndarray:
    """Up to `count` snapshots to take responses at: the first (the lowest actuation), then
    each next the one farthest from those chosen (spread over the box)."""
    chosen = [int(np.argmin(actuations.sum(axis=1)))]
    while len(chosen) < min(count, len(actuations)):
        distance = np.min(np.linalg.norm(actuations[:, None] - actuations[chosen][None],
                                         axis=2), axis=1)
        chosen.append(int(np.argmax(distance)))
    return np.array(chosen, dtype=np.int64)


@dataclass(frozen=True)
class ContactSites:
    """Where training presses: surface nodes (k,) a probe may touch (away from the clamp) and
    their outward unit normals at rest (k, 3); `per_state` contact equilibria per static one,
    each with one or two forces of max_force_n times [CONTACT_LOW, CONTACT_HIGH] split
    between them."""

    nodes: np.ndarray
    normals: np.ndarray
    per_state: int


# A contact equilibrium's total force, as a fraction of max_force_n: a probe's 0.1-0.3 N and
# the heaviest weights both fall inside with the default 1 N.
CONTACT_LOW, CONTACT_HIGH = 0.1, 0.5


@dataclass(frozen=True)
class _Press:
    """Forces pressing at k attachment points, a loaded state's or a contact's: along unit
    directions (k, 3), of magnitudes (k,) N."""

    points: Attachment
    directions: np.ndarray
    magnitudes_n: np.ndarray

    @property
    def loads(self) -> PointLoads:
        return PointLoads(self.points, self.directions * self.magnitudes_n[:, None])


@dataclass(frozen=True)
class _StateSnapshots:
    """What one static equilibrium gives besides itself: its responses (3n, R0 + a) or None,
    its loaded states [(n, 3) mm], and its contact equilibria [(positions (n, 3) mm,
    tensions (a,) N, responses (3n, p + a + 2))]: arrays only, which a worker process sends
    back cheaply (an Equilibrium holds its model)."""

    responses: np.ndarray | None
    loaded_mm: list[np.ndarray]
    contacts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]


def collect(model: FEModel, controls: tuple[str, ...], actuations: np.ndarray,
            feature_nodes: np.ndarray, feature_normals: np.ndarray,
            max_force_n: float = MAX_FORCE_N, response_states: int = 4,
            progress: Callable[[int, int], None] | None = None,
            sites: ContactSites | None = None) -> TrainingSet:
    """Solve, linearise and load the full model at every training actuation (S, a); with
    `sites`, also its contact equilibria and their responses (module docstring).

    The equilibria are solved in turn (each by continuation from the nearest solved); what
    each gives besides (its linearisation, responses, loaded states and contact equilibria)
    on the machine's cores (fem.processes), the first in this process, whose factorisation's
    symbolic analysis the others share. The random loads are drawn beforehand, in a fixed
    order: the same training set either way.
    """
    rng = np.random.default_rng(SEED)
    states = response_state_indices(actuations, response_states)
    features = Attachment.at_nodes(feature_nodes)
    feature_rows = features.cartesian_rows(model.node_count)
    total = 2 * len(actuations)

    def report(done: int) -> None:
        if progress is not None:
            progress(done, total)

    equilibria: list[Equilibrium] = []
    solved: list[tuple[np.ndarray, np.ndarray]] = []
    for values in actuations:
        equilibria.append(_continued(model, controls, values, solved))
        solved.append((values, equilibria[-1].positions_mm))
        report(len(equilibria))
    presses = [_draw_presses(rng, features, feature_normals, sites, max_force_n)
               for _ in actuations]

    def at_state(index: int, factor: Factor | None) -> tuple[_StateSnapshots, Factor]:
        equilibrium = equilibria[index]
        x = equilibrium.positions_mm
        lin = linearize(model, x, equilibrium.cable_tensions_n, factorization=factor)
        responses = (lin.responses(sp_vstack_dense(feature_rows, model.cable_jacobian(x)))
                     if index in states else None)
        loaded, contacts = presses[index]
        moved = [lin.responses(press.points.directional_rows(press.directions,
                                                             model.node_count))
                 @ press.magnitudes_n for press in loaded]
        inputs = CableInputs(controls, actuations[index])
        reached = [_contact_state(model, inputs, equilibrium, features, feature_normals, press,
                                  lin.factorization) for press in contacts]
        return _StateSnapshots(responses, [x + m.reshape(-1, 3) for m in moved],
                               [state for state in reached if state is not None]
                               ), lin.factorization

    first, factor = at_state(0, None)
    report(len(actuations) + 1)
    rest = map_on_cores(lambda i: at_state(i + 1, factor)[0], len(actuations) - 1,
                        lambda done: report(len(actuations) + 1 + done))
    snapshots = [first, *rest]
    responses = [s.responses for s in snapshots if s.responses is not None]
    loaded = [x for s in snapshots for x in s.loaded_mm]
    contacts = [c for s in snapshots for c in s.contacts]
    shape = (0, model.node_count, 3)
    return TrainingSet(
        actuations=np.asarray(actuations, float),
        positions_mm=np.array([e.positions_mm for e in equilibria]),
        tensions_n=np.array([e.cable_tensions_n for e in equilibria]),
        responses=np.hstack(responses), response_states=states, loaded_mm=np.array(loaded),
        max_force_n=float(max_force_n),
        contact_mm=np.array([x for x, _, _ in contacts]) if contacts else np.zeros(shape),
        contact_tensions_n=np.array([t for _, t, _ in contacts]).reshape(len(contacts),
                                                                         len(controls)),
        contact_responses=(np.hstack([r for _, _, r in contacts]) if contacts
                           else np.zeros((3 * model.node_count, 0))),
    )


def _draw_presses(rng: np.random.Generator, features: Attachment,
                  feature_normals: np.ndarray, sites: ContactSites | None, max_force_n: float
                  ) -> tuple[list[_Press], list[_Press]]:
    """One static equilibrium's random loads, drawn from `rng` in a fixed order: its loaded
    states (one, then two contacts pressing inwards at random features, LOADED_CONTACTS) and
    its contact equilibria (sites.per_state: one or two forces at random surface nodes,
    their total max_force_n times [CONTACT_LOW, CONTACT_HIGH])."""
    loaded = []
    for count in LOADED_CONTACTS:
        picks = rng.choice(len(feature_normals), size=count, replace=False)
        magnitudes = rng.uniform(0.3, 1.0, count) * max_force_n / count
        loaded.append(_Press(features.subset(picks), -feature_normals[picks], magnitudes))
    contacts = []
    for _ in range(0 if sites is None else sites.per_state):
        count = int(rng.integers(1, 3))
        picks = rng.choice(len(sites.nodes), size=count, replace=False)
        total = rng.uniform(CONTACT_LOW, CONTACT_HIGH) * max_force_n
        contacts.append(_Press(Attachment.at_nodes(sites.nodes[picks]), -sites.normals[picks],
                               rng.dirichlet(np.ones(count)) * total))
    return loaded, contacts


def _contact_state(model: FEModel, inputs: CableInputs, unloaded: Equilibrium,
                   features: Attachment, feature_normals: np.ndarray, press: _Press,
                   factor: Factor | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """One contact equilibrium from `unloaded`: (its positions (n, 3) mm, cable tensions (a,)
    N, responses (3n, p + a + 2) to the features' rest normals, the cables and its (up to
    two) contacts), or None when Newton's method does not reach it (a load the body buckles
    under: left out)."""
    loads = press.loads
    try:
        loaded = solve_equilibrium(model, inputs, loads, start_mm=unloaded.positions_mm,
                                   settings=ATTEMPT)
    except SolverError:
        return None
    x = loaded.positions_mm
    lin = linearize(model, x, loaded.cable_tensions_n, loads, factorization=factor)
    contact_rows = press.points.directional_rows(press.directions, model.node_count).toarray()
    rows = np.vstack([features.directional_rows(feature_normals, model.node_count).toarray(),
                      model.cable_jacobian(x), contact_rows,
                      np.zeros((2 - len(press.magnitudes_n), 3 * model.node_count))])
    return x, loaded.cable_tensions_n, lin.responses(rows)


def _continued(model: FEModel, controls: tuple[str, ...], target: np.ndarray,
               solved: list[tuple[np.ndarray, np.ndarray]]) -> Equilibrium:
    """The equilibrium at actuation `target`, from the nearest solved one by continuation
    (far corners of the box fold the body further than one Newton run from rest can go)."""
    try:
        return solve_by_continuation(model, controls, target, solved, ATTEMPT)
    except SolverError:
        raise SolverError(f"training could not reach actuation {np.round(target, 3).tolist()} "
                          "even in 8 steps; train a smaller box (--box-fraction 0.5 halves "
                          "each cable's range) or narrow the cables' [min, max] in the robot "
                          "file") from None


def save_training_set(path: Path, data: TrainingSet, key: str) -> None:
    """Cache snapshots (npz) under a key naming the model and the design they belong to."""
    arrays = {f.name: np.asarray(getattr(data, f.name)) for f in dataclasses.fields(data)}
    with atomic_path(path, force=True) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, key=np.array(key), **arrays)


def load_training_set(path: Path, key: str) -> TrainingSet | None:
    """The cached snapshots at `path` if they were made for `key`, else None."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            fields = {f.name: data[f.name] for f in dataclasses.fields(TrainingSet)}
    except (OSError, ValueError, KeyError):
        return None
    fields["max_force_n"] = float(fields["max_force_n"])
    return TrainingSet(**fields)


def sp_vstack_dense(sparse_rows, dense_rows: np.ndarray) -> np.ndarray:
    """Dense (k1 + k2, 3n) of sparse rows (k1, 3n) over dense rows (k2, 3n)."""
    return np.vstack([sparse_rows.toarray(), dense_rows])
