"""`softforce diagnose` end to end on the shipped recordings: a concealed 3 mm slack of the
north cable (its truth file read only here) is named, located, fitted within 10% and halves
the held-out residual; the clean control answers `none`; bad input is one line."""

import json
import tomllib

import pytest

from softforce_cli.diagnosis.selection import MIN_EXCESS_SHARE, Z_ACCEPT
from softforce_cli.fem import processes
from softforce_cli.model.effects import EFFECTS
from softforce_cli.model.robot import load_robot
from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT, SAMPLE_ROBOT
from tests.test_sense_cli import pose_calibration

RECORDINGS = ROOT / "sample_data" / "recordings"
SLACK = RECORDINGS / "diagnose_slack.mcap"
CLEAN = RECORDINGS / "diagnose_clean.mcap"
OUTPUTS = ("diagnosis.json", "robot.fitted.toml", "residual_map.png", "signature.png")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One FE cache for the module: the clean control's states are the slack recording's."""
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def slack_run(tmp_path_factory, cache):
    folder = tmp_path_factory.mktemp("slack")
    calibration = pose_calibration(SLACK.with_suffix("").with_suffix(".truth.json"), folder)
    # the default thresholds, stated in a settings file: the file is read and recorded
    settings = folder / "settings.toml"
    settings.write_text("[vision]\nvoxel_mm = 1.1\ndecimation = 0\n")
    result = softforce("diagnose", SLACK, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                       "-o", folder / "out", "--cache", cache, "--settings", settings)
    return result, folder / "out", calibration


def test_the_concealed_slack_is_named_located_fitted_and_halves_the_residual(slack_run):
    result, out, _ = slack_run
    assert result.returncode == 0, result.stderr
    truth = json.loads(SLACK.with_suffix("").with_suffix(".truth.json").read_text())
    (concealed,) = truth["concealed_effects"]
    assert (concealed["name"], concealed["target"]) == ("cable_slack", "north")
    true_slack = concealed["parameters"]["slack_mm"]["value"]
    document = json.loads((out / "diagnosis.json").read_text())
    assert document["verdict"] == "cable_slack"
    first = document["effects"][0]
    assert first["name"] == "cable_slack" and first["target"] == "north"
    assert first["evidence"]["selected"] and first["evidence"]["refitted"]
    slack = first["parameters"]["slack_mm"]
    assert slack["unit"] == "mm"
    assert slack["value"] == pytest.approx(true_slack, rel=0.1)
    assert slack["ci95"][0] < slack["value"] < slack["ci95"][1]
    assert slack["ci95"][0] <= true_slack <= slack["ci95"][1]
    assert first["heldout_rms_after_mm"] <= 0.5 * first["heldout_rms_before_mm"]
    # the sample robot is corotational, the recorded body Neo-Hookean: the law is the second
    # effect, judged with the slack on the absolute residuals, where its sag shows
    second = document["effects"][1]
    assert second["name"] == "material_nonlinearity" and second["evidence"]["selected"]
    assert second["label"] == "cable_slack[north] + material_nonlinearity"
    assert second["evidence"]["mode"] == "absolute"
    # the law switched fully (blend 1); fitted alone with the slack, the blend takes up the
    # coarse mesh's own stiffness error too (0.63), fitted with the mesh's allowance 0.89
    blend = second["parameters"]["material_nonlinearity.blend"]["value"]
    assert 0.8 < blend <= 1.0
    allowance = second["evidence"]["mesh_allowance"]
    assert allowance["alone"]["parameters"]["material_nonlinearity.blend"]["value"] < blend - 0.1
    bound = 1.0 / document["evidence"]["mesh_bracket"]["load_scale"]
    assert bound <= allowance["stiffness_scale"]["value"] <= 1.0
    assert second["parameters"]["cable_slack[north].slack_mm"]["value"] == pytest.approx(
        true_slack, rel=0.1)
    assert second["heldout_rms_after_mm"] <= 0.5 * second["heldout_rms_before_mm"]
    assert document["location"]["cables"] == ["north"]
    assert document["location"]["regions"][0] == "north"
    # the recording publishes markers: the north elbow is the furthest from the model, and
    # a camera fitted on them is no explanation (the clouds named the slack)
    marker_rms = document["location"]["marker_rms_mm"]
    assert max(marker_rms, key=marker_rms.get) == "elbow_north"
    assert document["evidence"]["markers"]["observations"] > 0
    judged = [e for e in document["effects"] if e["evidence"]["channel"] == "markers"]
    assert {e["name"] for e in judged} == {"extrinsic_offset", "depth_bias"}
    assert not any(e["evidence"]["selected"] for e in judged)
    # the terminal summary, printed to a pipe (80 columns), wraps names and values whole
    assert "…" not in result.stdout
    assert "cable_slack" in result.stdout and "slack_mm=" in result.stdout
    assert "cable_slack[north] + material_nonlinearity: " in result.stdout  # not rich markup


def test_diagnosis_json_follows_the_contract(slack_run):
    _, out, _ = slack_run
    for name in OUTPUTS:
        assert (out / name).stat().st_size > 0
    document = json.loads((out / "diagnosis.json").read_text())
    assert {"verdict", "noise_floor_mm", "effects", "location"} <= set(document)
    assert document["inputs"]["settings"].endswith("settings.toml")
    assert 0 < document["noise_floor_mm"] < 1.0
    assert set(document["location"]) >= {"regions", "cables", "nodes"}
    names = {"gravity", "stiffness_scale", "regional_stiffness", "material_nonlinearity",
             "cable_slack", "cable_friction", "compliant_base", "viscoelastic_creep",
             "support_contact", "depth_bias", "extrinsic_offset"}
    for effect in document["effects"]:
        assert effect["name"] in names
        assert {"name", "parameters", "heldout_rms_before_mm", "heldout_rms_after_mm",
                "evidence"} <= set(effect)
        for parameter in effect["parameters"].values():
            assert {"value", "ci95", "unit"} <= set(parameter)
    assert not document["interrupted"] and document["stage"] == "done"
    # every effect has a numeric interval, so `softforce report` reads the folder
    for effect in document["effects"]:
        for parameter in effect["parameters"].values():
            low, high = parameter["ci95"]
            assert low <= parameter["value"] <= high
    # ... within the parameter's physical range (a pair's parameters are named
    # "effect[target].parameter": those of the first effect alone are checked here)
    for effect in document["effects"]:
        for name, parameter in effect["parameters"].items():
            if "." in name:
                continue
            spec = EFFECTS[effect["name"]].parameter(name)
            assert spec.lower <= parameter["ci95"][0] <= parameter["ci95"][1] <= spec.upper
    table = softforce("report", out, "--format", "csv", "--table", "effects")
    assert table.returncode == 0, table.stderr
    assert table.stdout.splitlines()[1].startswith("cable_slack,north,slack_mm,")
    # the P1 robot's locking is measured and said, not taken for physics
    evidence = document["evidence"]
    assert evidence["element"] == "p1" and evidence["prediction_element"] == "p2"
    assert evidence["rms_given_element_mm"] > 2 * evidence["rms_nominal_mm"]
    # the body moves smoothly in its holds (diagnosis.jumps)
    assert evidence["jumps_in_holds"] == []


def test_the_fitted_robot_loads_and_carries_the_slack_and_the_law(slack_run, tmp_path):
    _, out, _ = slack_run
    fitted = out / "robot.fitted.toml"
    robot = load_robot(fitted)
    # each selected effect once, with the values of their joint fit, and the mesh's own
    # stiffness error fitted with them (pipeline._with_the_mesh)
    effect, law, allowance = robot.effects
    assert (effect.name, effect.target) == ("cable_slack", "north")
    assert effect["slack_mm"] == pytest.approx(3.0, rel=0.1)
    assert law.name == "material_nonlinearity" and 0.8 < law["blend"] <= 1.0
    assert allowance.name == "stiffness_scale" and 0.85 < allowance["scale"] <= 1.0
    # a 2 mm command stays inside the slack: the body does not move
    assert robot.cable_inputs([2.0, 0.0, 0.0, 0.0]).values[0] == 0.0
    solved = softforce("model", "solve", fitted, "--actuation", "6,0,0,0", "-o",
                       tmp_path / "deformed.vtu", "--json")
    assert solved.returncode == 0, solved.stderr
    assert tomllib.loads(fitted.read_text())["mesh"]["path"].endswith("diamond_coarse.vtu")


def neo_hookean_robot(folder) -> str:
    """The sample robot with the law of the sample recordings' truth (Neo-Hookean)."""
    text = SAMPLE_ROBOT.read_text()
    assert 'law = "corotational"' in text and 'path = "diamond_coarse.vtu"' in text
    path = folder / "diamond_neo.toml"
    path.write_text(text.replace('law = "corotational"', 'law = "neo-hookean"').replace(
        'path = "diamond_coarse.vtu"', f'path = "{SAMPLE_ROBOT.parent / "diamond_coarse.vtu"}"'))
    return path


