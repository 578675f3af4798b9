"""`softforce model`: create, inspect and solve robot models."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape

from softforce_cli.cli.common import (
    ForceOption,
    JsonOption,
    key_value_table,
    print_json,
    stderr,
    stdout,
)
from softforce_cli.errors import ModelError

app = typer.Typer(help="Create, inspect and solve robot models.", no_args_is_help=True)

RobotArgument = Annotated[Path, typer.Argument(help="Robot model file (TOML).")]


def parse_actuation(text: str) -> np.ndarray:
    """'5,5,0,0' -> array; one value per cable, in the cable's control units."""
    from softforce_cli.option_values import parse_numbers

    values = parse_numbers(text)
    if values is None:
        raise ModelError(f"--actuation {text!r}: expected comma-separated finite numbers, "
                         "e.g. 5,5,0,0")
    return values


@app.command("init")
def init(
    directory: Annotated[Path, typer.Argument(help="Folder to write diamond.toml and its mesh.")],
    resolution: Annotated[str, typer.Option(help="coarse (~4.5k tets, for estimation) or fine "
                                                 "(~18k tets, for ground truth).")] = "coarse",
    force: ForceOption = False,
) -> None:
    """Write softforce's default robot: the procedural Diamond, meshed with gmsh."""
    from softforce_cli.model.default_robot import write_default_robot

    with stderr.status(f"meshing the {resolution} Diamond with gmsh..."):
        path = write_default_robot(directory, resolution, force=force)
    stderr.print(f"wrote [bold]{escape(str(path))}[/] and its mesh")


@app.command("show")
def show(
    robot_file: RobotArgument,
    json_output: JsonOption = False,
    picture: Annotated[Path | None, typer.Option(help="Also save a PNG picture here.")] = None,
    force: ForceOption = False,
) -> None:
    """Summarise a robot: nodes, tetrahedra, volume, mass, supports, cables, features."""
    from softforce_cli.model.robot import load_robot
    from softforce_cli.model.summary import robot_summary

    robot = load_robot(robot_file)
    summary = robot_summary(robot)
    if picture is not None:
        from softforce_cli.plots.robot_picture import save_robot_picture

        save_robot_picture(robot, picture, force=force)
        summary["picture"] = str(picture)
    if json_output:
        print_json(summary)
        return
    material = summary["material"]
    rows = [
        ("file", summary["source"]),
        ("mesh", summary["mesh"]),
        ("nodes / tetrahedra", f"{summary['nodes']} / {summary['tetrahedra']}"),
        ("element", f"{summary['element']} ({summary['fe_nodes']} FE nodes)"),
        ("volume", f"{summary['volume_mm3'] / 1e3:.1f} cm^3"),
        ("mass", f"{summary['mass_kg']:.3f} kg"),
        ("material", f"{material['law']}, E = {material['young_modulus_mpa']} MPa, "
                     f"nu = {material['poisson_ratio']}, g = {material['gravity_mm_s2']}"),
        ("fixed nodes", str(summary["fixed_nodes"])),
        *((f"cable {cable['name']}", f"{cable['control']} in [{cable['min']}, {cable['max']}], "
           f"pull {cable['pull_point_mm']}") for cable in summary["cables"]),
        ("feature points", str(summary["features"])),
        ("markers", ", ".join(summary["markers"]) or "none"),
        *((f"effect {label}", ", ".join(f"{name} = {value:.6g}" if isinstance(value, float)
                                        else f"{name} = {value}"
                                        for name, value in parameters.items()))
          for label, parameters in summary["effects"].items()),
        *((("picture", str(picture)),) if picture is not None else ()),
    ]
    stdout.print(key_value_table(f"robot {summary['name']}", rows))


@app.command("solve")
def solve(
    robot_file: RobotArgument,
    output: Annotated[Path, typer.Option("-o", "--output",
                                         help="Deformed mesh (.vtu or any meshio format).")],
    actuation: Annotated[str | None, typer.Option(help="One value per cable, comma-separated, "
                                                       "in mm or N (the cable's control).")] = None,
    json_output: JsonOption = False,
    force: ForceOption = False,
) -> None:
    """Static equilibrium for an actuation; write the deformed mesh in the robot frame."""
    from softforce_cli.fem.statics import solve_equilibrium
    from softforce_cli.io.atomic import check_writable
    from softforce_cli.io.mesh_output import write_deformed_mesh
    from softforce_cli.model.robot import load_robot
    from softforce_cli.model.summary import equilibrium_summary

    check_writable(output, force)
    robot = load_robot(robot_file)
    values = np.zeros(len(robot.cable_specs)) if actuation is None else parse_actuation(actuation)
    inputs = robot.cable_inputs(values)
    with stderr.status("solving static equilibrium..."):
        equilibrium = solve_equilibrium(robot.fe_model, inputs)
    # the mesh's own nodes (P2 mid-edge nodes follow them and are not written)
    corners_mm = equilibrium.positions_mm[: robot.mesh.node_count]
    write_deformed_mesh(output, robot.mesh, corners_mm, force=force)
    summary = {"output": str(output), "actuation": values.tolist(),
               **equilibrium_summary(robot, equilibrium)}
    if json_output:
        print_json(summary)
        return
    rows = [
        ("max displacement", f"{summary['max_displacement_mm']:.3f} mm "
                             f"(node {summary['max_displacement_node']})"),
        ("top node displacement", f"{summary['top_node_displacement_mm']} mm"),
        *((f"cable {cable['name']}", f"{cable['displacement_mm']:.3f} mm, "
                                     f"{cable['tension_n']:.4f} N")
          for cable in summary["cables"]),
        ("support reaction", f"{summary['reaction_force_n']} N"),
        ("Newton iterations", str(summary["newton_iterations"])),
        ("written", str(output)),
    ]
    stdout.print(key_value_table(f"equilibrium of {robot.name}", rows))


