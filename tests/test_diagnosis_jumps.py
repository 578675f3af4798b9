"""Jumps within holds (diagnosis.jumps): frames whose robot points moved from the frame
before's, the inputs held, far more than in the recording's other holds.

The clouds are samplings of the coarse Diamond's surface with the camera's noise: each
frame draws its own points, as a camera's frames do; the study's recordings are in
docs/diagnosis.md (the creep_0.5 body tipping over is found, creep_0.3's drift is not).
"""

from __future__ import annotations

import numpy as np
import pytest

from softforce_cli.diagnosis.jumps import JUMP_FACTOR, cloud_gap_mm, jumps_in_holds
from softforce_cli.diagnosis.observations import FrameObservation
from softforce_cli.model.robot import load_robot
from tests.conftest import ROOT

POINTS = 6000  # a frame's points, as diagnosis keeps (observations.MAX_POINTS_PER_FRAME)
NOISE_MM = 0.5


@pytest.fixture(scope="module")
def surface():
    """(nodes (n, 3) mm, outward triangles (k, 3)) of the coarse Diamond at rest."""
    mesh = load_robot(ROOT / "sample_data" / "diamond" / "diamond.toml").mesh
    return mesh.nodes_mm, mesh.surface_faces


def sampled(surface, rng, shape=lambda p: p) -> np.ndarray:
    """(POINTS, 3) mm: points drawn uniformly by area on the surface moved by `shape`."""
    nodes, faces = surface
    corners = shape(nodes)[faces]
    areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                    corners[:, 2] - corners[:, 0]), axis=1)
    chosen = rng.choice(len(faces), POINTS, p=areas / areas.sum())
    u, v = rng.random((2, POINTS))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    a, b, c = np.moveaxis(corners[chosen], 1, 0)
    return a + u[:, None] * (b - a) + v[:, None] * (c - a) + NOISE_MM * rng.standard_normal(
        (POINTS, 3))


def frame(index: int, actuation: tuple, points: np.ndarray, recording: int = 0
          ) -> FrameObservation:
    return FrameObservation(index, recording, 0.5 * index, np.array(actuation, float), points,
                            points[:, 2].copy(), np.zeros((0, 3)), None)


def sag(millimetres: float):
    """A shape: the body sinks, in proportion to height, by `millimetres` at its top."""
    def moved(nodes):
        top = nodes[:, 2].max()
        return nodes - np.outer(nodes[:, 2] / top * millimetres, [0, 0, 1])
    return moved


def tipped(nodes):
    """The body turned over about the x axis through its base (as a Diamond tipping)."""
    return nodes * np.array([1, -1, -1])


def test_the_gap_of_two_parallel_grids_is_their_distance():
    """Two grids of 2 mm spacing 5 mm apart: every nearest point lies straight across."""
    x, y = np.meshgrid(np.arange(0, 40, 2.0), np.arange(0, 40, 2.0))
    grid = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    assert cloud_gap_mm(grid, grid) == 0.0
    assert cloud_gap_mm(grid, grid + np.array([0, 0, 5.0])) == pytest.approx(5.0)


def test_a_tip_over_in_a_hold_is_a_jump_and_creep_drift_is_not(surface):
    """Holds of a standing body, one of them creeping (the top sinks 6 mm, as the study's
    creep_0.5 body's apex in its first held frame), then the body tipped in a hold: only
    the tip is reported, with the typical gap of the holds."""
    rng = np.random.default_rng(3)
    still = [frame(i, (0, 0), sampled(surface, rng)) for i in range(4)]
    crept = frame(4, (0, 0), sampled(surface, rng, sag(6.0)))
    pulled = [frame(5, (5, 0), sampled(surface, rng, sag(8.0))),
              frame(6, (5, 0), sampled(surface, rng, sag(8.0)))]
    fallen = frame(7, (5, 0), sampled(surface, rng, tipped))
    jumps = jumps_in_holds([*still, crept, *pulled, fallen])
    assert [jump.frame for jump in jumps] == [7]
    typical = cloud_gap_mm(still[0].points_mm, still[1].points_mm)
    assert jumps[0].typical_mm == pytest.approx(typical, rel=0.2)
    assert jumps[0].moved_mm > 3 * JUMP_FACTOR * jumps[0].typical_mm


def test_a_move_of_the_inputs_is_no_jump_and_each_recording_has_its_own_holds(surface):
    """The body tipping while its inputs change is the inputs' doing; a second recording's
    holds are judged apart, and a recording with fewer than three holds is not judged."""
    rng = np.random.default_rng(4)
    first = [frame(0, (0, 0), sampled(surface, rng)), frame(1, (0, 0), sampled(surface, rng)),
             frame(2, (0, 0), sampled(surface, rng)), frame(3, (0, 0), sampled(surface, rng)),
             frame(4, (5, 0), sampled(surface, rng, tipped))]
    second = [frame(0, (0, 0), sampled(surface, rng), 1),
              frame(1, (0, 0), sampled(surface, rng, tipped), 1)]
    assert jumps_in_holds(first + second) == []
    second += [frame(2, (0, 0), sampled(surface, rng, tipped), 1),
               frame(3, (0, 0), sampled(surface, rng, tipped), 1)]
    assert [(jump.recording, jump.frame) for jump in jumps_in_holds(first + second)] == [(1, 1)]