def test_the_clean_control_answers_none(tmp_path, cache):
    # clean: the robot file's law is the truth body's, so the model differs from it by
    # the mesh alone
    calibration = pose_calibration(CLEAN.with_suffix("").with_suffix(".truth.json"), tmp_path)
    result = softforce("diagnose", CLEAN, "--robot", neo_hookean_robot(tmp_path),
                       "--calibration", calibration, "-o", tmp_path / "out", "--cache", cache)
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert document["verdict"] == "none", document["effects"][:3]
    assert "[[effect]]" not in (tmp_path / "out" / "robot.fitted.toml").read_text()
    # its markers were screened too (the clouds found nothing): a camera fitted on them
    # does not clearly improve their held-out residual, so no camera effect is named
    markers = document["evidence"]["markers"]
    assert markers["noise_floor_mm"] == pytest.approx(0.5, rel=0.2)  # the scenario's noise
    judged = [e["evidence"] for e in document["effects"] if e["evidence"]["channel"] == "markers"]
    assert judged and not any(e["selected"] for e in judged)
    assert all(e["segment_gain_z"] < Z_ACCEPT or e["excess_share"] < MIN_EXCESS_SHARE
               for e in judged)


def test_the_default_robots_law_is_named_against_the_neo_hookean_body(tmp_path, cache):
    # the default robot is corotational, and sags 0.6 mm more under gravity than the
    # Neo-Hookean body of the recording: the law is what its model leaves out
    calibration = pose_calibration(CLEAN.with_suffix("").with_suffix(".truth.json"), tmp_path)
    result = softforce("diagnose", CLEAN, "--robot", SAMPLE_ROBOT, "--calibration",
                       calibration, "-o", tmp_path / "out", "--cache", cache)
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert document["verdict"] == "material_nonlinearity", document["effects"][:3]
    first = document["effects"][0]
    # towards the other law, short of all of it: the coarse mesh is stiffer than the body
    # and takes the rest (docs/diagnosis_history.md, tenth run)
    assert 0.4 < first["parameters"]["blend"]["value"] < 1.0
    assert first["heldout_rms_after_mm"] <= 0.6 * first["heldout_rms_before_mm"]


