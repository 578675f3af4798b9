"""`softforce calibrate` (paper section IV, Algorithm 1): transform and actuation from markers.

Two protocols. The paper's simulation (Table I) lets the estimation model generate the
markers: the fit must then be exact. The cross-model one generates them on the fine mesh
with a Neo-Hookean law (no inverse crime) and checks realistic error bounds, measured by
scripts/calibration_study.py (docs/calibration.md) and set here with margin.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from softforce_cli.calibration.actuation_qp import ActuationBounds, solve_actuation_qp
from softforce_cli.calibration.calibrate import CalibrationSettings, calibrate
from softforce_cli.calibration.markers_csv import markers_to_csv, parse_markers_csv
from softforce_cli.calibration.recording_markers import markers_from_recording, static_stretch
from softforce_cli.calibration.result import read_calibration, result_from_dict, result_to_dict
from softforce_cli.calibration.rigid import (
    RigidTransform,
    fit_rigid_transform,
    rigid_motion_projector,
    rotation_angle_deg,
    rotation_from_euler_deg,
)
from softforce_cli.calibration.robust import calibrate_checked
from softforce_cli.calibration.synthetic import (
    FIVE_MARKERS,
    PAPER_FORCES_N,
    observed_markers,
    overhead_transform,
    paper_transform,
    with_controls,
    with_law,
)
from softforce_cli.camera.frame import Markers
from softforce_cli.errors import CalibrationError
from softforce_cli.fem.statics import solve_equilibrium
from softforce_cli.model.robot import load_robot
from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT, SAMPLE_ROBOT, SAMPLE_ROBOT_FINE

DISPLACEMENT_MM = np.array([6.0, 2.0, 4.0, 9.0])
RECORDINGS = ROOT / "sample_data" / "recordings"


@pytest.fixture(scope="module")
def coarse(sample_robot):
    return sample_robot


@pytest.fixture(scope="module")
def coarse_truth(coarse):
    """Equilibrium of the estimation model itself for DISPLACEMENT_MM (paper's protocol)."""
    return solve_equilibrium(coarse.fe_model, coarse.cable_inputs(DISPLACEMENT_MM)).positions_mm


@pytest.fixture(scope="module")
def fine_truth(coarse):
    """The truth robot: fine mesh (~4x the tetrahedra), Neo-Hookean, the coarse file's
    markers and cables; and its equilibrium for DISPLACEMENT_MM."""
    robot = with_law(coarse, "neo-hookean", load_robot(SAMPLE_ROBOT_FINE).mesh)
    positions = solve_equilibrium(robot.fe_model, robot.cable_inputs(DISPLACEMENT_MM))
    return robot, positions.positions_mm


def transform_errors(result, truth: RigidTransform, actuation: np.ndarray):
    rotation = rotation_angle_deg(result.robot_from_camera.rotation.T @ truth.rotation)
    translation = np.linalg.norm(result.robot_from_camera.translation_mm - truth.translation_mm)
    return rotation, translation, np.abs(result.actuation - actuation).max()


# --- rigid transform -------------------------------------------------------------------------

def test_rigid_fit_recovers_a_known_pose():
    rng = np.random.default_rng(0)
    truth = RigidTransform(rotation_from_euler_deg([30.0, -50.0, 120.0]),
                           np.array([10.0, -400.0, 580.0]))
    source = rng.uniform(-100, 100, (9, 3))
    fitted = fit_rigid_transform(source, truth.apply(source))
    np.testing.assert_allclose(fitted.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(fitted.translation_mm, truth.translation_mm, atol=1e-9)
    np.testing.assert_allclose(fitted.inverse().apply(truth.apply(source)), source, atol=1e-9)


def test_rigid_fit_is_a_proper_rotation_for_mirrored_and_planar_points():
    rng = np.random.default_rng(1)
    source = rng.uniform(-50, 50, (6, 3))
    mirrored = source * np.array([1.0, 1.0, -1.0])  # no rotation maps one onto the other
    fitted = fit_rigid_transform(source, mirrored)
    assert np.linalg.det(fitted.rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(fitted.rotation.T @ fitted.rotation, np.eye(3), atol=1e-12)
    planar = source * np.array([1.0, 1.0, 0.0])  # coplanar points still fix the rotation
    turned = planar @ rotation_from_euler_deg([0.0, 0.0, 40.0]).T
    assert rotation_angle_deg(fit_rigid_transform(planar, turned).rotation) == pytest.approx(40)


def test_rigid_fit_rejects_collinear_points():
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        fit_rigid_transform(line, line + 1.0)


def test_rigid_motion_projector_removes_exactly_the_small_rigid_motions():
    rng = np.random.default_rng(4)
    points = rng.uniform(-80, 80, (9, 3))
    P = rigid_motion_projector(points)
    spin, shift = rng.normal(size=3), rng.normal(size=3)
    rigid = (np.cross(spin, points - points.mean(axis=0)) + shift).ravel()
    np.testing.assert_allclose(P @ rigid, 0.0, atol=1e-9)
    np.testing.assert_allclose(P @ P, P, atol=1e-12)
    assert np.trace(P) == pytest.approx(27 - 6)


def test_rotation_angle_keeps_small_angles():
    assert rotation_angle_deg(rotation_from_euler_deg([1e-7, 0, 0])) == pytest.approx(1e-7,
                                                                                     rel=1e-6)


# --- actuation QP ----------------------------------------------------------------------------

def _bounds(control, lower, upper):
    names = tuple(f"c{i}" for i in range(len(control)))
    return ActuationBounds(names, tuple(control), np.array(lower, float), np.array(upper, float))


def test_qp_without_active_bounds_is_least_squares():
    rng = np.random.default_rng(2)
    W = rng.normal(size=(27, 4))
    truth = np.array([1.0, 2.0, 0.5, 1.5])
    free = rng.normal(size=27)
    bounds = _bounds(["force"] * 4, [0] * 4, [10] * 4)
    solution = solve_actuation_qp(W, free, W @ truth + free, np.eye(4), np.zeros(4), bounds)
    np.testing.assert_allclose(solution.tensions_n, truth, atol=1e-12)


def test_qp_with_active_bounds_matches_cvxpy():
    """Mixed control: force bounds on lam, displacement bounds through eq. 4 (independent
    reference: the same problem modelled in cvxpy)."""
    cp = pytest.importorskip("cvxpy")
    rng = np.random.default_rng(3)
    W_ea, W_aa = rng.normal(size=(15, 4)), np.diag([2.0, 3.0, 1.5, 2.5])
    free, delta_free = rng.normal(size=15), np.array([-1.0, 0.5, -0.2, 0.1])
    target = W_ea @ np.array([3.0, -1.0, 4.0, 2.0]) + free  # asks for a push and a long pull
    bounds = _bounds(["force", "displacement", "force", "displacement"], [0, 0, 0, 0],
                     [2.0, 20.0, 10.0, 3.0])
    lam = cp.Variable(4)
    shortening = W_aa @ lam + delta_free
    constraints = [lam >= 0, lam[0] <= 2.0, lam[2] <= 10.0, shortening[1] >= 0,
                   shortening[1] <= 20, shortening[3] >= 0, shortening[3] <= 3.0]
    cp.Problem(cp.Minimize(cp.sum_squares(W_ea @ lam + free - target)), constraints).solve()
    solution = solve_actuation_qp(W_ea, free, target, W_aa, delta_free, bounds)
    np.testing.assert_allclose(solution.tensions_n, lam.value, atol=1e-5)
    assert not solution.bound_violation.any()


def test_qp_relaxes_and_reports_bounds_that_cannot_hold():
    # shortening = lam - 5 must reach [-10, -8] with lam >= 0: impossible by 3 mm
    bounds = _bounds(["displacement"], [-10.0], [-8.0])
    solution = solve_actuation_qp(np.eye(3, 1), np.zeros(3), np.ones(3), np.eye(1),
                                  np.array([-5.0]), bounds)
    assert solution.bound_violation[0] == pytest.approx(3.0, abs=1e-6)


def test_force_cable_that_could_only_push_is_rejected():
    with pytest.raises(CalibrationError, match="can only pull"):
        _bounds(["force"], [-2.0], [-1.0]).check()


# --- the paper's simulation protocol (Table I) -----------------------------------------------

@pytest.mark.parametrize("control", ["force", "displacement"])
@pytest.mark.parametrize("ids", [FIVE_MARKERS, None], ids=["5 markers", "9 markers"])
def test_table_one_protocol_is_recovered_exactly(coarse, coarse_truth, control, ids):
    """Paper Table I: residual 0.025 mm (5 markers) and 0.024 mm (9 markers); R, T and the
    actuation recovered to 3 digits. Here the same model generates and estimates."""
    if control == "force":
        robot, actuation = with_controls(coarse, ("force",) * 4, 0.0, 5.0), PAPER_FORCES_N
        positions = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation)).positions_mm
    else:
        robot, actuation, positions = coarse, DISPLACEMENT_MM, coarse_truth
    truth = paper_transform()
    result = calibrate(robot, observed_markers(robot, positions, truth, ids))
    assert result.converged
    assert result.residual_rms_mm <= 0.03
    transform = result.robot_from_camera
    assert np.abs(transform.rotation - truth.rotation).max() <= 1e-3
    assert np.linalg.norm(transform.translation_mm - truth.translation_mm) <= 1e-3 * (
        np.linalg.norm(truth.translation_mm))
    np.testing.assert_allclose(result.actuation, actuation, rtol=1e-3)


def test_mixed_control_is_calibrated_per_cable(coarse):
    robot = with_controls(coarse, ("displacement", "force", "displacement", "force"), 0.0, 20.0)
    actuation = np.array([5.0, 1.0, 3.0, 1.5])  # mm, N, mm, N
    positions = solve_equilibrium(robot.fe_model, robot.cable_inputs(actuation)).positions_mm
    result = calibrate(robot, observed_markers(robot, positions, overhead_transform()))
    np.testing.assert_allclose(result.actuation, actuation, rtol=1e-4)
    assert result.control == "mixed"
    assert result_to_dict(result)["actuation"]["controls"][1] == "force"


def test_a_robot_without_cables_is_calibrated(tmp_path):
    """A passive body (no [[cable]]): the pose alone, recovered from its markers at its own
    equilibrium under gravity; the actuation QP has no unknown (it had failed on reshaping
    its empty constraint rows, and the check of their relaxation on an empty array)."""
    text = SAMPLE_ROBOT.read_text().replace(
        'path = "diamond_coarse.vtu"', f'path = "{SAMPLE_ROBOT.parent / "diamond_coarse.vtu"}"')
    start, end = text.index("[[cable]]"), text.index("[features]")
    (tmp_path / "passive.toml").write_text(text[:start] + text[end:])
    robot = load_robot(tmp_path / "passive.toml")
    positions = solve_equilibrium(robot.fe_model, robot.cable_inputs(np.zeros(0))).positions_mm
    truth = paper_transform()
    result = calibrate(robot, observed_markers(robot, positions, truth))
    assert result.converged and result.residual_rms_mm <= 1e-3
    assert len(result.actuation) == 0
    transform = result.robot_from_camera
    assert rotation_angle_deg(transform.rotation.T @ truth.rotation) <= 1e-4
    assert np.linalg.norm(transform.translation_mm - truth.translation_mm) <= 1e-3


def test_paper_alternation_converges_more_slowly(coarse, coarse_truth):
    """Without the rigid projection (the paper's plain alternation of SVD and QP)."""
    observed = observed_markers(coarse, coarse_truth, paper_transform())
    projected = calibrate(coarse, observed)
    plain = calibrate(coarse, observed, CalibrationSettings(project_rigid=False,
                                                            outer_iterations=12))
    assert plain.residual_history_mm[-1] > 100 * projected.residual_rms_mm
    assert plain.residual_history_mm[-1] < plain.residual_history_mm[0]  # still descending


# --- cross-model truth, noise, outliers ------------------------------------------------------

def test_cross_model_truth_gives_a_realistic_fit(coarse, fine_truth):
    robot, positions = fine_truth
    truth = overhead_transform()
    result = calibrate(coarse, observed_markers(robot, positions, truth))
    rotation, translation, actuation = transform_errors(result, truth, DISPLACEMENT_MM)
    # measured (docs/calibration.md, section 2): 0.48 mm, 0.34 deg, 3.5 mm, 0.35 mm; the
    # translation error is mostly the rotation error times the 0.58 m lever arm to the camera
    assert result.residual_rms_mm < 1.0
    assert rotation < 1.0 and translation < 7.0 and actuation < 1.0
    assert not result.outliers


def test_marker_noise_keeps_errors_within_the_study_bounds(coarse, fine_truth):
    robot, positions = fine_truth
    truth = overhead_transform()
    observed = observed_markers(robot, positions, truth, sigma_mm=1.0,
                                rng=np.random.default_rng(7))
    result = calibrate(coarse, observed)
    rotation, translation, actuation = transform_errors(result, truth, DISPLACEMENT_MM)
    # bounds: about twice the 90th percentiles of docs/calibration.md, section 3 (fine truth,
    # sigma 1 mm: 1.48 deg, 14.8 mm, 2.03 mm, residual 1.81 mm)
    assert rotation < 3.0 and translation < 30.0 and actuation < 4.0
    assert 0.5 < result.residual_rms_mm < 3.6


@pytest.mark.parametrize("marker_id", ["bar_east", "elbow_north"])
def test_gross_outlier_is_flagged_and_excluded_with_robust(coarse, fine_truth, marker_id):
    robot, positions = fine_truth
    observed = observed_markers(robot, positions, overhead_transform())
    moved = observed.positions_mm.copy()
    moved[robot.marker_ids.index(marker_id)] += np.array([12.0, -9.0, 8.0])  # 17 mm
    bad = Markers(observed.ids, moved)
    reported = calibrate_checked(coarse, bad)
    assert reported.outliers == (marker_id,) and not reported.excluded
    assert any("outlier" in w for w in reported.warnings)
    excluded = calibrate_checked(coarse, bad, exclude_outliers=True)
    assert excluded.excluded == (marker_id,) and excluded.robust
    assert excluded.residual_rms_mm < 1.0  # back to the cross-model level
    flagged = next(m for m in excluded.markers if m.id == marker_id)
    assert flagged.left_out_mm > 10.0 and flagged.distance_mm > 10.0


# --- inputs: recording, CSV, bad markers, bounds ---------------------------------------------

def test_calibration_from_the_sample_recording(coarse):
    """markers.mcap: the locking-free truth (P2 on another mesh, Neo-Hookean; docs/scenarios.md)
    at rest for frames 0-1, markers with 0.5 mm noise; the camera pose and actuation are in
    its truth file. The coarse P1 model sags about half as much under gravity as that truth
    (docs/locking.md), so this is a fit with model error, like a real one."""
    taken = markers_from_recording(RECORDINGS / "markers.mcap")
    assert taken.frames == (0, 1)
    truth_file = json.loads((RECORDINGS / "markers.truth.json").read_text())
    camera = truth_file["camera"]
    truth = RigidTransform(np.array(camera["rotation"]), np.array(camera["translation_mm"]))
    result = calibrate(coarse, taken.markers)
    rotation, translation, actuation = transform_errors(
        result, truth, np.array(truth_file["frames"][0]["actuation"]["values"]))
    # measured: 2.55 mm, 0.06 deg, 4.0 mm, 0.00 mm (the former P1 fine truth: 2.20 mm,
    # 1.25 deg, 5.6 mm, 1.45 mm); bounds unchanged
    assert result.residual_rms_mm < 3.0
    assert rotation < 2.5 and translation < 12.0 and actuation < 3.0


def test_static_stretch_is_the_longest_still_run():
    still = np.zeros((10, 4, 3))
    still[3:] += 10.0   # moved after frame 2
    still[8:] += 10.0   # and again after frame 7
    assert static_stretch(still) == (3, 8)


def test_a_marker_missing_from_some_frames_neither_breaks_the_stretch_nor_is_lost(tmp_path):
    """The sample markers recording with its apex marker left out of every other frame (a
    tracker losing it): the still frames 0-1 are still averaged, with the apex from the frame
    that saw it. Before, frames of different marker sets were never averaged together and
    the calibration took frame 0 alone, without the apex (2 mm further off sideways)."""
    import dataclasses

    from softforce_cli.io.mcap_reader import iter_frames
    from softforce_cli.io.mcap_writer import write_recording

    frames = list(iter_frames(RECORDINGS / "markers.mcap"))
    full = [frame.markers for frame in frames]
    flickering = []
    for index, frame in enumerate(frames):
        keep = [k for k, marker in enumerate(frame.markers.ids)
                if marker != "apex" or index % 2]
        flickering.append(dataclasses.replace(frame, markers=Markers(
            tuple(frame.markers.ids[k] for k in keep), frame.markers.positions_mm[keep])))
    path = tmp_path / "flicker.mcap"
    write_recording(flickering, path)
    taken = markers_from_recording(path)
    assert taken.frames == (0, 1)
    assert set(taken.markers.ids) == set(full[0].ids)
    apex = full[1].ids.index("apex")
    found = dict(zip(taken.markers.ids, taken.markers.positions_mm, strict=True))
    np.testing.assert_allclose(found["apex"], full[1].positions_mm[apex])
    others = [k for k, marker in enumerate(full[0].ids) if marker != "apex"]
    np.testing.assert_allclose(
        [found[full[0].ids[k]] for k in others],
        (full[0].positions_mm[others] + full[1].positions_mm[others]) / 2)


def test_a_frame_sharing_no_marker_with_the_stretch_ends_it():
    still = np.zeros((6, 4, 3))
    still[2, :2] = np.nan   # frame 2 sees markers 2-3 only: the same stretch
    assert static_stretch(still) == (0, 6)
    still[:4, 3] = np.nan   # frames 0-3 never see marker 3 ...
    still[4, :3] = np.nan   # ... and frame 4 sees it alone: nothing to compare, a new run
    assert static_stretch(still) == (0, 4)


def test_markers_csv_round_trip():
    markers = Markers(("apex", "bar_east"), np.array([[1.0, 2.0, 3.0], [-4.5, 5.25, 580.0]]))
    parsed = parse_markers_csv("# observed by hand\n" + markers_to_csv(markers) + "\n")
    assert parsed.ids == markers.ids
    np.testing.assert_array_equal(parsed.positions_mm, markers.positions_mm)


@pytest.mark.parametrize(("text", "fragment"), [
    ("x,y,z\n", "header"),
    ("id,x_mm,y_mm,z_mm\n,1,2,3\n", "missing marker id"),
    ("id,x_mm,y_mm,z_mm\napex,1,nan,3\n", "y_mm of marker 'apex' is nan"),
    ("id,x_mm,y_mm,z_mm\napex,1,two,3\n", "not a number"),
    ("id,x_mm,y_mm,z_mm\napex,1,2\n", "3 fields"),
    ("id,x_mm,y_mm,z_mm\napex,1,2,3\napex,1,2,3\n", "appears twice"),
    ("id,x_mm,y_mm,z_mm\n", "no markers"),
])
def test_markers_csv_errors_name_the_line(text, fragment):
    with pytest.raises(CalibrationError, match=fragment):
        parse_markers_csv(text, "m.csv")


@pytest.mark.parametrize(("ids", "positions", "fragment"), [
    (("apex", "nose", "bar_east"), np.eye(3), "'nose' is not in"),
    (("apex", "bar_east"), np.eye(2, 3), "at least 3"),
    (("apex", "bar_east", "bar_west"), np.outer([1, 2, 3], [1.0, 0, 0]), "collinear"),
    (("apex", "bar_east", "bar_west"), [[0, 0, 0], [1, np.nan, 0], [0, 1, 0]], "non-finite"),
])
def test_bad_markers_fail_clearly(coarse, ids, positions, fragment):
    with pytest.raises(CalibrationError, match=fragment):
        calibrate(coarse, Markers(ids, np.asarray(positions, float)))


def test_bounds_that_cannot_hold_fail_clearly(coarse, coarse_truth):
    """Cables told to stay 10 mm longer than at rest: only pushing could do it."""
    robot = with_controls(coarse, ("displacement",) * 4, -12.0, -10.0)
    with pytest.raises(CalibrationError, match=r"bounds cannot hold.*'north'"):
        calibrate(robot, observed_markers(coarse, coarse_truth, overhead_transform()))


# --- output ----------------------------------------------------------------------------------

def test_result_json_round_trip(coarse, coarse_truth, tmp_path):
    result = calibrate(coarse, observed_markers(coarse, coarse_truth, overhead_transform(),
                                                FIVE_MARKERS))
    document = result_to_dict(result)
    for key in ("rotation", "translation_mm", "actuation", "residual_rms_mm",
                "residual_history_mm", "markers"):
        assert key in document
    assert document["unobserved"] == ["bar_north", "bar_west", "bar_south", "bar_east"]
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(document))
    again = read_calibration(path)
    np.testing.assert_array_equal(again.robot_from_camera.rotation,
                                  result.robot_from_camera.rotation)
    np.testing.assert_array_equal(again.actuation, result.actuation)
    assert result_to_dict(again)["markers"] == document["markers"]
    np.testing.assert_array_equal(again.pose_covariance, result.pose_covariance)
    with pytest.raises(CalibrationError, match="pose_covariance"):
        result_from_dict({**document, "pose_covariance": [[1.0, 2.0], [0.0, 1.0]]}, "x.json")
    with pytest.raises(CalibrationError, match="missing field"):
        result_from_dict({"rotation": np.eye(3).tolist()}, "x.json")


