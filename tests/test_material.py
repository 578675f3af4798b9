"""`softforce calibrate --material`: Young's modulus from a known weight, then used by sense."""

from __future__ import annotations

import json

import pytest

from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT, SAMPLE_ROBOT
from tests.test_sense_cli import pose_calibration

WEIGHTS = ROOT / "sample_data" / "recordings" / "weights.mcap"
# the quadratic element: it does not lock, so the fitted modulus is the truth body's own
P2_ROBOT = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
TRUTH_MODULUS_MPA = 0.18  # sample_data/diamond_truth/diamond.toml
# frame 0 unloaded, frame 3 holds 0.66 N below the apex (sample_data/scenarios/weights.toml)
LOAD = ["--load-point", "0,0,110", "--load-n", "0,0,-0.66"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("material")
    pose = pose_calibration(WEIGHTS.with_suffix("").with_suffix(".truth.json"), folder)
    out = folder / "material.json"
    result = softforce("calibrate", "--material", "--robot", P2_ROBOT, "--calibration", pose,
                       "--recording", WEIGHTS, "--frames", "3:4", "--reference-frames", "0:1",
                       *LOAD, "-o", out, "--json")
    return result, out, folder


def test_fit_makes_the_sensed_weight_the_known_one(fitted):
    result, out, _ = fitted
    assert result.returncode == 0, result.stderr
    material = json.loads(result.stdout)
    assert material == json.loads(out.read_text())["material"]
    # the coarse P2 model against the locking-free truth on another mesh (Neo-Hookean, D415
    # noise, one 424x240 frame): the fitted modulus is the truth's within 5%
    assert material["young_modulus_mpa"] == pytest.approx(TRUTH_MODULUS_MPA, rel=0.05)
    assert material["estimates_n"][0] == pytest.approx(0.66, rel=0.03)
    # at the file's modulus, below the fitted one, the model is softer and reads the weight
    # low (not in proportion: the settled sensed load is not linear in E, docs/sensing.md)
    assert material["young_modulus_mpa"] > 0.18 and material["nominal_estimate_n"] < 0.66
    interval = material["young_modulus_ci95_mpa"]  # one frame: only a step of the load gives one
    if interval is not None:
        assert interval[0] <= material["young_modulus_mpa"] <= interval[1]
    assert material["element"] == "p2" and "tared" in material["method"]


def test_sense_uses_the_fitted_modulus(fitted):
    _, out, folder = fitted
    material = json.loads(out.read_text())["material"]
    result = softforce("sense", WEIGHTS, "--robot", P2_ROBOT, "--calibration", out,
                       "-o", folder / "sense", "--contact-point", "0,0,110", "--direction",
                       "0,0,-1", "--tare", "1", "--updates", "6")
    assert result.returncode == 0, result.stderr
    assert "lock" not in result.stderr  # E fitted for the element: no locking warning
    document = json.loads((folder / "sense" / "sense.json").read_text())
    assert document["robot"]["young_modulus_mpa"] == material["young_modulus_mpa"]
    forces = {f["frame"]: f["contacts"][0]["force_n"] for f in document["frames"]
              if f["contacts"]}
    # the fit sensed frame 3 right after the tare, here it follows frames 1-2 (single
    # 424x240 frames: 0.227, 0.453, 0.659, 0.746, 0.830, 0.913 N for 0.26 to 0.96 N)
    assert forces[3] == pytest.approx(0.66, rel=0.06)
    # heavier weights read heavier, within the noise of single 424x240 frames (see
    # docs/sensing.md): 0.26 and 0.96 N far apart
    assert forces[1] < 0.45 < forces[6]


@pytest.mark.parametrize(("drop", "fragment"), [("--load-n", "--load-n"),
                                                ("--calibration", "--calibration")])
def test_material_needs_its_inputs(fitted, tmp_path, drop, fragment):
    _, _, folder = fitted
    args = {"--calibration": str(folder / "pose.json"), "--recording": str(WEIGHTS),
            "--load-point": "0,0,110", "--load-n": "0,0,-0.66"}
    del args[drop]
    result = softforce("calibrate", "--material", "--robot", SAMPLE_ROBOT, "-o",
                       tmp_path / "m.json", *[x for pair in args.items() for x in pair])
    assert_one_line_error(result, fragment)


def test_the_fit_senses_with_the_settings_file_sense_reads(fitted, tmp_path):
    """--settings reaches the fit's sensing: with the paper's nearest-point matching the
    file's modulus reads the weight otherwise (the sensed load depends on the matching), and
    a bad settings file, or --settings without --material, is one line."""
    result, _, folder = fitted
    default = json.loads(result.stdout)
    paper = tmp_path / "paper.toml"
    paper.write_text("[vision]\nmatch_mean_mm = 0.0\nmatch_max_view_deg = 90.0\n")
    args = ["--robot", P2_ROBOT, "--calibration", folder / "pose.json", "--recording", WEIGHTS,
            "--frames", "3:4", "--reference-frames", "0:1", *LOAD]
    run = softforce("calibrate", "--material", *args, "--settings", paper,
                    "-o", tmp_path / "paper.json", "--json")
    assert run.returncode == 0, run.stderr
    nearest = json.loads(run.stdout)
    assert abs(nearest["nominal_estimate_n"] - default["nominal_estimate_n"]) > 1e-3
    assert nearest["young_modulus_mpa"] == pytest.approx(TRUTH_MODULUS_MPA, rel=0.05)
    bad = tmp_path / "bad.toml"
    bad.write_text("[vision]\nmatch_max_view_deg = 120.0\n")
    assert_one_line_error(softforce("calibrate", "--material", *args, "--settings", bad,
                                    "-o", tmp_path / "bad.json"), "match_max_view_deg")
    assert_one_line_error(softforce("calibrate", "--robot", SAMPLE_ROBOT, "--recording",
                                    WEIGHTS, "--settings", paper, "-o", tmp_path / "c.json"),
                          "--settings is for --material")


def test_a_jump_in_the_sensed_load_is_not_taken_for_a_root(monkeypatch):
    """Brent's method on a sensed load that jumps past the known one at 0.25 MPa (a frame
    that starts or stops matching) ends on the jump; the fit must refuse it."""
    import numpy as np

    from softforce_cli.calibration import material
    from softforce_cli.errors import CalibrationError
    from softforce_cli.model.robot import load_robot

    def sensed(robot, *_):
        modulus = robot.material.young_modulus_mpa
        return np.array([0.5 * np.sqrt(modulus / 0.18) if modulus < 0.25 else 2.0]), 1.0

    monkeypatch.setattr(material, "_sensed", sensed)
    load = material.KnownLoad(np.array([0.0, 0.0, 110.0]), np.array([0.0, 0.0, -0.66]))
    with pytest.raises(CalibrationError, match="jumps"):
        material.fit_young_modulus(load_robot(SAMPLE_ROBOT), None, [], [], load, None)
    # the same fit on a continuous response finds the proportional answer
    monkeypatch.setattr(material, "_sensed", lambda robot, *_: (
        np.array([0.5 * robot.material.young_modulus_mpa / 0.18]), 1.0))
    fit = material.fit_young_modulus(load_robot(SAMPLE_ROBOT), None, [], [], load, None)
    assert fit.young_modulus_mpa == pytest.approx(0.18 * 0.66 / 0.5, rel=5e-3)


def test_a_small_step_at_the_root_is_reported_as_the_interval(monkeypatch):
    """A sensed load proportional to E but 5% low below the root and 5% high above it (the
    feature matches change there): the fit lands on the step and reports, as its interval,
    the moduli the two sides ask for (E / 1.05 and E / 0.95 of the continuous root)."""
    import numpy as np

    from softforce_cli.calibration import material
    from softforce_cli.model.robot import load_robot

    root = 0.18 * 0.66 / 0.5

    def sensed(robot, *_):
        modulus = robot.material.young_modulus_mpa
        return np.array([0.5 * modulus / 0.18 * (0.95 if modulus < root else 1.05)]), 1.0

    monkeypatch.setattr(material, "_sensed", sensed)
    load = material.KnownLoad(np.array([0.0, 0.0, 110.0]), np.array([0.0, 0.0, -0.66]))
    fit = material.fit_young_modulus(load_robot(SAMPLE_ROBOT), None, [], [], load, None)
    assert fit.young_modulus_mpa == pytest.approx(root, rel=1e-2)
    assert fit.ci95_mpa == pytest.approx((root / 1.05, root / 0.95), rel=1e-2)


def test_a_step_to_a_modulus_that_cannot_be_sensed_is_taken_back(monkeypatch):
    """The bracketing's first step (20% softer) lands where the model cannot be sensed (the
    coarse Diamond's P2 model 17% softer snaps out of the sample's rest shape: no feature
    matched, and sensing raised); the fit steps back halfway, brackets the root from there
    and finds it, where it had refused."""
    import numpy as np

    from softforce_cli.calibration import material
    from softforce_cli.errors import CalibrationError
    from softforce_cli.model.robot import load_robot

    def sensed(robot, *_):
        modulus = robot.material.young_modulus_mpa
        if modulus < 0.16:
            raise CalibrationError("no loaded frame could be sensed (fewmatches)")
        return np.array([0.532 * modulus / 0.18]), 1.0

    monkeypatch.setattr(material, "_sensed", sensed)
    load = material.KnownLoad(np.array([0.0, 0.0, 110.0]), np.array([0.0, 0.0, -0.5]))
    fit = material.fit_young_modulus(load_robot(SAMPLE_ROBOT), None, [], [], load, None)
    assert fit.young_modulus_mpa == pytest.approx(0.18 * 0.5 / 0.532, rel=5e-3)
    # where even the smallest step back cannot be sensed, the error is the user's one line
    def sensed_at_the_nominal_only(robot, *_):
        if robot.material.young_modulus_mpa < 0.18:
            raise CalibrationError("no loaded frame could be sensed (lost)")
        return np.array([0.6]), 1.0

    monkeypatch.setattr(material, "_sensed", sensed_at_the_nominal_only)
    with pytest.raises(CalibrationError, match="could be sensed"):
        material.fit_young_modulus(load_robot(SAMPLE_ROBOT), None, [], [], load, None)


def _robot_copy(folder, *replacements):
    """The sample robot file in folder with its mesh path absolute and each (old, new) of
    replacements made once."""
    text = SAMPLE_ROBOT.read_text().replace(
        'path = "diamond_coarse.vtu"', f'path = "{SAMPLE_ROBOT.parent / "diamond_coarse.vtu"}"')
    for old, new in replacements:
        assert old in text
        text = text.replace(old, new, 1)
    path = folder / "robot.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("replacement", "fragment"), [
    (('name = "north"', 'name = "top"'), "are not the robot's cables"),
    (('control = "displacement"', 'control = "force"'), "displacement-controlled but"),
])
def test_a_recording_for_other_cables_is_refused(fitted, tmp_path, replacement, fragment):
    """A recording whose /robot/actuation names another robot's cables, or another control
    mode, is refused with one line by the material calibration (which read the inputs by
    position before) as by sense, rather than driving the wrong cables."""
    _, _, folder = fitted
    robot = _robot_copy(tmp_path, replacement)
    material = softforce("calibrate", "--material", "--robot", robot, "--calibration",
                         folder / "pose.json", "--recording", WEIGHTS, "--frames", "3:4", *LOAD,
                         "-o", tmp_path / "m.json")
    assert_one_line_error(material, fragment)
    assert not (tmp_path / "m.json").exists()
    sense = softforce("sense", WEIGHTS, "--robot", robot, "--calibration", folder / "pose.json",
                      "-o", tmp_path / "sense")
    assert_one_line_error(sense, fragment)
