"""A robot: its mesh in the robot frame with supports, cables, feature points and markers.

`load_robot` reads a robot TOML and checks it against its mesh; `Robot.fe_model` is the
finite element model the estimators use, with the element type of `[mesh] element`, or the
reduced-order model of `[mesh] reduced` (with the element it was trained on). With P2
elements the FE model has more nodes than the mesh: the mesh's n nodes first, in their order,
then one per edge (`Robot.fe_mesh`), so positions[:n] of any FE configuration are the mesh's
nodes.

A robot file's `[[effect]]` tables (model.effects) enter here: the physics effects into
`full_fe_model` (creep, which needs frame times, excepted), cable slack into `cable_inputs`;
`nominal_fe_model` is the model without them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from softforce_cli.errors import ModelError
from softforce_cli.fem.attachment import Attachment, attach_points
from softforce_cli.fem.cables import Cable, CableInputs
from softforce_cli.fem.element import ElementMesh, element_mesh
from softforce_cli.fem.materials import Material
from softforce_cli.fem.model import FEModel, lumped_masses
from softforce_cli.fem.reduction.reduced_model import ReducedModel, Reduction
from softforce_cli.fem.reduction.rom_file import load_reduction, reduced_model
from softforce_cli.model.config import CableSpec, RobotConfig, load_config
from softforce_cli.model.effect_physics import fe_model_with_effects, reducible
from softforce_cli.model.effects import Effect, effects_of_kind, slack_actuation
from softforce_cli.model.features import face_nodes, nearest_surface_nodes, spread_surface_nodes
from softforce_cli.model.mesh import TetMesh
from softforce_cli.model.mesh_io import read_tet_mesh

# A cable point or marker may sit this far outside the mesh (surface faceting, a marker glued
# on the skin) before the file is considered wrong.
OUTSIDE_TOLERANCE_MM = 2.0
# kg/m^3 -> kg/mm^3.
KG_M3_TO_KG_MM3 = 1e-9


@dataclass(frozen=True)
class Robot:
    """Everything softforce knows about a robot, in the robot frame (mm).

    fixed_nodes    : (k,) clamped mesh nodes (inside a [[fixed]] box, or used by no element).
    feature_nodes  : (p,) surface nodes used as effectors (feature points); mesh nodes, which
                     are FE nodes of the same number for either element.
    marker_ids     : marker names, in file order; marker_points attaches them to the FE mesh.
    """

    config: RobotConfig
    mesh: TetMesh
    fixed_nodes: np.ndarray
    feature_nodes: np.ndarray
    marker_ids: tuple[str, ...]

    @property
    def name(self) -> str:
        return self.config.name

    @property
    def cable_specs(self) -> tuple[CableSpec, ...]:
        return self.config.cables

    @property
    def effects(self) -> tuple[Effect, ...]:
        """The robot file's [[effect]] tables (model.effects)."""
        return self.config.effects

    @cached_property
    def material(self) -> Material:
        spec = self.config.material
        return Material(spec.law, spec.young_modulus_mpa, spec.poisson_ratio)

    @cached_property
    def density_kg_mm3(self) -> float:
        spec = self.config.material
        if spec.density_kg_m3 is not None:
            return spec.density_kg_m3 * KG_M3_TO_KG_MM3
        return spec.total_mass_kg / self.mesh.volume_mm3

    @property
    def mass_kg(self) -> float:
        return self.density_kg_mm3 * self.mesh.volume_mm3

    @cached_property
    def reduction(self) -> Reduction | None:
        """The trained reduction of `[mesh] reduced`, or None."""
        path = self.config.mesh.reduced
        return None if path is None else load_reduction(path)

    @property
    def element_name(self) -> str:
        """The FE element: the reduced model's when `[mesh] reduced` is set (it was trained on
        that element), else `[mesh] element`."""
        return self.config.mesh.element if self.reduction is None else self.reduction.element

    @cached_property
    def fe_mesh(self) -> ElementMesh:
        """The FE nodes (the mesh's, then P2 mid-edge nodes) and elements of `element_name`."""
        return element_mesh(self.mesh.nodes_mm, self.mesh.tets, self.element_name)

    @property
    def rest_nodes_mm(self) -> np.ndarray:
        """(N, 3) rest positions of every FE node; the first mesh.node_count are the mesh's."""
        return self.fe_mesh.nodes_mm

    def attach(self, points_mm: np.ndarray) -> Attachment:
        """Attach points (p, 3) mm to the FE mesh, following its elements' shape functions."""
        return attach_points(self.fe_mesh.nodes_mm, self.fe_mesh.elements, points_mm)

    @cached_property
    def marker_points(self) -> Attachment:
        """The markers attached to the FE mesh, in marker_ids order."""
        positions = np.array([m.position_mm for m in self.config.markers]).reshape(-1, 3)
        return self.attach(positions)

    @cached_property
    def cables(self) -> tuple[Cable, ...]:
        nodes = self.rest_nodes_mm
        return tuple(
            Cable.through(spec.name, self.attach(spec.path_mm), spec.pull_point_mm, nodes)
            for spec in self.cable_specs
        )

    @cached_property
    def fe_model(self) -> FEModel | ReducedModel:
        """The model commands use: the reduced one when `[mesh] reduced` is set (ModelError
        when it was trained for another mesh or material) and represents the file's effects
        (model.effect_physics.reducible), else the full one."""
        if self.reduction is None or not reducible(self.effects):
            return self.full_fe_model
        return reduced_model(self.full_fe_model, self.reduction, self.config.mesh.reduced)

    @cached_property
    def full_fe_model(self) -> FEModel:
        """The full FE model of `element_name` with the file's physics effects (what a
        reduced model is trained on); the nominal model when it has none."""
        if not effects_of_kind(self.effects, "physics"):
            return self.nominal_fe_model
        return fe_model_with_effects(self, self.effects)

    @cached_property
    def nominal_fe_model(self) -> FEModel:
        """The full FE model of `element_name`, without the file's effects."""
        fe_mesh = self.fe_mesh
        return FEModel(
            rest_nodes_mm=fe_mesh.nodes_mm,
            tets=fe_mesh.elements,
            material=self.material,
            # P2: the mid-edge nodes of clamped edges too, so the same faces stay clamped
            fixed_nodes=fe_mesh.with_midside(self.fixed_nodes),
            node_masses_kg=lumped_masses(fe_mesh.nodes_mm, fe_mesh.elements,
                                         self.density_kg_mm3),
            gravity_mm_s2=np.asarray(self.config.material.gravity_mm_s2, dtype=float),
            cables=self.cables,
            element_name=fe_mesh.element.name,
        )

    @cached_property
    def feature_normals(self) -> np.ndarray:
        """(p, 3) outward unit normals at the feature points, rest shape."""
        return self.mesh.vertex_normals[self.feature_nodes]

    @property
    def marker_positions_mm(self) -> np.ndarray:
        """(k, 3) marker positions on the rest shape."""
        return self.marker_points.positions(self.rest_nodes_mm)

    def cable_inputs(self, values: np.ndarray) -> CableInputs:
        """Actuation values (a,) with each cable's control mode from the robot file, after
        the file's cable_slack effects (u - slack, not below 0)."""
        values = np.asarray(values, dtype=float)
        if values.shape != (len(self.cable_specs),):
            raise ModelError(f"{len(values)} actuation values for {len(self.cable_specs)} cables "
                             f"({', '.join(c.name for c in self.cable_specs)})")
        if self.effects:
            values = slack_actuation(self.effects, values, [c.name for c in self.cable_specs])
        return CableInputs(tuple(c.control for c in self.cable_specs), values)