def test_cli_writes_calibration_table_and_plot(coarse, coarse_truth, tmp_path):
    markers = tmp_path / "markers.csv"
    markers.write_text(markers_to_csv(observed_markers(coarse, coarse_truth,
                                                       overhead_transform())))
    output, plot = tmp_path / "calib.json", tmp_path / "residual.png"
    args = ("calibrate", "--robot", SAMPLE_ROBOT, "--markers", markers, "-o", output,
            "--plot", plot)
    run = softforce(*args)
    assert run.returncode == 0, run.stderr
    assert "residual RMS" in run.stdout and "north" in run.stdout
    assert "pose uncertainty" in run.stdout
    document = json.loads(output.read_text())
    assert document["residual_rms_mm"] < 0.03
    # noise-free markers: the pose is as certain as the model's own rounding lets it be
    spread = np.sqrt(np.diag(document["pose_covariance"]))
    assert np.degrees(spread[:3]).max() < 0.02 and spread[3:].max() < 0.03
    np.testing.assert_allclose(document["actuation"]["values"], DISPLACEMENT_MM, rtol=1e-3)
    assert plot.stat().st_size > 1000
    assert_one_line_error(softforce(*args), "--force")


def test_cli_json_from_a_recording(tmp_path):
    run = softforce("calibrate", "--robot", SAMPLE_ROBOT, "--recording",
                    RECORDINGS / "markers.mcap", "--frame", "4", "-o", tmp_path / "c.json",
                    "--json")
    assert run.returncode == 0, run.stderr
    document = json.loads(run.stdout)
    assert "frame 4" in document["source"]
    assert document["actuation"]["control"] == "displacement"


