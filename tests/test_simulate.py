"""`softforce simulate`: scenarios, ground truth, and the sample recordings staying current."""

from __future__ import annotations

import json
import re
import warnings
from collections import defaultdict
from pathlib import Path

import meshio
import numpy as np
import pytest

from softforce_cli.errors import ScenarioError, SolverError
from softforce_cli.io.mcap_reader import (
    frames_from_messages,
    iter_frames,
    open_recording,
    read_summary,
    recording_messages,
)
from softforce_cli.model.robot import load_robot, with_element
from softforce_cli.model.structured import box_mesh
from softforce_cli.sim import ground_truth
from softforce_cli.sim.ground_truth import hook_region
from softforce_cli.sim.scenario import HOOK_RADIUS_MM, load_scenario
from softforce_cli.sim.simulate import SnapThroughWarning, simulate
from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT

SCENARIOS = ROOT / "sample_data" / "scenarios"
RECORDINGS = ROOT / "sample_data" / "recordings"


# States of each sample scenario that the tests solve again: the truth (P2 on 8.7k tets)
# costs 12 s to minutes of CPU per state, so the first two (an actuation, then a load or
# another actuation) stand for the rest, which use the same code. About 3 minutes of CPU
# for this file in all.
STATES = 2
# The truth states each sample scenario's tests solve, shared between them: the noise-free
# test solves the markers scenario's first states again otherwise (simulate's states cache,
# keyed by the frame; one per scenario).
TRUTH_STATES: dict[str, dict] = defaultdict(dict)


def scenario_prefix(name: str, states: int, folder: Path, noise: bool = True) -> Path:
    """A copy of sample scenario `name` with its first `states` [[frame]] blocks only."""
    text = (SCENARIOS / f"{name}.toml").read_text()
    head, *frames = text.split("\n[[frame]]")
    text = "\n[[frame]]".join([head, *frames[:states]]) + "\n"
    text = text.replace('robot = "../', f'robot = "{SCENARIOS.parent}/')
    if not noise:
        text = text.replace("[camera]", "[camera]\nnoise = false")
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["markers", "weights", "probes"])
def test_sample_recordings_are_reproduced_by_their_scenarios(name, tmp_path):
    """The committed sample data cannot drift from the code that makes it (its first frames:
    the noise is drawn frame by frame, so a prefix of the scenario gives a prefix of it)."""
    result = simulate(scenario_prefix(name, STATES, tmp_path), tmp_path / f"{name}.mcap",
                      states=TRUTH_STATES[name])
    committed = json.loads((RECORDINGS / f"{name}.truth.json").read_text())
    fresh = json.loads(result.truth.read_text())
    assert fresh["truth_model"] == committed["truth_model"]
    assert fresh["truth_model"]["element"] == "p2"  # the locking-free truth, weights included
    assert len(fresh["frames"]) == result.frames < len(committed["frames"])
    for old, new in zip(committed["frames"], fresh["frames"], strict=False):  # a prefix
        assert new["actuation"] == old["actuation"]
        np.testing.assert_allclose(new["cable_tensions_n"], old["cable_tensions_n"], atol=1e-5)
        for c_old, c_new in zip(old["contacts"], new["contacts"], strict=True):
            np.testing.assert_allclose(c_new["point_mm"], c_old["point_mm"], atol=1e-3)
            np.testing.assert_allclose(c_new["force_n"], c_old["force_n"], atol=1e-6)
    recorded = zip(iter_frames(RECORDINGS / f"{name}.mcap"), iter_frames(result.recording),
                   strict=False)
    for old, new in recorded:
        assert new.time_ns == old.time_ns
        # rounding of the depth may flip where the geometry differs in the last bits
        changed = np.abs(new.depth_mm.astype(int) - old.depth_mm.astype(int))
        assert np.mean(changed > 1) < 1e-3
        assert np.mean(np.abs(new.color.astype(int) - old.color.astype(int)) > 2) < 1e-3