def with_element(robot: Robot, element: str) -> Robot:
    """The same robot with `[mesh] element` replaced and no reduced model (what `model
    reduce` trains on)."""
    mesh = dataclasses.replace(robot.config.mesh, element=element, reduced=None)
    return Robot(dataclasses.replace(robot.config, mesh=mesh), robot.mesh, robot.fixed_nodes,
                 robot.feature_nodes, robot.marker_ids)


def robot_with_effects(robot: Robot, effects: tuple[Effect, ...]) -> Robot:
    """The same robot with its [[effect]] list replaced by `effects` (what robot.fitted.toml
    holds): its full_fe_model has their physics, its cable_inputs their slack."""
    config = dataclasses.replace(robot.config, effects=tuple(effects))
    return Robot(config, robot.mesh, robot.fixed_nodes, robot.feature_nodes, robot.marker_ids)


def load_robot(path: Path) -> Robot:
    """Read a robot TOML and its mesh; check the model against the mesh."""
    config = load_config(path)
    spec = config.mesh
    mesh = read_tet_mesh(spec.path, spec.scale, spec.rotation_deg, spec.translation_mm)
    return build_robot(config, mesh)


def build_robot(config: RobotConfig, mesh: TetMesh) -> Robot:
    source = config.source
    nodes = mesh.nodes_mm
    fixed = []
    for i, box in enumerate(config.fixed_boxes_mm):
        inside = np.all((nodes >= box[:3]) & (nodes <= box[3:]), axis=1)
        if not inside.any():
            raise ModelError(f"{source}: fixed[{i}] box {list(box)} catches no node; the mesh "
                             f"spans {np.round(mesh.bounds_mm, 1).tolist()} mm")
        fixed.append(np.flatnonzero(inside))
    unused = np.setdiff1d(np.arange(mesh.node_count), mesh.tets)
    fixed_nodes = np.unique(np.concatenate([*fixed, unused]))
    for cable in config.cables:
        _check_inside(mesh, np.array(cable.path_mm), f"cable {cable.name!r} path point", source)
    if config.feature_points_mm is not None:
        features, _ = nearest_surface_nodes(nodes, mesh.surface_nodes,
                                            np.array(config.feature_points_mm))
        features = np.unique(features)
    else:
        on_faces = face_nodes(nodes, mesh.surface_faces) \
            if config.feature_placement == "faces" else None
        features = spread_surface_nodes(nodes, mesh.surface_nodes, fixed_nodes,
                                        config.feature_count, among=on_faces)
    marker_positions = np.array([m.position_mm for m in config.markers]).reshape(-1, 3)
    _check_inside(mesh, marker_positions, "marker", source,
                  names=[m.id for m in config.markers])
    return Robot(
        config=config,
        mesh=mesh,
        fixed_nodes=fixed_nodes,
        feature_nodes=features,
        marker_ids=tuple(m.id for m in config.markers),
    )