def test_cli_bounds_that_cannot_hold_fail_with_one_line(coarse, coarse_truth, tmp_path):
    text = SAMPLE_ROBOT.read_text().replace('path = "', f'path = "{SAMPLE_ROBOT.parent}/')
    text = text.replace("min = 0.0", "min = -12.0").replace("max = 20.0", "max = -10.0")
    robot = tmp_path / "stretched.toml"
    robot.write_text(text)
    markers = tmp_path / "m.csv"
    markers.write_text(markers_to_csv(observed_markers(coarse, coarse_truth,
                                                       overhead_transform())))
    run = softforce("calibrate", "--robot", robot, "--markers", markers, "-o",
                    tmp_path / "c.json")
    assert_one_line_error(run, "bounds cannot hold")


@pytest.mark.parametrize(("csv", "extra", "fragment"), [
    ("id,x_mm,y_mm,z_mm\napex,0,0,450\nnose,0,1,450\nbar_east,1,0,450\n", (), "'nose'"),
    ("id,x_mm,y_mm,z_mm\napex,0,0,450\nbar_east,1,nan,450\nbar_west,1,0,450\n", (), "nan"),
    ("id,x_mm,y_mm,z_mm\napex,0,0,450\nbar_east,1,0,450\n", (), "at least 3"),
    ("id,x_mm,y_mm,z_mm\napex,0,0,450\n", ("--recording", "x.mcap"), "exactly one"),
])
def test_cli_bad_markers_fail_with_one_line(tmp_path, csv, extra, fragment):
    markers = tmp_path / "m.csv"
    markers.write_text(csv)
    run = softforce("calibrate", "--robot", SAMPLE_ROBOT, "--markers", markers, *extra,
                    "-o", tmp_path / "c.json")
    assert_one_line_error(run, fragment)
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize(("frame", "fragment"), [
    ("5", "markers.mcap holds 5 frames (0 to 4); --frame 5 is not one of them"),
    ("-1", "--frame -1: frames are counted from 0"),
])
def test_cli_frame_outside_the_recording_fails_with_one_line(tmp_path, frame, fragment):
    """A frame the recording does not hold is named as such (it was said to have no marker
    observations)."""
    run = softforce("calibrate", "--robot", SAMPLE_ROBOT, "--recording",
                    RECORDINGS / "markers.mcap", "--frame", frame, "-o", tmp_path / "c.json")
    assert_one_line_error(run, fragment)
    assert not (tmp_path / "c.json").exists()