def test_noise_free_depth_agrees_with_the_truth_geometry(tmp_path):
    """Project the apex marker (on the top surface) into the image: the depth there is its z."""
    quiet = scenario_prefix("markers", STATES, tmp_path, noise=False)
    result = simulate(quiet, tmp_path / "quiet.mcap", states=TRUTH_STATES["markers"])
    truth = json.loads(result.truth.read_text())
    for frame, recorded in zip(truth["frames"], iter_frames(result.recording), strict=True):
        x, y, z = frame["markers"]["apex"]["camera_mm"]
        k = recorded.intrinsics
        u, v = round(k.fx * x / z + k.cx), round(k.fy * y / z + k.cy)
        assert abs(int(recorded.depth_mm[v, u]) - z) <= 1.0  # 1 mm quantisation
        # the robot is blue there (its colour is distinct from the table and the probes)
        assert blue(recorded.color[v : v + 1, u : u + 1])[0, 0]


def test_a_lens_that_distorts_is_rendered_and_read_back_rectified(tmp_path):
    """A scenario's [camera] distortion renders each pixel along the ray the lens maps it to
    and writes the lens in camera_info; read back, the frames are the pinhole camera's
    (tests/test_lens.py for the models): the same scene as without the lens, but for pixels
    by the edges (nearest-pixel resampling) and beyond the raw image's border."""
    pinhole = scenario_prefix("markers", STATES, tmp_path, noise=False)
    text = pinhole.read_text().replace(
        "[camera]", '[camera]\nlook_at_mm = [200.0, 140.0, 40.0]\ndistortion_model = '
        '"plumb_bob"\ndistortion = [-0.12, 0.04, 0.0008, -0.0006]')
    lens = tmp_path / "lens.toml"
    lens.write_text(text)
    pinhole.write_text(text.replace("distortion = [", "distortion = [0, 0, 0, 0] # ["))
    lensed = simulate(lens, tmp_path / "lens.mcap", states=TRUTH_STATES["markers"])
    plain = simulate(pinhole, tmp_path / "pinhole.mcap", states=TRUTH_STATES["markers"])
    assert read_summary(lensed.recording).intrinsics.distortion.coefficients == (
        -0.12, 0.04, 0.0008, -0.0006, 0.0)
    truth = json.loads(lensed.truth.read_text())["camera"]["intrinsics"]["distortion"]
    assert truth == {"model": "plumb_bob", "coefficients": [-0.12, 0.04, 0.0008, -0.0006, 0.0]}
    for got, want in zip(iter_frames(lensed.recording), iter_frames(plain.recording),
                         strict=True):
        assert got.intrinsics == want.intrinsics
        same = np.abs(got.depth_mm.astype(int) - want.depth_mm.astype(int)) <= 1
        robot = blue(want.color)  # its slopes change by more than 1 mm in half a pixel
        assert same.mean() > 0.99 and same[robot].mean() > 0.95
    # as recorded, the lens moves the robot by pixels: most of its depths change
    with open_recording(lensed.recording) as recording:
        raw = next(frames_from_messages(lensed.recording, recording_messages(recording, {})))
    want = next(iter_frames(plain.recording))
    assert raw.intrinsics.distortion is not None
    moved = np.abs(raw.depth_mm.astype(int) - want.depth_mm.astype(int)) > 1
    robot = blue(want.color)
    assert moved[robot].mean() > 0.3  # 0.60: against 0.03 rectified


def blue(color: np.ndarray) -> np.ndarray:
    """(h, w) where an image (h, w, 3) shows the sample robot's blue."""
    r, g, b = np.moveaxis(color.astype(int), -1, 0)
    return (b > r + 60) & (b > g + 40)


def test_markers_are_observed_with_the_requested_noise():
    truth = json.loads((RECORDINGS / "markers.truth.json").read_text())
    errors = np.array(
        [
            np.subtract(m["observed_camera_mm"], m["camera_mm"])
            for frame in truth["frames"]
            for m in frame["markers"].values()
        ]
    )
    assert errors.std() == pytest.approx(0.5, rel=0.25)  # scenario: sigma_mm = 0.5
    frames = list(iter_frames(RECORDINGS / "markers.mcap"))
    observed = frames[0].markers.positions_mm
    expected = [m["observed_camera_mm"] for m in truth["frames"][0]["markers"].values()]
    np.testing.assert_allclose(observed, expected, atol=1e-4)


def test_truth_stays_out_of_the_recording():
    summary = read_summary(RECORDINGS / "probes.mcap")
    assert summary.metadata["softforce"]["scenario"] == "probes.toml"
    raw = (RECORDINGS / "probes.mcap").read_bytes()
    assert b"force_n" not in raw and b"contacts" not in raw