def distance_outside_mm(mesh: TetMesh, points_mm: np.ndarray) -> np.ndarray:
    """(p,) how far each point lies outside the mesh (0 inside), to within a tet's size.

    Measured to the nearest point of its attachment tetrahedron's clamped barycentric image,
    which bounds the true distance from above.
    """
    attachment = attach_points(mesh.nodes_mm, mesh.tets, points_mm)
    clamped = np.clip(attachment.weights, 0.0, None)
    clamped /= clamped.sum(axis=1, keepdims=True)
    nearest = np.einsum("pa,pai->pi", clamped, mesh.nodes_mm[attachment.node_indices])
    return np.where(attachment.inside, 0.0, np.linalg.norm(points_mm - nearest, axis=1))


def _check_inside(mesh: TetMesh, points: np.ndarray, what: str, source: Path,
                  names: list[str] | None = None) -> None:
    if not len(points):
        return
    outside = distance_outside_mm(mesh, points)
    worst = int(np.argmax(outside))
    if outside[worst] > OUTSIDE_TOLERANCE_MM:
        label = f"{what} {names[worst]!r}" if names else what
        raise ModelError(f"{source}: {label} at {np.round(points[worst], 2).tolist()} mm is "
                         f"{outside[worst]:.1f} mm outside the mesh (tolerance "
                         f"{OUTSIDE_TOLERANCE_MM} mm); check its coordinates and the mesh "
                         "placement")
