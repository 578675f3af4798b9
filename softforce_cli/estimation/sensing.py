"""Force sensing, frame by frame (paper section V): where the robot is touched and how hard.

Per frame: the vision stage (softforce_cli.vision.pipeline) turns the depth image into robot
and object points, finds contacts where object points crowd robot points (Algorithm 2), puts
each at the surface node on the camera's line of sight through it (the paper: its nearest
feature point) and matches the feature points to the robot points along the current FE
surface normals (Algorithm 3). The FE model, linearised at its current
configuration, gives the normal compliance of eq. 10, and the QP of eq. 11-14 the contact
intensities with the cables' inputs as constraints. Eq. 6 then moves the FE configuration
towards the observed robot, and the next frame starts from there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.camera.frame import RgbdFrame, robot_actuation
from softforce_cli.errors import SensingError, SolverError
from softforce_cli.estimation.intensity import IntensityProblem, solve_intensities
from softforce_cli.estimation.linear_model import LinearizedModel
from softforce_cli.estimation.results import ContactEstimate, FrameEstimate
from softforce_cli.estimation.settings import SenseSettings
from softforce_cli.estimation.tracking import ContactTracker
from softforce_cli.fem.attachment import Attachment
from softforce_cli.fem.coordinates import State
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.mesh import vertex_normals
from softforce_cli.model.robot import Robot
from softforce_cli.vision.contacts import nearest_features, object_axes, touch_points
from softforce_cli.vision.feature_matching import FeatureMatches, match_features
from softforce_cli.vision.filters import crop_box_from_bounds
from softforce_cli.vision.pipeline import (
    Observation,
    match_observation,
    observe_frame,
)
from softforce_cli.vision.point_cloud import cloud_from_frame
from softforce_cli.vision.segmentation import Segmentation, learn_robot_colour
from softforce_cli.vision.settings import VisionSettings

# Matched features within this distance of a contact give its local fit residual (mm): about
# the spacing of 51 features on the Diamond.
LOCAL_RESIDUAL_RADIUS_MM = 30.0
# Without --tare, the sensor zeroes itself on this many first frames in which no contact is
# seen: the model and the body differ by about a millimetre at rest (P2, docs/locking.md),
# which untared reads as forces (the 12-location probes study: 55% median intensity error
# untared, 18% tared on 3 frames).
AUTO_TARE_FRAMES = 3
AXES = np.eye(3)
# A contact moves to another node only when its node lies this much further from the line
# of sight than the best node (contact_nodes): the centre found in the cloud moves by
# tenths of a millimetre from one frame to the next.
RELOCATE_MM = 1.0
# The surface nodes a contact may act at lie within this of the node nearest its centre
# (mm): about the coarse Diamond's surface node spacing.
CONTACT_REACH_MM = 8.0
# A known contact's point outside the body must lie within this of a surface node at rest
# (mm): the coarse Diamond's surface triangles have their centroids within 5.1 mm of one
# (3.8 mm median); a point further out is in other units or another frame, and its
# attachment would extrapolate an element.
KNOWN_CONTACT_REACH_MM = 10.0
# A contact that pushed more than HELD_MIN_N on the last frame and that this frame's vision
# does not find is held, at its node, while an object's points stay within HELD_OBJECT_MM of
# that node: a probe bending a bar into a fold hides its tip and the bar around it (a 0.3 N
# probe 30 mm deep: the probe's points 8 mm from the touch; docs/sensing_studies.md), and
# the object that pushed is still there. The QP gives it no force once the object has let
# go. 15 mm held a probe whose centre the vision had put 12 mm off, as a second contact.
HELD_MIN_N = 0.02
HELD_OBJECT_MM = 10.0


@dataclass(frozen=True)
class KnownContact:
    """A contact given by the user (the paper's Table III): rest_point_mm (3,) on the robot at
    rest, robot frame; direction (3,) unit direction of the force on the robot."""

    rest_point_mm: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class _Columns:
    """The contact force columns of one update: their attachment, directions (f, 3), which
    may only push, for each contact the columns that make up its force, and the (normal,
    tangent, tangent) columns (k, 3) of the contacts in a friction cone."""

    points: Attachment
    directions: np.ndarray
    unilateral: np.ndarray
    groups: tuple[np.ndarray, ...]
    cones: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=np.int64))


@dataclass(frozen=True)
class Update:
    matches: FeatureMatches
    columns: _Columns
    forces_n: np.ndarray
    residual_mm: np.ndarray


class ForceSensor:
    """The estimator's state between frames: the FE configuration, its cable tensions, the
    linearisation to reuse (estimation.linear_model), the robot's colour and the contact
    tracks.

    robot_from_camera maps camera points to robot points (calibration); start_actuation (a,)
    the calibrated cable inputs, in each cable's control units. relinearizations counts the
    linearisations made so far (what a frame costs most; benchmarks report it).
    """

    def __init__(
        self,
        robot: Robot,
        robot_from_camera: RigidTransform,
        start_actuation: np.ndarray,
        settings: SenseSettings,
        known_contact: KnownContact | None = None,
        robot_rgb: np.ndarray | None = None,
        tare_frames: int | None = 0,
    ) -> None:
        self.robot = robot
        self.model = robot.fe_model
        self.transform = robot_from_camera
        self.settings = settings
        self.known_contact = known_contact
        self.robot_rgb = None if robot_rgb is None else np.asarray(robot_rgb, dtype=float)
        self.features = Attachment.at_nodes(robot.feature_nodes)
        self.controls = tuple(spec.control for spec in robot.cable_specs)
        self.actuation = np.asarray(start_actuation, dtype=float)
        self.linear: LinearizedModel | None = None
        # the mesh's nodes: all the sensor looks at (surface, features, contacts); a reduced
        # model forms their positions alone (fem.coordinates State.nodes_mm)
        self.mesh_nodes = np.arange(robot.mesh.node_count)
        self._geometry_of: State | None = None
        self._geometry = (np.zeros((0, 3)), np.zeros((0, 3)))
        # the nodes the last frame's contacts acted at: the next frame's contacts start there
        self.placed_nodes = np.zeros(0, dtype=np.int64)
        # the nodes where the last frame's contacts pushed (held when not seen again)
        self.pushing_nodes = np.zeros(0, dtype=np.int64)
        self.restart()
        self.relinearizations = 0
        # the first frame's fit: the model's own offset from the robot (P1 locks: 10 mm and
        # more), which a lost model's fit is measured above
        self.first_fit_mm: float | None = None
        self.tracker = ContactTracker(settings.estimation.track_radius_mm)
        # taring: the first tare_frames processed frames are taken as free of external force,
        # and each feature's mean normal offset there (observed - model) is subtracted from
        # its later observations, as a force sensor is zeroed before use; None tares on the
        # first AUTO_TARE_FRAMES frames that show no contact, and stops at one that does;
        # a recording that starts touched is tared on the first frames it shows free (never
        # with a known contact: a weight may hang from the first frame)
        self.auto_tare = tare_frames is None and known_contact is None
        self.tare_left = AUTO_TARE_FRAMES if self.auto_tare else tare_frames or 0
        self.started_touched: bool | None = None  # with auto taring, once a frame is seen
        self._tare_sum = np.zeros(len(robot.feature_nodes))
        self._tare_count = np.zeros(len(robot.feature_nodes))
        clamped = robot.mesh.nodes_mm[robot.fixed_nodes]
        self.clamped_box = np.r_[clamped.min(axis=0), clamped.max(axis=0)]
        self.table_plane: tuple[np.ndarray, float] | None = None
        # the crop box observe() uses: the mesh's bounds where the last process() left it
        self.crop_bounds_mm = self._bounds()
        if known_contact is not None:
            point = np.asarray(known_contact.rest_point_mm, dtype=float)[None]
            self.known_points = robot.attach(point)
            surface = robot.mesh.nodes_mm[robot.mesh.surface_nodes]
            gap = float(np.linalg.norm(surface - point, axis=1).min())
            if not self.known_points.inside.all() and gap > KNOWN_CONTACT_REACH_MM:
                raise SensingError(
                    f"the known contact's point {np.round(point[0], 2).tolist()} mm is "
                    f"outside the robot, {gap:.0f} mm from its surface at rest; give a point on "
                    "the robot, in the robot frame and in mm")

    def restart(self) -> None:
        """Move the FE configuration to the unloaded equilibrium at the current actuation
        (where sensing starts, and starts again when it has lost the robot)."""
        start = solve_equilibrium(self.model, self.robot.cable_inputs(self.actuation))
        self.state: State = start.state
        self.tensions = start.cable_tensions_n
        self.linear = None

    def mesh_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """(m, 3) mm positions and (m, 3) outward unit normals (zero inside) of the robot
        mesh's nodes at the configuration, computed once per configuration (matching, force
        columns and reports all need them)."""
        if self._geometry_of is not self.state:
            positions = self.state.nodes_mm(self.mesh_nodes)
            self._geometry = (positions, vertex_normals(positions, self.robot.mesh.surface_faces))
            self._geometry_of = self.state
        return self._geometry

    def node_normals(self) -> np.ndarray:
        """(m, 3) outward unit normals of the mesh's nodes at the configuration."""
        return self.mesh_geometry()[1]

    def feature_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """Feature positions (p, 3) mm and outward unit normals (p, 3) at the configuration."""
        features = self.robot.feature_nodes
        positions, normals = self.mesh_geometry()
        return positions[features], normals[features]

    def attached_mm(self, points: Attachment) -> np.ndarray:
        """(p, 3) mm: the positions of attached points at the configuration."""
        nodes = np.unique(points.node_indices)
        positions = np.zeros((self.model.node_count, 3))
        positions[nodes] = self.state.nodes_mm(nodes)
        return points.positions(positions)

    def process(self, index: int, frame: RgbdFrame,
                observation: Observation | None = None) -> FrameEstimate:
        """Estimate the contacts of one frame and move the FE configuration to it, from the
        frame's observation when it was made ahead (observe()), else observing it here."""
        try:
            return self._process(index, frame, observation)
        finally:
            self.crop_bounds_mm = self._bounds()

    def _process(self, index: int, frame: RgbdFrame,
                 observation: Observation | None) -> FrameEstimate:
        timings: dict[str, float] = {}
        time_s = frame.time_ns * 1e-9
        if frame.actuation is not None:
            self.actuation = robot_actuation(frame.actuation, self.robot.cable_specs,
                                             f"frame {index}")
        if self.robot_rgb is None:
            self.robot_rgb = learned_robot_colour(frame, self.transform, self.mesh_geometry()[0],
                                                  self.robot.mesh.surface_nodes,
                                                  self.settings.vision)
        positions, normals = self.feature_geometry()
        vision = match_observation(observation or self.observe(frame), positions, normals)
        timings.update({k: v for k, v in vision.timings_ms.items() if k != "total"})
        segmentation = vision.segmentation
        counts = dict(points_kept=len(vision.cloud), robot_points=len(segmentation.robot),
                      object_points=len(segmentation.objects))
        if not len(vision.cloud):
            return FrameEstimate(index, time_s, "nodepth", timings_ms=timings, **counts)
        if len(segmentation.robot) < self.settings.estimation.min_robot_points:
            return FrameEstimate(index, time_s, "norobot", timings_ms=timings, **counts)
        touched = self.auto_tare and len(vision.contacts.centres_mm) > 0
        if self.started_touched is None and self.auto_tare:
            self.started_touched = touched
        if touched and not self.started_touched:
            self.tare_left = 0  # the robot was seen free first, and is touched now: tared
        # a recording that starts touched is tared on the first frames it shows free
        taring = self.tare_left > 0 and not touched
        detected = vision.contacts if not taring and self.known_contact is None else None
        centres = np.zeros((0, 3)) if detected is None else detected.centres_mm
        sighted = None if detected is None else ~detected.occluded
        if detected is not None:
            centres, sighted = self._with_held(centres, sighted, segmentation)
        self.pushing_nodes = np.zeros(0, dtype=np.int64)
        contact_nodes, axes, relocate = self.placement(
            centres, self._contact_axes(centres, segmentation), sighted)
        clock = _Clock(timings)
        saved = (self.state, self.tensions)
        try:
            outcome = self.settle(vision.matches, lambda: self._match(segmentation),
                                  contact_nodes, clock, axes, relocate, taring)
        except SolverError:
            self.state, self.tensions = saved
            self.linear = None
            return FrameEstimate(index, time_s, "solver", timings_ms=timings, **counts)
        if outcome is None:
            return FrameEstimate(index, time_s, "fewmatches", timings_ms=timings, **counts)
        fit_rms_mm = float(np.sqrt(np.mean(outcome.residual_mm**2)))
        if self.first_fit_mm is None:
            self.first_fit_mm = fit_rms_mm
        if fit_rms_mm > self.first_fit_mm + self.settings.estimation.lost_fit_mm:
            try:
                self.restart()
            except SolverError:
                self.state, self.tensions = saved
                self.linear = None
            return FrameEstimate(index, time_s, "lost", timings_ms=timings, **counts,
                                 fit_rms_mm=fit_rms_mm)
        if taring:  # a frame whose fit diverged (lost) does not join the tare
            self.add_tare(outcome)
        status = "tare" if taring else "ok"
        contacts = () if taring else self._contacts(outcome, centres, sighted,
                                                    segmentation.robot_tree)
        clock.lap("update")
        matches = outcome.matches
        return FrameEstimate(
            index, time_s, status, contacts, **counts,
            features_matched=int(matches.matched.sum()),
            features_hidden=int(matches.hidden.sum()),
            features_rejected=int(matches.rejected.sum()),
            fit_rms_mm=fit_rms_mm,
            cable_tensions_n=self.tensions.copy(), timings_ms=timings,
        )

    def settle(self, matches: FeatureMatches, rematch: Callable[[], FeatureMatches],
               contact_nodes: np.ndarray, clock: _Clock | None = None,
               contact_axes: np.ndarray | None = None,
               relocate: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
               taring: bool | None = None) -> Update | None:
        """One frame's FE updates from its first matches at the current configuration:
        update, then rematch() at the moved configuration and update again, up to
        updates_per_frame times, stopping once an update moved no feature point more than
        rematch_mm. Contact forces act at the mesh nodes contact_nodes (c,) (or at the known
        contact), with force_model "axis" along contact_axes (c, 3) where not NaN (the
        pushing object's axis), both given again by relocate() at the moved configuration
        when given; while taring (the frame is a tare frame; None: while tare frames are
        left) there are none, and the caller adds the frame to the tare (add_tare) once its
        fit is judged. Returns the last update, or None when too few features match (the
        configuration is then that of the updates made)."""
        clock = clock or _Clock({})
        taring = self.tare_left > 0 if taring is None else taring
        outcome: Update | None = None
        for _ in range(self.settings.estimation.updates_per_frame):
            if outcome is not None:
                matches = rematch()
                if relocate is not None:
                    # a contact is where the moved surface is nearest it: a probe that
                    # lands between frames sits millimetres inside the surface the frame
                    # started from, nearer another part of the body there
                    contact_nodes, contact_axes = relocate()
                clock.lap("matching")
            matched_at = self.feature_geometry()[0]
            update = self.update(matches, contact_nodes, clock, taring, contact_axes)
            if update is None:
                break
            outcome = update
            moved = np.linalg.norm(self.feature_geometry()[0] - matched_at,
                                   axis=1).max(initial=0.0)
            if moved <= self.settings.estimation.rematch_mm:
                break  # matching again would find the same points: the frame is done
        return outcome

    def observe(self, frame: RgbdFrame) -> Observation:
        """The frame's vision stages that need no feature geometry (vision.pipeline
        observe_frame), in the crop box of the configuration the last process() left and the
        table found before. Once the robot's colour is known (after the first process()),
        another thread may call this for the next frame while process() runs: it reads
        nothing process() changes but crop_bounds_mm, which process() replaces whole."""
        if self.robot_rgb is None:
            raise RuntimeError("observe() before the first process(): the robot's colour is "
                               "not known yet")
        # the camera is fixed to the table (its pose is calibrated): the table found on one
        # frame is the table of the next
        observation = observe_frame(frame.depth_mm, frame.color, frame.intrinsics,
                                    self.transform, self.crop_bounds_mm, self.robot_rgb,
                                    self.settings.vision, self.clamped_box, self.table_plane)
        self.table_plane = observation.table_plane
        return observation

    def _bounds(self) -> np.ndarray:
        """(2, 3) mm [min, max] of the mesh at the configuration."""
        nodes = self.mesh_geometry()[0]
        return np.array([nodes.min(axis=0), nodes.max(axis=0)])

    def _match(self, segmentation: Segmentation) -> FeatureMatches:
        positions, normals = self.feature_geometry()
        return match_features(positions, normals, segmentation.robot.points_mm,
                              self.settings.vision, camera_mm=self.transform.translation_mm,
                              robot_tree=segmentation.robot_tree)

    def _contact_axes(self, centres_mm: np.ndarray, segmentation: Segmentation) -> np.ndarray:
        """(c, 3) the axis of the object pushing at each contact centre (c, 3)
        (vision.contacts.object_axes; NaN where it has none, and not computed unless
        force_model is "axis")."""
        if self.settings.estimation.force_model != "axis" or not len(centres_mm):
            return np.full((len(centres_mm), 3), np.nan)
        return object_axes(centres_mm, segmentation.objects.points_mm)

    def placement(self, centres_mm: np.ndarray, axes: np.ndarray,
                  sighted: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, Callable[[], tuple[np.ndarray, np.ndarray]]]:
        """The distinct nodes (k,) where the contacts at centres_mm (c, 3) act at the
        current configuration, the axes (k, 3) of the contacts (axes (c, 3)) they were first
        found for, and the callable that places them again on the surface an update moved
        (settle's relocate); the nodes are contact_nodes', sighted (c,) bool (None: all)
        the contacts that are not hidden tips (vision.contacts.occluded_tips: already on the
        robot's surface, placed by distance). A contact starts from the node of the last
        frame's contacts nearest it, kept within the same margin, so that a held contact
        keeps its node from frame to frame (fewer FE linearisations: 74 against 78 on the
        12-location probes at 1280x720)."""
        placed = self._contact_nodes(centres_mm, self._carried(centres_mm), sighted, axes)

        def relocate() -> tuple[np.ndarray, np.ndarray]:
            nonlocal placed
            placed = self._contact_nodes(centres_mm, placed, sighted, axes)
            self.placed_nodes = placed
            return _acting(placed, axes)

        self.placed_nodes = placed
        return (*_acting(placed, axes), relocate)

    def _with_held(self, centres_mm: np.ndarray, sighted: np.ndarray,
                   segmentation: Segmentation) -> tuple[np.ndarray, np.ndarray]:
        """The detected contact centres (c, 3) and their sighted flags (c,), with the last
        frame's pushing nodes that held_contacts keeps appended, not sighted (a hidden
        contact, placed at the node by distance)."""
        if not len(self.pushing_nodes):
            return centres_mm, sighted
        pushing = self.mesh_geometry()[0][self.pushing_nodes]
        held = held_contacts(pushing, centres_mm, segmentation.objects.points_mm,
                             self.settings.estimation.track_radius_mm)
        return (np.vstack([centres_mm, pushing[held]]),
                np.concatenate([sighted, np.zeros(int(held.sum()), dtype=bool)]))

    def _carried(self, centres_mm: np.ndarray) -> np.ndarray | None:
        """(c,) for each contact centre (c, 3), the node of the last frame's contacts
        nearest it at the configuration; None when the last frame had none."""
        if not len(self.placed_nodes) or not len(centres_mm):
            return None
        carried = self.mesh_geometry()[0][self.placed_nodes]
        _, nearest = cKDTree(carried).query(centres_mm)
        return self.placed_nodes[np.asarray(nearest, dtype=np.int64)]

    def _contact_nodes(self, centres_mm: np.ndarray, placed: np.ndarray | None = None,
                       sighted: np.ndarray | None = None,
                       axes: np.ndarray | None = None) -> np.ndarray:
        """(c,) the mesh node where each contact at centres_mm (c, 3) acts at the current
        configuration (contact_nodes: the surface node on the camera's line of sight
        through it where sighted (c,), the nearest elsewhere, on a face the object's axis
        (c, 3) can push), or with contact_at = "feature" the paper's nearest feature point;
        placed (c,) the nodes before, kept within the margin."""
        if not len(centres_mm):
            return np.zeros(0, dtype=np.int64)
        positions, normals = self.mesh_geometry()
        if self.settings.estimation.contact_at == "feature":
            return self.robot.feature_nodes[
                nearest_features(centres_mm, positions[self.robot.feature_nodes])]
        return contact_nodes(centres_mm, self.transform.translation_mm, positions, normals,
                             self.robot.mesh.surface_nodes, placed, sighted, axes,
                             self.settings.estimation.max_axis_angle_deg)

    @property
    def tare_offsets_mm(self) -> np.ndarray:
        """(p,) mean observed-minus-model normal offset of each feature over the tare frames
        (0 where a feature was never matched, or without taring)."""
        return np.divide(self._tare_sum, self._tare_count, out=np.zeros_like(self._tare_sum),
                         where=self._tare_count > 0)

    def add_tare(self, update: Update) -> None:
        """Join a tare frame's last update to the tare: its features' observed-minus-model
        normal offsets at the settled configuration."""
        matched = update.matches.matched
        positions, normals = self.feature_geometry()
        model = np.einsum("pi,pi->p", positions, normals)
        self._tare_sum[matched] += update.matches.normal_mm[matched] - model[matched]
        self._tare_count[matched] += 1
        self.tare_left -= 1

    def _columns(self, contact_nodes: np.ndarray, taring: bool = False,
                 axes: np.ndarray | None = None) -> _Columns:
        """Force columns for the contacts: along the inward normal (one push each), the known
        direction, the inward normal and two tangents in a friction cone ("cone"), or three
        free axes per contact ("3d"); none while taring."""
        if self.known_contact is not None and not taring:
            direction = np.asarray(self.known_contact.direction, dtype=float)[None]
            return _Columns(self.known_points, direction, np.ones(1, bool), (np.arange(1),))
        c = len(contact_nodes)
        if self.settings.estimation.force_model == "3d":
            points = Attachment.at_nodes(np.repeat(contact_nodes, 3))
            groups = tuple(np.arange(3 * i, 3 * i + 3) for i in range(c))
            return _Columns(points, np.tile(AXES, (c, 1)), np.zeros(3 * c, bool), groups)
        inward = -self.node_normals()[contact_nodes]
        if self.settings.estimation.force_model == "cone":
            points = Attachment.at_nodes(np.repeat(contact_nodes, 3))
            directions = np.concatenate([inward[:, None], tangent_basis(inward)], axis=1)
            cones = np.arange(3 * c).reshape(c, 3)
            return _Columns(points, directions.reshape(-1, 3), np.zeros(3 * c, bool),
                            tuple(cones), cones)
        if self.settings.estimation.force_model == "axis" and axes is not None:
            inward = pushing_directions(inward, axes, self.settings.estimation.max_axis_angle_deg)
        groups = tuple(np.array([i]) for i in range(c))
        return _Columns(Attachment.at_nodes(contact_nodes), inward, np.ones(c, bool), groups)

    def update(self, matches: FeatureMatches, contact_nodes: np.ndarray,
               clock: _Clock | None = None, taring: bool = False,
               contact_axes: np.ndarray | None = None) -> Update | None:
        """One FE update (eq. 10-14, then eq. 6) from feature matches at the current
        configuration, with contact forces at the mesh nodes contact_nodes (c,) (or at the
        known contact); None when too few features match for the unknowns."""
        clock = clock or _Clock({})
        _, normals = self.feature_geometry()
        columns = self._columns(contact_nodes, taring, contact_axes)
        matched = matches.matched
        unknowns = len(self.controls) + len(columns.directions)
        if matched.sum() < max(self.settings.estimation.min_matched, unknowns + 1):
            return None
        linear = self._linearized()
        node_count = self.model.node_count
        responses = linear.force_responses(columns.points, columns.directions)
        effector_rows = self.features.subset(matched).directional_rows(normals[matched],
                                                                        node_count)
        projected = linear.compliance(effector_rows, responses)
        clock.lap("fe")
        problem = IntensityProblem(
            projected.W_ea, projected.W_ef, projected.delta_e_free,
            matches.normal_mm[matched] - (0.0 if taring else self.tare_offsets_mm[matched]),
            projected.W_aa, projected.W_af,
            projected.delta_a_free, columns.unilateral, columns.cones,
            self.settings.estimation.friction_coefficient,
        )
        solution = solve_intensities(problem, self.controls, self.actuation,
                                     self.settings.estimation.regularization)
        clock.lap("qp")
        # eq. 6 at the linearisation x0: x <- x0 + dx_free + K0^-1 (H_a^T lam_a + H_f^T lam_f)
        self.state = linear.configuration(solution.cable_tensions_n, responses,
                                          solution.contact_forces_n)
        self.tensions = solution.cable_tensions_n
        clock.lap("update")
        return Update(matches, columns, solution.contact_forces_n, solution.residual_mm)

    def _linearized(self) -> LinearizedModel:
        """The linearisation to use at the current configuration: the cached one while the
        configuration is within relinearize_mm of where it was made, else a new one here
        (K and the internal forces at the current x: a Newton step)."""
        linear = self.linear
        tolerance = self.settings.estimation.relinearize_mm
        if linear is None or linear.moved_mm(self.mesh_geometry()[0]) > tolerance:
            self.linear = linear = LinearizedModel(
                self.model, self.state, self.tensions,
                factorization=None if linear is None else linear.factorization,
                watched_nodes=self.mesh_nodes)
            self.relinearizations += 1
        return linear

    def _contacts(self, update: Update, centres_mm: np.ndarray, sighted: np.ndarray | None,
                  robot_tree: cKDTree) -> tuple[ContactEstimate, ...]:
        """The update's contacts, each reported where the camera's line of sight through
        its centre meets the observed skin (vision.contacts.touch_points) where sighted
        (c,) bool (None: every contact), else at its node; centres_mm (c, 3): the detected
        contacts the update placed (none for a known contact), robot_tree the frame's robot
        points. The force acts at the node either way."""
        columns = update.columns
        points = self.attached_mm(columns.points)
        feature_positions, _ = self.feature_geometry()
        matched_positions = feature_positions[update.matches.matched]
        positions = np.array([points[group[0]] for group in columns.groups]).reshape(-1, 3)
        nodes = columns.points.node_indices[[group[0] for group in columns.groups], 0]
        if len(centres_mm):
            # the first contact centre placed on each group's node
            placed = nodes[:, None] == self.placed_nodes[None]
            centre = placed.argmax(axis=1)
            seen = placed.any(axis=1) & (True if sighted is None else sighted[centre])
            touches = touch_points(centres_mm[centre], self.transform.translation_mm,
                                   robot_tree, positions)
            positions = np.where(seen[:, None], touches, positions)
        indices = self.tracker.assign(positions)
        features = nearest_features(positions, feature_positions)
        estimates, pushing = [], []
        for i, group in enumerate(columns.groups):
            vector = update.forces_n[group] @ columns.directions[group]
            if len(centres_mm) and np.linalg.norm(vector) > HELD_MIN_N:
                pushing.append(nodes[i])
            near = np.linalg.norm(matched_positions - positions[i], axis=1) \
                <= LOCAL_RESIDUAL_RADIUS_MM
            local = update.residual_mm[near] if near.any() else update.residual_mm
            estimates.append(ContactEstimate(
                int(indices[i]), int(features[i]), positions[i], vector,
                float(np.sqrt(np.mean(local**2))),
            ))
        self.pushing_nodes = np.array(pushing, dtype=np.int64)
        return tuple(estimates)


