"""`softforce calibrate --material`: Young's modulus from a recording with a known load."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rich.markup import escape
from rich.table import Table

from softforce_cli.cli.common import print_json, stderr, stdout
from softforce_cli.errors import CalibrationError, SensingError


def calibrate_material(robot_file: Path, output: Path, calibration: Path | None,
                       recording: Path | None, reference: Path | None, load_point: str | None,
                       load_n: str | None, frames: str | None, reference_frames: str | None,
                       settings_file: Path | None, json_output: bool, force: bool) -> None:
    from softforce_cli.calibration.material import KnownLoad, fit_young_modulus
    from softforce_cli.calibration.material_inputs import static_frames
    from softforce_cli.calibration.result import read_calibration
    from softforce_cli.estimation.settings import load_settings
    from softforce_cli.estimation.setup import parse_vector
    from softforce_cli.io.atomic import atomic_write_text, check_writable
    from softforce_cli.model.robot import load_robot

    missing = [name for name, value in (("--calibration", calibration),
                                        ("--recording", recording),
                                        ("--load-point", load_point), ("--load-n", load_n))
               if value is None]
    if missing:
        raise CalibrationError(f"--material needs {', '.join(missing)}")
    check_writable(output, force)
    try:
        load = KnownLoad(parse_vector(load_point, "--load-point"), parse_vector(load_n, "--load-n"))
    except SensingError as error:
        raise CalibrationError(str(error)) from error
    settings = load_settings(settings_file)
    robot = load_robot(robot_file)
    pose = read_calibration(calibration)
    with stderr.status("reading the loaded and reference frames..."):
        loaded = static_frames(recording, frames, robot)
        reference = [] if reference is None and reference_frames is None else static_frames(
            reference or recording, reference_frames, robot)
    with stderr.status("fitting Young's modulus...") as status:
        fit = fit_young_modulus(
            robot, pose.robot_from_camera, loaded, reference, load, settings,
            progress=lambda n, e: status.update(f"fitting Young's modulus: pass {n}, "
                                                f"{e:.4f} MPa"))
    document = json.loads(Path(calibration).read_text())
    document["material"] = fit.to_dict()
    atomic_write_text(output, json.dumps(document, indent=2) + "\n", force=force)
    if json_output:
        print_json(document["material"])
    else:
        table = Table(title="material", title_justify="left")
        for name in ("", "Young's modulus (MPa)", "95% interval", "sensed load (N)"):
            table.add_column(name, justify="right")
        table.add_row("robot file", f"{fit.nominal_young_modulus_mpa:.4f}", "",
                      f"{fit.nominal_estimate_n:.4f}")
        # one loaded frame whose load is smooth in E has no spread and no step to show
        interval = "none: one frame" if fit.ci95_mpa is None else \
            f"{fit.ci95_mpa[0]:.4f} to {fit.ci95_mpa[1]:.4f}"
        table.add_row("fitted", f"{fit.young_modulus_mpa:.4f}", interval,
                      f"{np.mean(fit.estimates_n):.4f} (known {fit.load_n:.4f})")
        stdout.print(table)
        stdout.print(f"{len(fit.estimates_n)} loaded frames{', tared' if fit.tared else ''}, "
                     f"element {fit.element}, law {fit.law}, {fit.passes} passes, fit RMS "
                     f"{fit.fit_rms_mm:.3f} mm")
    stderr.print(f"wrote [bold]{escape(str(output))}[/]")
