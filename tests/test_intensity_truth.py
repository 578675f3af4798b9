"""The intensity stage against an independent truth: the sample probes (sample_data/scenarios/
probes.toml), whose truth is the locking-free P2 body on its own 6.5 mm mesh with a
Neo-Hookean law, sensed by the coarse P2 robot (corotational, another mesh).

tests/data/probes_truth_features.json (benchmarks/intensity_fixture.py) holds where the
truth carries the estimator's feature points in each state and each probe's force: the
observations a perfect camera would give. The test feeds them to the estimator through its
own update loop (matching replaced by the truth along the current normals, the features
facing the sample's overhead camera only), with the contact at the surface node nearest to
the true material point, each state held two frames, and compares the intensities with the
truth's. This isolates the model of the contact force from the vision stage; the object's
axis comes from the probe's surface as the simulator renders it (sim.props.probe_surface).

The probe pushes along the bar's normal at rest; on the actuated, bent bar that is 10-16
degrees from the deformed normal, and a push constrained to the deformed normal read it
26-33% high (the bar is far stiffer along itself than across it). Pushing along the
probe's axis ("axis", the default) or within a friction cone ("cone") reads it right.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.estimation.sensing import ForceSensor
from softforce_cli.estimation.settings import EstimationSettings, SenseSettings
from softforce_cli.model.robot import load_robot
from softforce_cli.sim.props import probe_surface
from softforce_cli.vision.contacts import object_axes
from softforce_cli.vision.feature_matching import FeatureMatches

ROOT = Path(__file__).parents[1]
FIXTURE = ROOT / "tests" / "data" / "probes_truth_features.json"
# the sample probes' camera looks down from 580 mm above the base (probes.truth.json)
CAMERA_MM = np.array([0.0, 0.0, 580.0])
# a load is held over several camera frames; the state settles over the first two
HOLD_FRAMES = 2


def _truth_matches(sensor: ForceSensor, truth_mm: np.ndarray) -> FeatureMatches:
    """Perfect matches: the truth's feature points along the current normals, for the
    features facing the camera."""
    positions, normals = sensor.feature_geometry()
    facing = np.einsum("pi,pi->p", CAMERA_MM - positions, normals) > 0
    points = np.where(facing[:, None], truth_mm, np.nan)
    return FeatureMatches(facing, ~facing, np.zeros(len(facing), bool), points,
                          np.einsum("pi,pi->p", points, normals),
                          np.einsum("pi,pi->p", points - positions, normals),
                          np.zeros(len(facing)))


def _probe_points(contact: dict, count: int = 5000) -> np.ndarray:
    """Points spread evenly (by area) over the surface of the probe touching at a truth
    contact (its rod along the force), the probe's side facing up as the overhead camera
    sees it."""
    probe = probe_surface(np.array(contact["point_mm"]), np.array(contact["force_n"]),
                          (255, 0, 0))
    corners = probe.vertices_mm[probe.faces]  # (k, 3, 3)
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                   corners[:, 2] - corners[:, 0]), axis=1)
    rng = np.random.default_rng(0)
    face = rng.choice(len(area), count, p=area / area.sum())
    u, v = rng.random((2, count))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    points = corners[face, 0] + u[:, None] * (corners[face, 1] - corners[face, 0]) \
        + v[:, None] * (corners[face, 2] - corners[face, 0])
    axis = np.array(contact["force_n"]) / np.linalg.norm(contact["force_n"])
    along = (points - contact["point_mm"]) @ axis
    centre_line = np.array(contact["point_mm"]) + along[:, None] * axis
    return points[points[:, 2] >= centre_line[:, 2]]


def _sense(force_model: str) -> list[tuple[np.ndarray, np.ndarray]]:
    return sense_perfect_observations(json.loads(FIXTURE.read_text()), force_model)


def sense_perfect_observations(document: dict, force_model: str = "axis"
                               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(estimated, true) contact force magnitudes (N) of each loaded state of a fixture
    document (benchmarks/intensity_fixture.py), sensed by its estimator robot."""
    robot = load_robot(ROOT / document["estimator"])
    np.testing.assert_allclose(robot.mesh.nodes_mm[robot.feature_nodes],
                               document["feature_rest_mm"], atol=1e-4)
    frames = document["frames"]
    settings = SenseSettings(estimation=EstimationSettings(force_model=force_model,
                                                           updates_per_frame=6))
    sensor = ForceSensor(robot, RigidTransform(np.eye(3), np.zeros(3)),
                         np.array(frames[0]["actuation"]), settings, tare_frames=1)
    surface = robot.mesh.surface_nodes
    results = []
    for frame in frames:
        truth = np.array(frame["features_mm"])
        points = np.array([c["rest_point_mm"] for c in frame["contacts"]]).reshape(-1, 3)
        nearest = np.linalg.norm(robot.mesh.nodes_mm[surface][None] - points[:, None], axis=2)
        nodes = surface[np.argmin(nearest, axis=1)]
        axes = np.array([object_axes(np.array(c["point_mm"])[None], _probe_points(c))[0]
                         for c in frame["contacts"]]).reshape(-1, 3)
        for _ in range(1 if sensor.tare_left else HOLD_FRAMES):
            taring = sensor.tare_left > 0
            update = sensor.settle(_truth_matches(sensor, truth),
                                   lambda truth=truth: _truth_matches(sensor, truth), nodes,
                                   contact_axes=axes)
            if taring:
                sensor.add_tare(update)
        if not frame["contacts"]:
            continue
        estimated = np.array([np.linalg.norm(update.forces_n[g] @ update.columns.directions[g])
                              for g in update.columns.groups])
        results.append((estimated, np.linalg.norm([c["force_n"] for c in frame["contacts"]],
                                                  axis=1)))
    return results


def test_a_push_along_the_probes_axis_reads_the_true_intensities():
    """The default force model: 0.15 N and 0.25 N alone, and 0.25 N + 0.2 N on two bars in
    all, within 12% (measured with the robot file's 151 features: 0.150, 0.228, 0.246 +
    0.173 N; with 51: 0.150, 0.228, 0.252 + 0.164 N; the pair's second probe, on the west
    bar, reads low even with the true direction, and 0.244 N for 0.25 N with
    relinearize_mm = 0: the linearisation reused within 0.5 mm costs 7% there)."""
    assert EstimationSettings().force_model == "axis"
    results = _sense("axis")
    assert [len(e) for e, _ in results] == [1, 1, 2]
    for estimated, true in results:
        assert abs(estimated.sum() - true.sum()) / true.sum() < 0.12


@pytest.mark.bench
def test_the_friction_cone_reads_the_true_intensities():
    """0.15 N, 0.25 N and 0.25 N + 0.2 N within 10% each (measured with 151 features: 0.160,
    0.252, 0.274 + 0.201 N; with 51: 0.158, 0.250, 0.271 + 0.194 N)."""
    for estimated, true in _sense("cone"):
        np.testing.assert_array_less(np.abs(estimated - true) / true, 0.10)


@pytest.mark.bench
def test_a_push_along_the_deformed_normal_reads_high():
    """The cause the cone removes: the paper's push along the deformed normal reads the
    same observations 25% high or more on the single probes (measured with 151 features:
    0.203 N for 0.15 N, 0.336 N for 0.25 N; with 51: 0.195 and 0.328 N)."""
    for estimated, true in _sense("normal")[:2]:
        assert np.all(estimated / true > 1.2)