def test_weights_make_the_apex_sink_monotonically():
    truth = json.loads((RECORDINGS / "weights.truth.json").read_text())
    loaded = [f for f in truth["frames"] if f["contacts"]]
    heights = [f["contacts"][0]["point_mm"][2] for f in loaded]
    forces = [f["contacts"][0]["magnitude_n"] for f in loaded]
    # the paper's Table III, with 0.96 for its 1.06 N (docs/scenarios.md: the truth buckles)
    assert forces == pytest.approx([0.26, 0.46, 0.66, 0.76, 0.86, 0.96])
    assert np.all(np.diff(heights) < 0)
    # and ever faster: the locking-free body softens on its way to buckling near 1 N
    compliance = -np.diff(heights) / np.diff(forces)  # mm/N between successive weights
    assert np.all(np.diff(compliance) > 0) and compliance[-1] > 1.5 * compliance[0]


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('law = "neo-hookean"', 'law = "rubber"', "law 'rubber' unknown"),
        ("[camera]", "[camera]\nzoom = 2", "unknown key 'zoom' in [camera]"),
        ('robot = "../diamond_truth/diamond.toml"', 'robot = "../nothere.toml"', "not found"),
        ("actuation = [0.0, 0.0, 0.0, 0.0]", "actuation = [0.0, 0.0]", "2 actuation values"),
        # no pose follows from these cameras (a look_at ValueError's traceback before)
        ("[camera]", "[camera]\nposition_mm = [0, 0, 580]\nlook_at_mm = [0, 0, 580]",
         "camera: eye and target are the same point"),
        ("[camera]", "[camera]\nup_hint = [0, 0, 1]", "camera: up_hint is parallel"),
        ("[camera]", "[camera]\nhorizontal_fov_deg = 190", "must be below 180"),
        # a depth stream the D415 does not have (its minimum range would hide the robot)
        ("width = 424\nheight = 240", "width = 1920\nheight = 1080",
         "measures depth at 1280x720 at most"),
        ("[camera]", "[scene]\nambient = 1.5\n[camera]", "scene.ambient must be in [0, 1]"),
        ("[camera]", "[scene]\nlight_direction = [0, 0, 0]\n[camera]",
         "scene.light_direction must not be zero"),
        ("[camera]", "[scene]\nspecular = 2\n[camera]", "scene.specular must be in [0, 1]"),
        ("publish = true", "publish = true\nsticker_rgb = [300, 0, 0]",
         "markers.sticker_rgb must be 3 integers in 0..255"),
        ("[camera]", '[camera]\ndistortion_model = "fisheye62"\ndistortion = [0.1]',
         "camera.distortion: distortion model 'fisheye62' is not one softforce knows"),
        ("[camera]", "[camera]\ndistortion = [0.1, 0, 0, 0, 0, 0.2]",
         "camera.distortion: distortion model plumb_bob takes 5 coefficients"),
        ("[camera]", '[camera]\ndistortion = "strong"', "camera.distortion must be an array"),
    ],
)
def test_bad_scenarios_give_one_clear_line(tmp_path, old, new, message):
    text = (SCENARIOS / "markers.toml").read_text()
    assert old in text
    text = text.replace(old, new, 1).replace('robot = "../', f'robot = "{SCENARIOS.parent}/')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    result = softforce("simulate", path, "-o", tmp_path / "bad.mcap")
    assert_one_line_error(result, message)
    assert not (tmp_path / "bad.mcap").exists()


def test_load_needs_a_force_or_a_mass(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        'robot = "r.toml"\n[[frame]]\nload = [{kind = "weight", point_mm = [0, 0, 0]}]\n'
    )
    with pytest.raises(ScenarioError, match=re.escape("needs exactly one of force_n, mass_g")):
        load_scenario(path)


@pytest.mark.parametrize("load, message", [
    ('{kind = "probe", point_mm = [0, 0, 0], force_n = 0.1, hook_radius_mm = 2}',
     "hook_radius_mm is for weights only"),
    ('{kind = "weight", point_mm = [0, 0, 0], force_n = 0.1, hook_radius_mm = -1}',
     "hook_radius_mm must be >= 0"),
])
def test_hook_radius_is_checked(tmp_path, load, message):
    path = tmp_path / "s.toml"
    path.write_text(f'robot = "r.toml"\n[[frame]]\nload = [{load}]\n')
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)


