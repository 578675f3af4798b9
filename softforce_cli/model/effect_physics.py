"""The physics effects of model.effects entered into a robot's FE model.

- gravity: the body load's magnitude and direction;
- stiffness_scale: E x scale; viscoelastic_creep: E x creep_factor(hold) of the frame;
- regional_stiffness: E x scale on the elements of one region (model.regions), through
  FEModel.element_stiffness_scale;
- material_nonlinearity: the law blended with its other law (fem.blended_material);
- compliant_base: the clamp replaced by springs to the rest position (fem.supports);
- support_contact: a one-sided plane under the body (fem.supports).

Actuation and sensor effects do not change the FE model (model.effects).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import numpy as np

from softforce_cli.fem.blended_material import BlendedMaterial
from softforce_cli.fem.materials import Material
from softforce_cli.fem.model import FEModel
from softforce_cli.fem.supports import NodeSprings, SupportPlane
from softforce_cli.model.effects import Effect, FrameContext, creep_factor, effects_of_kind
from softforce_cli.model.mesh_io import rotation_from_euler_deg
from softforce_cli.model.regions import element_regions

# The other law of material_nonlinearity: the one a model with this law leaves out.
OTHER_LAW = {"corotational": "neo-hookean", "neo-hookean": "corotational",
             "linear": "neo-hookean"}
# Gravity of a robot file that has none, for the gravity effect to scale (mm/s^2, down).
STANDARD_GRAVITY_MM_S2 = np.array([0.0, 0.0, -9810.0])
# Penalty stiffness of the support plane per node, in units of E h (h the mean edge length):
# a node load f sinks it f / (100 E h) into the plane, about 1% of the elastic displacement
# the same load makes around that node, so the plane is rigid to about 1% while the tangent
# stays within two decades of the elastic one (Newton and Cholesky stay well conditioned).
CONTACT_PENALTY = 100.0
# Effects a reduced-order model represents: it reuses any E, and projects gravity anew.
REDUCIBLE = frozenset({"gravity", "stiffness_scale", "viscoelastic_creep"})


def fe_model_with_effects(robot, effects: Iterable[Effect],
                          context: FrameContext | None = None) -> FEModel:
    """The robot's full FE model without its file's effects, with the physics `effects`.

    `effects` is the whole list (the robot file's [[effect]] tables are not added); context
    is the frame's, for viscoelastic_creep (left out when None). The nominal model's
    geometry (shape gradients, sparsity pattern) is shared, not recomputed.
    """
    nominal = robot.nominal_fe_model
    physics = effects_of_kind(effects, "physics")
    if not physics:
        return nominal
    by_name = {e.name: e for e in physics if e.name != "regional_stiffness"}
    changes: dict = {}
    modulus = nominal.material.young_modulus_mpa
    if "stiffness_scale" in by_name:
        modulus *= by_name["stiffness_scale"]["scale"]
    if context is not None:
        modulus *= creep_factor(physics, context.hold_s)
    law, nu = nominal.material.law, nominal.material.poisson_ratio
    material = Material(law, modulus, nu)
    blend = by_name["material_nonlinearity"]["blend"] if "material_nonlinearity" in by_name else 0
    if blend == 1.0:
        material = Material(OTHER_LAW[law], modulus, nu)
    elif blend > 0.0:  # at 0 the other law is not evaluated: it may be undefined (inversion)
        material = BlendedMaterial(material, Material(OTHER_LAW[law], modulus, nu), blend)
    if material != nominal.material:
        changes["material"] = material
    if "gravity" in by_name:
        changes["gravity_mm_s2"] = effective_gravity(nominal.gravity_mm_s2, by_name["gravity"])
    regional = [e for e in physics if e.name == "regional_stiffness"]
    if regional:
        changes["element_stiffness_scale"] = element_stiffness_scale(robot, regional)
    supports = []
    base = by_name.get("compliant_base")
    if base is not None and math.isfinite(base["stiffness_n_per_mm"]):
        changes["fixed_nodes"], springs = base_springs(nominal, base["stiffness_n_per_mm"])
        supports.append(springs)
    contact = by_name.get("support_contact")
    if contact is not None and math.isfinite(contact["table_z_mm"]):
        supports.append(support_plane(nominal, changes.get("fixed_nodes", nominal.fixed_nodes),
                                      contact["table_z_mm"], modulus))
    if supports:
        changes["supports"] = tuple(supports)
    return _sharing_geometry(nominal, changes)


def effective_gravity(nominal_mm_s2: np.ndarray, effect: Effect) -> np.ndarray:
    """(3,) mm/s^2: the nominal gravity (standard gravity down when zero) times `scale`,
    turned about the robot's x by tilt_x_deg, then about its y by tilt_y_deg."""
    nominal = np.asarray(nominal_mm_s2, dtype=float)
    reference = nominal if np.any(nominal) else STANDARD_GRAVITY_MM_S2
    rotation = rotation_from_euler_deg((effect["tilt_x_deg"], effect["tilt_y_deg"], 0.0))
    return effect["scale"] * rotation @ reference


def element_stiffness_scale(robot, effects: Iterable[Effect]) -> np.ndarray:
    """(m,) modulus multiplier per element of regional_stiffness effects (1 elsewhere)."""
    regions = element_regions(robot)
    scale = np.ones(robot.mesh.tet_count)
    for effect in effects:
        scale[regions[effect.target]] *= effect["scale"]
    return scale


def base_springs(model: FEModel, total_n_per_mm: float) -> tuple[np.ndarray, NodeSprings]:
    """(fixed nodes left, springs): the clamped nodes that elements use are freed and tied to
    their rest positions by springs summing to total_n_per_mm, shared in proportion to the
    nodes' lumped volume (so the split does not depend on the element type)."""
    unused = np.setdiff1d(np.arange(model.node_count), model.tets)
    clamped = np.setdiff1d(model.fixed_nodes, unused)
    share = model.node_masses_kg[clamped] / model.node_masses_kg[clamped].sum()
    springs = NodeSprings(clamped, total_n_per_mm * share, model.rest_nodes_mm[clamped])
    return unused, springs


def support_plane(model: FEModel, fixed_nodes: np.ndarray, height_mm: float,
                  modulus_mpa: float) -> SupportPlane:
    """The plane z = height_mm under the free nodes that lie above it at rest (the part of
    the body below it at rest, such as a base through a hole in the plate, passes by)."""
    rest = model.rest_nodes_mm
    free = np.setdiff1d(np.arange(model.node_count), fixed_nodes)
    above = free[rest[free, 2] > height_mm]
    # edge of the regular tetrahedron of the mean corner-tet volume
    edge = (6.0 * math.sqrt(2.0) * float(np.mean(model.tet_volumes_mm3))) ** (1.0 / 3.0)
    return SupportPlane(above, float(height_mm), CONTACT_PENALTY * modulus_mpa * edge)


def _sharing_geometry(nominal: FEModel, changes: dict) -> FEModel:
    """dataclasses.replace, with the nominal's reference gradients and (same supports)
    sparsity pattern carried over instead of recomputed."""
    model = dataclasses.replace(nominal, **changes)
    shared = ["element", "_reference", "element_dofs", "tet_volumes_mm3"]
    if "fixed_nodes" not in changes:
        shared.append("pattern")
    for name in shared:
        getattr(nominal, name)  # computed once on the nominal model
        model.__dict__[name] = nominal.__dict__[name]
    return model


def reducible(effects: Iterable[Effect]) -> bool:
    """True when a reduced-order model trained without the physics effects represents them."""
    return all(e.name in REDUCIBLE for e in effects_of_kind(effects, "physics"))