def test_bad_input_is_one_line(slack_run, tmp_path):
    _, out, calibration = slack_run
    missing = softforce("diagnose", tmp_path / "none.mcap", "--robot", SAMPLE_ROBOT,
                        "--calibration", calibration, "-o", tmp_path / "a")
    assert_one_line_error(missing, "none.mcap")
    again = softforce("diagnose", SLACK, "--robot", SAMPLE_ROBOT, "--calibration", calibration,
                      "-o", out)
    assert_one_line_error(again, "--force")
    # a calibration for another camera: the robot is nowhere in its view
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text(json.dumps({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                                     "translation_mm": [2000.0, 0.0, 0.0]}))
    away = softforce("diagnose", SLACK, "--robot", SAMPLE_ROBOT, "--calibration", elsewhere,
                     "-o", tmp_path / "b")
    assert_one_line_error(away, "calibration belongs to this camera")
    assert not (tmp_path / "b").exists()  # refused after the vision: no empty folder left
    # the settings reach the vision: everything within a metre of the table is table
    for text, message in [("[vision]\ntable_clearance_mm = 1000.0\n", "shows the robot"),
                          ("[vision]\ndecimation = 9\n", "decimation"),
                          ("[vision]\nvoxel = 1.1\n", "voxel")]:
        settings = tmp_path / "settings.toml"
        settings.write_text(text)
        refused = softforce("diagnose", SLACK, "--robot", SAMPLE_ROBOT, "--calibration",
                            calibration, "-o", tmp_path / "d", "--settings", settings,
                            "--no-cache")
        assert_one_line_error(refused, message)
        assert not (tmp_path / "d").exists()
    # a recording whose actuation never changes cannot tell physics from the model
    weights = RECORDINGS / "weights.mcap"
    still = softforce("diagnose", weights, "--robot", SAMPLE_ROBOT, "--calibration",
                      pose_calibration(weights.with_suffix("").with_suffix(".truth.json"),
                                       tmp_path), "-o", tmp_path / "c", "--no-cache")
    assert_one_line_error(still, "actuation never changes")
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize(("stage_name", "calls", "effects"), [
    ("screening", 4, 4), ("plate contacts", 2, 0), ("second effect", 1, None)])
def test_an_interrupted_run_keeps_what_it_reached(slack_run, cache, tmp_path, stage_name,
                                                  calls, effects):
    """A stop requested during the screening (Ctrl-C under deferred_interrupt) leaves a
    diagnosis.json marked interrupted, with the stage reached and the effects screened so
    far, and no fitted robot; during the plate's responses (diagnosis.support), at stage
    `plate contacts` with nothing screened; during the refits of a second effect, which the
    stop cuts short, interrupted too, not a verdict on values the refit did not reach."""
    from softforce_cli.diagnosis.run import DiagnoseInputs, run_diagnosis

    _, _, calibration = slack_run
    reached = []

    def stage(name, done, total):
        if name == stage_name:
            reached.append(done)

    inputs = DiagnoseInputs((SLACK,), SAMPLE_ROBOT, calibration, tmp_path / "out",
                            cache=cache)
    diagnosis = run_diagnosis(inputs, stage, lambda: len(reached) >= calls)
    assert diagnosis.interrupted and diagnosis.verdict is None
    document = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert document["interrupted"] and document["stage"] == stage_name
    assert document["verdict"] is None
    if effects is not None:  # the hypotheses screened before the stop (and those running)
        assert effects - 1 <= len(document["effects"]) <= effects + processes.MAX_WORKERS
    assert not (tmp_path / "out" / "robot.fitted.toml").exists()
