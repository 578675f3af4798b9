"""The table as evidence about the camera (diagnosis.background) against plane geometry worked
by hand: a camera 580 mm above the robot looking straight down, a table 617 mm from it."""

import json
from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.diagnosis.background import observed_table
from softforce_cli.diagnosis.fitting import Candidate, fit_values
from softforce_cli.diagnosis.hypotheses import FREE, Hypothesis, Inputs
from softforce_cli.diagnosis.observations import observe_recordings
from softforce_cli.diagnosis.residuals import Field
from softforce_cli.diagnosis.sensitivities import ColumnSet
from softforce_cli.model.effects import frame_contexts, make_effect
from softforce_cli.model.robot import load_robot

# p_robot = R p_cam + T: the sample scenes' camera, 580 mm above, looking down
CAMERA = RigidTransform(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 580.0]))
BODY = np.array([[-101.0, -101.0, -37.0], [101.0, 101.0, 126.0]])  # the Diamond's bounds
TABLE_DEPTH = 580.0 + 37.0


def _plane_at(height: float, slope_x: float = 0.0) -> tuple[np.ndarray, float]:
    """The plane z = height + slope_x x as (unit normal, offset)."""
    normal = np.array([-slope_x, 0.0, 1.0])
    scale = np.linalg.norm(normal)
    return normal / scale, -height / scale


def test_observed_table_is_its_height_over_the_footprint_above_the_robot_base():
    table = observed_table([_plane_at(-37.4), None, _plane_at(-37.6)], BODY, 0.5)
    np.testing.assert_allclose(table.observed_mm, -0.5, atol=1e-12)
    np.testing.assert_allclose(table.points_mm[:, 2], -37.0)
    assert table.points_mm[:, 0].min() == -101.0 and table.points_mm[:, 1].max() == 101.0
    tilted = observed_table([_plane_at(-37.0, 0.01)], BODY, 0.5)
    np.testing.assert_allclose(tilted.observed_mm, 0.01 * tilted.points_mm[:, 0], atol=1e-12)
    # 1 mm, plus a tenth of the offset seen: a camera effect refitted on the robot alone
    assert table.tolerance_mm == pytest.approx(1.05)
    assert observed_table([None], BODY, 0.5) is None
    assert observed_table([_plane_at(-137.0)], BODY, 50.0) is None  # a floor, not its table


def test_a_table_the_camera_did_not_move_is_not_the_robots():
    """A camera effect moves the robot about as far as the table: a table 29.9 mm below the
    robot's base beside a robot within 1.2 mm of its model is another surface (a robot
    clamped above its table), while the same table beside a robot 12 mm off is evidence (a
    depth scale of 5% moves both)."""
    assert observed_table([_plane_at(-66.9)], BODY, 1.2) is None
    assert observed_table([_plane_at(-66.9)], BODY, 12.0).observed_mm == pytest.approx(-29.9)
    assert observed_table([_plane_at(-40.0)], BODY, 1.2).observed_mm == pytest.approx(-3.0)
    assert observed_table([_plane_at(-42.0)], BODY, 1.2) is None  # 5 mm > 1 + 3 x 1.2


@pytest.mark.parametrize(("name", "values", "expected"), [
    ("depth_bias", {"scale": 0.01}, -0.01 * TABLE_DEPTH),  # seen 6.17 mm further away
    ("extrinsic_offset", {"translation_z_mm": 3.0}, 3.0),  # the camera 3 mm lower
    ("extrinsic_offset", {"translation_x_mm": 3.0}, 0.0),  # along the table
    ("extrinsic_offset", {"rotation_z_deg": 1.0}, 0.0),  # about its axis
    ("gravity", {"scale": 1.3}, 0.0),  # physics leaves the table alone
])
def test_table_shift_of_camera_effects(name, values, expected):
    table = observed_table([_plane_at(-37.0)], BODY, 0.5)
    shift = table.shift((make_effect(name, None, **values),), CAMERA)
    np.testing.assert_allclose(shift, expected, atol=1e-9)