class _Clock:
    """Accumulates the wall time between laps into timings[stage] (ms): a stage met twice in
    a frame (several FE updates) adds up."""

    def __init__(self, timings: dict[str, float]) -> None:
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + 1e3 * (now - self.last)
        self.last = now


def contact_nodes(centres_mm: np.ndarray, camera_mm: np.ndarray, positions_mm: np.ndarray,
                  normals: np.ndarray, surface_nodes: np.ndarray,
                  placed: np.ndarray | None = None,
                  sighted: np.ndarray | None = None,
                  axes: np.ndarray | None = None,
                  max_axis_angle_deg: float = 60.0) -> np.ndarray:
    """(c,) the surface node under each contact centre (c, 3) mm, seen from the camera at
    camera_mm (3,): among the surface nodes within CONTACT_REACH_MM of the centre's nearest
    that face the camera, the one nearest the line of sight through the centre.

    A contact's centre is the mean of the object points the camera sees touching the robot,
    and the object hides the touch itself: on the 12-location probes the true contact lay
    5.4 mm (median) further along the line of sight and 1.0 mm across it (4.7 and 1.0 mm
    with the camera oblique, benchmarks/scenarios/oblique_camera.toml). The surface node
    nearest the centre in space was then often one beside the contact, on a bar's edge, and
    a point force's dent under a node moved the contact to a neighbour on every other frame;
    along the line of sight a dent changes nothing. placed (c,): the contacts' nodes before
    (the last update's, or the last frame's), each kept while it faces the camera, within
    the reach, and no more than RELOCATE_MM further from the line than the best. sighted
    (c,) bool, default all: contacts that are not (a hidden tip found on the robot's
    surface, maybe on a side the camera does not face) take the node nearest in space,
    under the same margin. positions_mm, normals (m, 3): the mesh's nodes and outward unit
    normals.

    axes (c, 3), NaN where unknown: the axis of the object pushing at each contact
    (vision.contacts.object_axes). Where known, only the nodes whose inward normal lies
    within max_axis_angle_deg of it are candidates, if any are: a rod pressing a face
    cannot push a side face beside it. On a finger seen obliquely, a probe pressing the top
    face 6 mm from its edge was otherwise placed on the side face below the edge (the line
    of sight through the touch meets it first before the push has bent the model), where
    its force, along that face's normal, could not dent the top: 0.2 N read 0-0.1 N on two
    frames, three with the camera calibrated from markers (docs/sensing_studies.md,
    "Other robots")."""
    surface = positions_mm[surface_nodes]
    tree = cKDTree(surface)
    nearest_mm, _ = tree.query(centres_mm)
    sight = centres_mm - np.asarray(camera_mm, dtype=float)
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    axes = np.full((len(centres_mm), 3), np.nan) if axes is None else np.asarray(axes, float)
    min_cosine = np.cos(np.radians(max_axis_angle_deg))
    chosen = np.empty(len(centres_mm), dtype=np.int64)
    for k, reach in enumerate(tree.query_ball_point(centres_mm, nearest_mm + CONTACT_REACH_MM)):
        reach = np.asarray(reach, dtype=np.int64)
        if np.isfinite(axes[k]).all():
            pushable = -normals[surface_nodes[reach]] @ axes[k] >= min_cosine
            reach = reach[pushable] if pushable.any() else reach
        if sighted is not None and not sighted[k]:  # by the distance in space
            candidates = reach
            distance_mm = np.linalg.norm(surface[reach] - centres_mm[k], axis=1)
        else:
            candidates = reach[normals[surface_nodes[reach]] @ sight[k] < 0.0]
            if not len(candidates):  # seen edge-on: the nearest node
                candidates = reach[[np.argmin(np.linalg.norm(surface[reach] - centres_mm[k],
                                                             axis=1))]]
            offset = surface[candidates] - centres_mm[k]  # by the distance from the line
            distance_mm = np.linalg.norm(offset - np.outer(offset @ sight[k], sight[k]), axis=1)
        nodes = surface_nodes[candidates]
        chosen[k] = nodes[np.argmin(distance_mm)]
        if (placed is not None and placed[k] in nodes
                and distance_mm[nodes == placed[k]][0] <= distance_mm.min() + RELOCATE_MM):
            chosen[k] = placed[k]
    return chosen