@app.command("reduce")
def reduce(
    robot_file: RobotArgument,
    output: Annotated[Path, typer.Option("-o", "--output",
                                         help="Reduced model to write (.rom.npz).")],
    element: Annotated[str, typer.Option(help="Element trained on: p2 or p2-p0 (accurate, "
                                              "locking-free), or p1.")] = "p2",
    max_force: Annotated[float, typer.Option(help="Largest contact force trained (N).")] = 1.0,
    max_modes: Annotated[int, typer.Option(help="Cap on the basis size (the update costs "
                                                "~ modes^2).")] = 200,
    box_fraction: Annotated[float, typer.Option(
        help="Train over this fraction of each cable's \\[min, max] from the robot file.")
    ] = 1.0,
    ecsw_tolerance: Annotated[float | None, typer.Option(
        help="Relative residual of the sampled internal forces over the training set "
             "(default 0.001; looser: fewer points, a faster update; 0: every point, the "
             "exact projection, an update as slow as the mesh; docs/reduced_model.md).")
    ] = None,
    keep_snapshots: Annotated[bool, typer.Option(
        help="Keep the training snapshots (OUTPUT.snapshots.npz, ~100 MB) to retrain fast.")
    ] = False,
    json_output: JsonOption = False,
    force: ForceOption = False,
) -> None:
    r"""Train a reduced-order model (POD + ECSW) of the robot; use it with \[mesh] reduced.

    The snapshots are saved beside OUTPUT while training, so a run stopped after them resumes
    there; they are deleted at the end unless --keep-snapshots.
    """
    import dataclasses

    from softforce_cli.cli.common import progress_bar
    from softforce_cli.fem.element import ELEMENTS
    from softforce_cli.fem.reduction.rom_file import save_reduction
    from softforce_cli.fem.reduction.train import (
        TrainingSettings,
        check_trainable,
        train_robot,
    )
    from softforce_cli.io.atomic import check_can_write, check_writable
    from softforce_cli.model.robot import load_robot, with_element

    if element not in ELEMENTS:
        raise ModelError(f"--element {element!r} unknown; use {' or '.join(ELEMENTS)}")
    check_writable(output, force)
    check_can_write(output)  # before the minutes of training
    robot = with_element(load_robot(robot_file), element)
    check_trainable(robot)
    if not 0.0 < box_fraction <= 1.0:
        raise ModelError(f"--box-fraction {box_fraction:g} must be in (0, 1]")
    if max_modes < 1:
        raise ModelError(f"--max-modes {max_modes} must be at least 1")
    if not 0.0 < max_force < np.inf:
        raise ModelError(f"--max-force {max_force:g} must be a positive number of newtons")
    settings = TrainingSettings(max_force_n=max_force, max_modes=max_modes,
                                box_fraction=box_fraction)
    if ecsw_tolerance is not None:
        if not 0.0 <= ecsw_tolerance < 1.0:
            raise ModelError(f"--ecsw-tolerance {ecsw_tolerance:g} must be in [0, 1)")
        settings = dataclasses.replace(settings, ecsw_tolerance=ecsw_tolerance)
    # the snapshots are kept beside the output: a stopped training resumes after them
    cache = output.with_name(output.name + ".snapshots.npz")
    with progress_bar(f"training {element} reduced model") as advance:
        reduction = train_robot(robot, settings, advance, cache)
    save_reduction(output, reduction, force=force)
    if not keep_snapshots:
        cache.unlink(missing_ok=True)
    info = reduction.info
    summary = {"output": str(output), "element": element, "modes": info["modes"],
               "sampled_elements": info["sampled_elements"], "elements": info["elements"],
               "sampled_points": info["sampled_points"], "points": info["points"],
               "validation_rms_mm": reduction.box.rms_error_mm,
               "max_force_n": reduction.box.max_force_n,
               "max_displacement_mm": reduction.box.max_displacement_mm,
               "start_equilibria": info["start_equilibria"],
               "training_s": round(info["total_s"], 1),
               "robot_key": f'[mesh] reduced = "{output.name}"'}
    if json_output:
        print_json(summary)
        return
    box = reduction.box
    inputs = ", ".join(f"{c.name} {lo:g}-{hi:g} {'mm' if c.control == 'displacement' else 'N'}"
                       for c, lo, hi in zip(robot.cable_specs, box.cable_min, box.cable_max,
                                            strict=True))
    rows = [
        ("basis", f"{info['modes']} modes (POD energy tolerance {info['energy_tolerance']:g})"),
        ("sampled points", f"{info['sampled_points']} of {info['points']} quadrature points, "
                           f"in {info['sampled_elements']} of {info['elements']} elements "
                           f"(ECSW residual {info['ecsw_residual']:.2g})"),
        ("validation", f"{box.rms_error_mm:.3f} mm RMS surface error at untrained actuations, "
                       "unloaded and under a contact"),
        ("valid for", f"cables {inputs}; contact forces up to {box.max_force_n:g} N; shapes up "
                      f"to {box.max_displacement_mm:.1f} mm RMS from rest (beyond, it warns)"),
        ("static solves", f"start from the nearest of {info['start_equilibria']} of its own "
                          "equilibria over the box, moved to first order"),
        ("training", f"{info['total_s']:.0f} s"),
        ("written", str(output)),
        ("use it", f'add reduced = "{output.name}" under [mesh] of {robot_file.name}'),
    ]
    stdout.print(key_value_table(f"reduced model of {robot.name}", rows))