def test_a_tilted_camera_tilts_the_table_by_its_angle():
    table = observed_table([_plane_at(-37.0)], BODY, 0.5)
    shift = table.shift((make_effect("extrinsic_offset", None, rotation_y_deg=0.5),), CAMERA)
    slope = np.polyfit(table.points_mm[:, 0], shift, 1)[0]
    assert abs(slope) == pytest.approx(np.tan(np.radians(0.5)), rel=1e-3)


def _camera_inputs(depth_scale: float) -> tuple[Inputs, Field]:
    """A flat patch of the robot 100 mm above the table (z = 63, 517 mm from the camera) and
    the table, both seen through a depth scale: the patch 5.17 mm and the table 6.17 mm
    further per percent, which no camera move reproduces."""
    grid = np.stack(np.meshgrid(np.linspace(-60, 60, 9), np.linspace(-60, 60, 9)), -1)
    positions = np.c_[grid.reshape(-1, 2), np.full(81, 63.0)]
    frames = 4
    field = Field(np.repeat(np.arange(frames), 81), np.tile(np.arange(81), frames),
                  np.tile(-depth_scale * (580.0 - 63.0), 81 * frames), np.full(81 * frames, 50.0))
    table = observed_table([_plane_at(-37.0 - depth_scale * TABLE_DEPTH)], BODY,
                           abs(depth_scale) * (580.0 - 63.0))
    contexts = tuple(frame_contexts(np.arange(frames) * 0.5, np.zeros((frames, 1))))
    count = len(field.frame)
    inputs = Inputs(field, np.zeros(count, dtype=int), np.tile([0.0, 0.0, 1.0], (count, 1)),
                    np.tile(positions, (frames, 1)), np.zeros((0, count)), ColumnSet(()),
                    contexts, (), CAMERA, np.zeros((1, 81, 3)), np.zeros((1, 0)),
                    np.zeros((1, 0, 81, 3)), table)
    return inputs, field


def _candidate(name: str) -> Candidate:
    free = FREE[name]
    return Candidate((Hypothesis(name, None, tuple(p for p, _, _ in free),
                                 np.zeros(len(free)), np.array([lo for _, lo, _ in free]),
                                 np.array([hi for _, _, hi in free])),))


def test_fitted_with_the_table_a_depth_scale_is_not_a_camera_move():
    inputs, field = _camera_inputs(0.01)
    depth = _candidate("depth_bias")
    values = fit_values(depth, inputs, field, relative=False)
    assert values[0] == pytest.approx(0.01, abs=1e-4)
    assert depth.table_misfit_mm(values, inputs) < 0.05
    move = _candidate("extrinsic_offset")
    values = fit_values(move, inputs, field, relative=False)
    # the best camera move splits the 1 mm difference between the patch and the table
    assert move.table_misfit_mm(values, inputs) > 0.3
    assert field.rms(shift=move.shift(values, inputs)) > 0.3


def test_every_frame_measures_the_table_and_the_planes_are_averaged():
    """Diagnosis fits the table in every frame (sensing reuses the first frame's plane, for
    speed): one frame's RANSAC plane tilts by its noise, 0.04-0.12 degrees on the sample's
    clean recording, which a camera's sideways move trades for a turn. The simulated table
    lies 0.5 mm under the clamp."""
    recording = Path("sample_data/recordings/diagnose_clean.mcap")
    camera = json.loads(recording.with_suffix("").with_suffix(".truth.json").read_text())["camera"]
    robot = load_robot("sample_data/diamond/diamond_p2.toml")
    pose = RigidTransform(np.array(camera["rotation"]), np.array(camera["translation_mm"]))
    observations = observe_recordings([recording], robot, pose, (0, 4))
    planes = [frame.table_plane for frame in observations.frames]
    assert len({round(offset, 9) for _, offset in planes}) == 4  # each frame its own fit
    averaged = observed_table(planes, robot.mesh.nodes_mm, 1.0)
    first = observed_table(planes[:1], robot.mesh.nodes_mm, 1.0)
    assert averaged.observed_mm.mean() == pytest.approx(-0.5, abs=0.1)
    assert np.ptp(averaged.observed_mm) < 0.8 * np.ptp(first.observed_mm)