@pytest.mark.parametrize("element", ["p1", "p2"])
def test_a_weight_hook_averages_the_ball_around_its_point(element):
    """The hook's attachment is a mean over a symmetric lattice in the ball: shape functions
    reproduce linear fields, so at rest it sits exactly at the point, its weights sum to 1,
    and a rigid motion of the body moves it rigidly."""
    robot = with_element(load_robot(ROOT / "sample_data" / "diamond_truth" / "diamond.toml"),
                         element)
    point = np.array([0.0, 0.0, 110.0])  # inside the apex, 4 mm above its lower face
    hook = hook_region(robot, point, HOOK_RADIUS_MM)
    assert hook.weights.shape[0] == 1 and hook.weights.sum() == pytest.approx(1.0)
    assert hook.weights.shape[1] > 10  # spread over more than one element's nodes
    np.testing.assert_allclose(hook.positions(robot.rest_nodes_mm)[0], point, atol=1e-9)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    moved = robot.rest_nodes_mm @ turn.T + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(hook.positions(moved)[0], turn @ point + [1.0, 2.0, 3.0],
                               atol=1e-9)


def test_scenario_defaults_follow_the_design(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('robot = "r.toml"\n[[frame]]\nrepeat = 3\n')
    scenario = load_scenario(path)
    assert scenario.camera.position_mm == (0.0, 0.0, 580.0)  # docs/virtual_camera.md: 0.58 m above
    assert scenario.frame_count == 3
    assert scenario.robot == Path(tmp_path / "r.toml").resolve()
    # lit from the camera with 0.7 of the paint as ambient light (docs/virtual_camera.md)
    assert scenario.scene.ambient == 0.7 and scenario.scene.light_direction is None


# A shallow arch clamped at both ends, 80 mm span, 2 mm thick, 6 mm rise (P2, Neo-Hookean).
# Pressed at its crown in steps of 0.01 N it snaps through to the inverted arch between 0.07
# and 0.08 N and back between 0.03 and 0.02 N: between those loads it has two equilibria.
ARCH_TOML = """name = "arch"
[mesh]
path = "arch.vtu"
element = "p2"
[material]
law = "neo-hookean"
young_modulus_mpa = 5.0
poisson_ratio = 0.45
total_mass_kg = 0.001
gravity_mm_s2 = [0.0, 0.0, -9810.0]
[[fixed]]
box_mm = [-1.0, -10.0, -10.0, 1.0, 10.0, 10.0]
[[fixed]]
box_mm = [79.0, -10.0, -10.0, 81.0, 10.0, 10.0]
[[marker]]
id = "crown"
position_mm = [40.0, 0.0, 8.0]
"""


def arch_scenario(folder: Path, crown_loads_n: list[float]) -> Path:
    """A scenario pressing the arch's crown with each load in turn (one frame each)."""
    nodes, tets = box_mesh((80.0, 8.0, 2.0), (16, 2, 1), (0.0, -4.0, 0.0))
    nodes[:, 2] += 6.0 * np.sin(np.pi * nodes[:, 0] / 80.0)
    meshio.write(folder / "arch.vtu", meshio.Mesh(nodes, [("tetra", tets)]))
    (folder / "arch.toml").write_text(ARCH_TOML)
    frames = "".join(
        "\n[[frame]]\nactuation = []\n" + (f'[[frame.load]]\nkind = "probe"\npoint_mm = '
                                          f"[40.0, 0.0, 8.0]\nforce_n = {load}\n" if load else "")
        for load in crown_loads_n)
    path = folder / "arch_scenario.toml"
    path.write_text('robot = "arch.toml"\n[camera]\nwidth = 32\nheight = 24\nnoise = false\n'
                    + frames)
    return path


def crown_heights(truth: Path) -> list[float]:
    return [frame["markers"]["crown"]["robot_mm"][2]
            for frame in json.loads(truth.read_text())["frames"]]


def snaps(truth: Path) -> dict[int, float]:
    return {frame["index"]: frame["snap_through_mm"]
            for frame in json.loads(truth.read_text())["frames"] if "snap_through_mm" in frame}


def test_a_snap_through_of_the_truth_is_reported(tmp_path):
    """Past 0.07 N the arch snaps through, and the way back to 0.05 N stays inverted: the
    frame is marked with how far the two equilibria at 0.05 N lie apart (about the arch's
    whole rise) and a warning says so; so is the snap back at rest."""
    scenario = arch_scenario(tmp_path, [0.05, 0.1, 0.05, 0.0])
    with pytest.warns(SnapThroughWarning) as caught:
        result = simulate(scenario, tmp_path / "arch.mcap")
    assert [str(w.message).split(" ")[:2] for w in caught] == [["frame", "1"], ["frame", "3"]]
    heights = crown_heights(result.truth)
    assert heights[0] > 6.0 and heights[1] < -1.0  # standing, then inverted
    assert heights[2] < 0.0  # inverted at the load it stood under in frame 0
    assert heights[3] > 7.0  # back up at rest
    found = snaps(result.truth)
    assert sorted(found) == [1, 3]
    # the two equilibria at 0.05 N: the crown at heights[0] and heights[2]
    assert found[1] >= heights[0] - heights[2] - 0.01


def test_a_truth_moving_along_one_branch_reports_no_snap(tmp_path):
    """Loads the arch holds without snapping, loading and unloading: no warning, no mark."""
    scenario = arch_scenario(tmp_path, [0.0, 0.03, 0.06, 0.03, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error", SnapThroughWarning)
        result = simulate(scenario, tmp_path / "arch.mcap")
    assert snaps(result.truth) == {}
    assert min(crown_heights(result.truth)) > 5.0


def test_states_past_a_snap_through_are_not_taken_from_the_cache(tmp_path):
    """simulate's states cache holds a state per frame's loads, which a body with two
    equilibria there does not determine: past a snap-through a run neither reads nor fills
    it, so frame 2 is the inverted arch, not frame 0's standing one, on a run that finds
    frame 0 cached too."""
    scenario = arch_scenario(tmp_path, [0.05, 0.1, 0.05])
    states: dict = {}
    for run in range(2):
        with pytest.warns(SnapThroughWarning):
            result = simulate(scenario, tmp_path / f"arch{run}.mcap", states=states)
        heights = crown_heights(result.truth)
        assert heights[0] > 6.0 and heights[2] < 0.0
        assert sorted(snaps(result.truth)) == [1]
    assert len(states) == 1  # frame 0's state only


def test_continuation_walks_from_the_previous_frames_loads(tmp_path, monkeypatch):
    """Where one Newton solve does not reach a frame, simulate walks to it in load steps, as
    the body moves between the frames: from the inverted arch under 0.1 N to 0.05 N, the load
    eases off and the arch stays inverted. (A walk whose loads grow from zero, as before
    2026-12-02, first asks the inverted arch to stand under 0.017 N, below the 0.02-0.03 N
    where its branch ends, and Newton found no equilibrium there.)"""
    monkeypatch.setattr(ground_truth, "CONTINUATION_STEPS", (3,))
    scenario = arch_scenario(tmp_path, [0.1, 0.05])
    with warnings.catch_warnings():
        warnings.simplefilter("error", SnapThroughWarning)
        result = simulate(scenario, tmp_path / "arch.mcap")
    heights = crown_heights(result.truth)
    assert heights[0] < -1.0 and -1.0 < heights[1] < 0.0


def test_a_frame_the_truth_cannot_reach_is_named(tmp_path, monkeypatch):
    """Where no continuation reaches a frame's state, the error says which frame, and the
    frames before it are kept."""
    solve = ground_truth.solve_equilibrium

    def failing_past(model, inputs, loads=None, *args, **kwargs):
        if loads is not None and np.abs(loads.forces_n).sum() > 0.07:
            raise SolverError("static solve did not converge")
        return solve(model, inputs, loads, *args, **kwargs)

    monkeypatch.setattr(ground_truth, "solve_equilibrium", failing_past)
    scenario = arch_scenario(tmp_path, [0.05, 0.1])
    with pytest.raises(ScenarioError, match=r"^frame 1 \(0.5 s\): the truth robot cannot "
                                            r"reach the frame's state even in 16 load steps"):
        simulate(scenario, tmp_path / "arch.mcap")
    assert len(crown_heights(tmp_path / "arch.truth.json")) == 1