def held_contacts(pushing_mm: np.ndarray, centres_mm: np.ndarray, objects_mm: np.ndarray,
                  same_mm: float) -> np.ndarray:
    """(k,) bool: which of the last frame's pushing contacts at pushing_mm (k, 3) hold on
    this frame, unseen: no contact centre (c, 3) within same_mm of it (the vision found it
    again: the tracker's radius, within which a contact is the same one), and an object
    point (n, 3) within HELD_OBJECT_MM (the object that pushed is still there)."""
    pushing = np.asarray(pushing_mm, dtype=float).reshape(-1, 3)
    objects = np.asarray(objects_mm, dtype=float).reshape(-1, 3)
    if not len(pushing) or not len(objects):
        return np.zeros(len(pushing), dtype=bool)
    held = np.isfinite(cKDTree(objects).query(pushing, distance_upper_bound=HELD_OBJECT_MM)[0])
    centres = np.asarray(centres_mm, dtype=float).reshape(-1, 3)
    if len(centres):
        held &= np.linalg.norm(pushing[:, None] - centres[None], axis=2).min(axis=1) > same_mm
    return held


def _acting(placed: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) the distinct nodes of the contacts' nodes `placed` (c,), and (k, 3) the axes
    (c, 3) of the contacts they were first found for."""
    nodes, first = np.unique(placed, return_index=True)
    return nodes, axes[first]


def pushing_directions(inward: np.ndarray, axes: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """(c, 3) the direction of each contact's push: its object's axis (c, 3) where known and
    within max_angle_deg of the inward normal (c, 3), else the inward normal."""
    inward = np.asarray(inward, dtype=float).reshape(-1, 3)
    axes = np.asarray(axes, dtype=float).reshape(-1, 3)
    cosine = np.einsum("ij,ij->i", np.nan_to_num(axes), inward)
    usable = np.isfinite(axes).all(axis=1) & (cosine >= np.cos(np.radians(max_angle_deg)))
    return np.where(usable[:, None], np.nan_to_num(axes), inward)


def tangent_basis(normals: np.ndarray) -> np.ndarray:
    """(c, 2, 3) two unit tangents orthogonal to each other and to each unit normal (c, 3)."""
    normals = np.asarray(normals, dtype=float).reshape(-1, 3)
    # cross with the axis least aligned with the normal: never a near-zero product
    axis = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    first = np.cross(normals, axis)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return np.stack([first, np.cross(normals, first)], axis=1)


def learned_robot_colour(frame: RgbdFrame, robot_from_camera: RigidTransform,
                         nodes_mm: np.ndarray, surface_nodes: np.ndarray,
                         vision: VisionSettings) -> np.ndarray:
    """(3,) RGB of the robot: the colour of the frame's points near the model's surface."""
    bounds = np.array([nodes_mm.min(axis=0), nodes_mm.max(axis=0)])
    cloud = cloud_from_frame(frame.depth_mm, frame.color, frame.intrinsics, robot_from_camera,
                             crop_box_from_bounds(bounds, vision.crop_margin_mm))
    return np.asarray(learn_robot_colour(cloud, nodes_mm[surface_nodes]), dtype=float)
