"""`softforce model init | show | solve` end to end, through the real command."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest

from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import SAMPLE_ROBOT


@pytest.fixture(scope="module")
def robot_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("robot")
    result = softforce("model", "init", directory)
    assert result.returncode == 0, result.stderr
    return directory


def test_init_writes_the_sample_robot_deterministically(robot_dir):
    assert (robot_dir / "diamond.toml").read_text() == SAMPLE_ROBOT.read_text()
    again = softforce("model", "init", robot_dir)
    assert_one_line_error(again, "already exists; pass --force")


def test_show_json_is_the_only_stdout(robot_dir, tmp_path):
    picture = tmp_path / "robot.png"
    result = softforce("model", "show", robot_dir / "diamond.toml", "--json",
                       "--picture", picture)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["tetrahedra"] > 4000 and summary["features"] == 51
    assert summary["mass_kg"] == pytest.approx(0.5)
    assert [c["name"] for c in summary["cables"]] == ["north", "west", "south", "east"]
    assert summary["effects"] == {}
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_show_lists_the_files_effects(robot_dir, tmp_path):
    """A fitted robot file's effects (diagnose writes them) in the table and the JSON."""
    fitted = robot_dir / "fitted.toml"
    fitted.write_text((robot_dir / "diamond.toml").read_text() + '\n[[effect]]\n'
                      'name = "support_contact"\ntable_z_mm = -7.25\n\n[[effect]]\n'
                      'name = "cable_slack"\ncable = "north"\nslack_mm = 2.5\n')
    summary = json.loads(softforce("model", "show", fitted, "--json").stdout)
    assert summary["effects"] == {"support_contact": {"table_z_mm": -7.25},
                                  "cable_slack[north]": {"slack_mm": 2.5}}
    table = softforce("model", "show", fitted).stdout
    assert "effect support_contact" in table and "table_z_mm = -7.25" in table
    assert "effect cable_slack[north]" in table and "slack_mm = 2.5" in table


def test_solve_writes_the_deformed_mesh_in_input_node_order(robot_dir, tmp_path):
    output = tmp_path / "deformed.vtu"
    result = softforce("model", "solve", robot_dir / "diamond.toml", "--actuation",
                       "5,5,5,5", "-o", output, "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert [c["displacement_mm"] for c in summary["cables"]] == pytest.approx([5] * 4, abs=1e-6)
    rest = meshio.read(robot_dir / "diamond_coarse.vtu")
    deformed = meshio.read(output)
    displacement = deformed.point_data["displacement_mm"]
    np.testing.assert_allclose(deformed.points - displacement, rest.points, atol=1e-9)
    np.testing.assert_array_equal(deformed.cells_dict["tetra"], rest.cells_dict["tetra"])
    # pulling all four cables lifts the apex (the top node) against gravity's sag
    assert summary["top_node_displacement_mm"][2] > 1.0
    # the supports carry the robot's weight (0.5 kg * 9.81 m/s^2) and the cables' downward pull
    assert summary["reaction_force_n"][2] > 0.5 * 9.81


def test_supports_balance_weight_and_cable_forces(sample_robot):
    from softforce_cli.fem.statics import solve_equilibrium

    model = sample_robot.fe_model
    equilibrium = solve_equilibrium(model, sample_robot.cable_inputs(np.array([5, 5, 0, 0.0])))
    cable_forces = model.cable_jacobian(equilibrium.positions_mm).T @ equilibrium.cable_tensions_n
    total = (equilibrium.reaction_forces_n.sum(axis=0) + model.gravity_forces_n.sum(axis=0)
             + cable_forces.reshape(-1, 3).sum(axis=0))
    np.testing.assert_allclose(total, 0.0, atol=1e-8)
    np.testing.assert_allclose(model.gravity_forces_n.sum(axis=0), [0, 0, -0.5 * 9.81])


def test_solve_rejects_bad_input(robot_dir, tmp_path):
    robot = robot_dir / "diamond.toml"
    assert_one_line_error(
        softforce("model", "solve", robot, "--actuation", "5,5", "-o", tmp_path / "a.vtu"),
        "2 actuation values for 4 cables")
    assert_one_line_error(
        softforce("model", "solve", robot, "--actuation", "5,x,0,0", "-o", tmp_path / "a.vtu"),
        "expected comma-separated finite numbers")
    # a NaN reached the solver's SVD as a traceback, an infinity Newton's 60 iterations
    for value in ("nan", "inf"):
        assert_one_line_error(
            softforce("model", "solve", robot, "--actuation", f"5,{value},0,0", "-o",
                      tmp_path / "a.vtu"), "expected comma-separated finite numbers")
    assert_one_line_error(softforce("model", "show", tmp_path / "none.toml"), "not found")
    assert not (tmp_path / "a.vtu").exists()


def test_a_path_with_brackets_is_printed_as_it_is(tmp_path):
    # rich would read "[run]" as a markup tag and drop it from the line
    folder = tmp_path / "[run]"
    result = softforce("model", "init", folder)
    assert result.returncode == 0, result.stderr
    # (a long path may be wrapped anywhere: compared without white space)
    assert f"wrote{folder / 'diamond.toml'}anditsmesh" in "".join(result.stderr.split())
