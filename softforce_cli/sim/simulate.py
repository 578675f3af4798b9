"""A scenario -> a synthetic recording (MCAP) and its ground truth (`<name>.truth.json`).

For each state of the scenario the truth robot is solved, its deformed surface and the probes
and weights are ray cast by a virtual D415 above the robot, and the frame is written with its
actuation (and optional noisy marker observations). The ground truth never enters the
recording (docs/recordings.md).

A scenario's `[[effect]]` tables are concealed in the truth (docs/effects.md): physics
effects in the truth robot, actuation effects between the commanded and the received cable
displacement, sensor effects in the virtual camera (depth scaled, camera moved); the
recording carries the commanded actuation only, the truth file the effects and their values.
A state is solved again within a held frame when its effective actuation or (creep) its
modulus changes. Each new state is checked for a snap-through from the one before, which the
truth file marks and a SnapThroughWarning reports (docs/scenarios.md, "Snap-throughs").
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softforce_cli import __version__
from softforce_cli.camera.frame import Actuation, Markers, RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import ScenarioError, SoftforceError
from softforce_cli.fem.model import FEModel
from softforce_cli.io.atomic import atomic_write_text, check_writable
from softforce_cli.io.mcap_writer import write_recording
from softforce_cli.model.effect_physics import fe_model_with_effects
from softforce_cli.model.effects import (
    Effect,
    EffectError,
    FrameContext,
    camera_offset,
    check_targets,
    creep_factor,
    depth_scale,
    effective_actuation,
    effects_of_kind,
    frame_contexts,
)
from softforce_cli.model.regions import region_names
from softforce_cli.model.robot import Robot
from softforce_cli.sim.camera_pose import invert_pose, look_at, transform_points
from softforce_cli.sim.depth_noise import D415Noise, apply_d415
from softforce_cli.sim.ground_truth import (
    TruthState,
    return_separation,
    solve_frame,
    truth_robot,
)
from softforce_cli.sim.props import probe_surface, weight_surface
from softforce_cli.sim.render import RenderedView, SceneSurface, Spots, render, table_surface
from softforce_cli.sim.scenario import FrameSpec, Scenario, load_scenario


class SnapThroughWarning(UserWarning):
    """The truth robot passed a fold between two frames and jumped to another equilibrium."""


# The table is a square this big around the robot, large enough to fill the D415's view.
TABLE_HALF_SIZE_MM = 600.0
Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class SimulationResult:
    recording: Path
    truth: Path
    frames: int
    interrupted: bool


def truth_path_for(recording: Path) -> Path:
    """rec.mcap -> rec.truth.json, beside it."""
    return recording.with_name(recording.stem + ".truth.json")


@dataclass(frozen=True)
class Simulation:
    """A validated scenario, ready to run: its truth robot loaded, its outputs writable."""

    scenario: Scenario
    robot: Robot
    intrinsics: CameraIntrinsics
    world_from_cam: np.ndarray
    recording: Path
    truth: Path
    force: bool


def prepare_simulation(scenario_path: Path, output: Path, force: bool = False) -> Simulation:
    """Check the scenario, its truth robot and the outputs before any work is done."""
    scenario = load_scenario(scenario_path)
    output = Path(output)
    truth_file = truth_path_for(output)
    check_writable(output, force)
    check_writable(truth_file, force)
    robot = truth_robot(scenario)
    if len({spec.control for spec in robot.cable_specs}) > 1:
        raise ScenarioError(
            f"{robot.config.source}: the recording's actuation topic has one control mode; "
            "cables mixing displacement and force are not supported"
        )
    for index, frame in enumerate(scenario.frames):
        if len(frame.actuation) != len(robot.cable_specs):
            raise ScenarioError(
                f"{scenario.source}: frame[{index}] gives {len(frame.actuation)} actuation "
                f"values for the {len(robot.cable_specs)} cables of {robot.config.source}"
            )
    _check_effects(scenario, robot)
    camera = scenario.camera
    return Simulation(
        scenario=scenario,
        robot=robot,
        intrinsics=dataclasses.replace(CameraIntrinsics.from_fov(
            camera.width, camera.height, camera.horizontal_fov_deg
        ), distortion=camera.lens),
        world_from_cam=look_at(
            np.array(camera.position_mm), np.array(camera.look_at_mm), np.array(camera.up_hint)
        ),
        recording=output,
        truth=truth_file,
        force=force,
    )


def _check_effects(scenario: Scenario, robot: Robot) -> None:
    """ScenarioError when a concealed effect targets a cable or region the truth robot lacks,
    or acts on a force-controlled cable's displacement."""
    try:
        check_targets(scenario.effects, [c.name for c in robot.cable_specs], region_names(robot))
    except EffectError as error:
        raise ScenarioError(f"{scenario.source}: {error}") from error
    controls = {c.name: c.control for c in robot.cable_specs}
    for effect in effects_of_kind(scenario.effects, "actuation"):
        if controls[effect.target] != "displacement":
            raise ScenarioError(f"{scenario.source}: {effect.name} acts on a cable's "
                                f"displacement; cable {effect.target!r} is force-controlled")


@dataclass(frozen=True)
class FramePlan:
    """Every recorded frame of a scenario, repeats expanded.

    spec_index : (n,) the scenario frame ([[frame]]) each recorded frame comes from.
    times_s    : (n,) frame times, s (frame_interval_s apart).
    commanded  : (n, a) the actuation the recording carries.
    effective  : (n, a) what the body receives after the actuation effects.
    contexts   : per frame, for the history effects.
    """

    spec_index: np.ndarray
    times_s: np.ndarray
    commanded: np.ndarray
    effective: np.ndarray
    contexts: list[FrameContext]


def frame_plan(scenario: Scenario, cable_names: tuple[str, ...]) -> FramePlan:
    """The recorded frames of a scenario, with their effective actuation."""
    spec_index = np.repeat(np.arange(len(scenario.frames)),
                           [frame.repeat for frame in scenario.frames])
    commanded = np.array([scenario.frames[i].actuation for i in spec_index],
                         dtype=float).reshape(len(spec_index), len(cable_names))
    times = np.arange(len(spec_index)) * scenario.frame_interval_s
    contexts = frame_contexts(times, commanded)
    actuation_effects = effects_of_kind(scenario.effects, "actuation")
    effective = (effective_actuation(actuation_effects, contexts, cable_names)
                 if actuation_effects else commanded)
    return FramePlan(spec_index, times, commanded, effective, contexts)


# Solved truth states by what determines them: a scenario frame (its effective actuation
# and loads; repeat set to 1) and the creep modulus factor. Valid for one truth robot (file,
# law, physics effects): a study reusing the states across scenarios that differ only in
# their camera (noise, resolution, pose) passes the same dict to each run_simulation.
TruthCache = dict[tuple[FrameSpec, float], TruthState]


def run_simulation(
    simulation: Simulation, progress: Progress | None = None, states: TruthCache | None = None
) -> SimulationResult:
    """Solve, render and write every frame, then the truth file. Ctrl-C keeps what is done.

    `states`, when given, supplies truth states solved before (for the same truth robot) and
    receives those solved now, so the expensive solve is not repeated across recordings (nor
    for a state the scenario returns to). Without it every change of state is solved from
    the previous one, as always.
    """
    truth_frames: list[dict] = []
    written = [0]

    def counted(frames: Iterator[RgbdFrame]) -> Iterator[RgbdFrame]:
        for frame in frames:
            yield frame
            written[0] += 1  # the writer asks for the next frame once this one is written

    frames = _frames(
        simulation.scenario,
        simulation.robot,
        simulation.intrinsics,
        simulation.world_from_cam,
        truth_frames,
        progress,
        states,
    )
    try:
        result = write_recording(
            counted(frames),
            simulation.recording,
            force=simulation.force,
            stop_on_interrupt=True,
            metadata={"scenario": simulation.scenario.source.name},
        )
    except SoftforceError as error:
        # write_recording kept the frames written before the error: their truth goes with
        # them (a recording without it, or with an earlier run's, would mislead)
        if written[0]:
            _write_truth(simulation, truth_frames[: written[0]])
            error.args = (f"{error} (the {written[0]} frame(s) before it are kept in "
                          f"{simulation.recording}, their truth in {simulation.truth})",)
        raise
    if result.interrupted and result.frames == 0:
        raise KeyboardInterrupt  # stopped before the first frame: no recording, so no truth
    _write_truth(simulation, truth_frames[: result.frames])
    return SimulationResult(
        simulation.recording, simulation.truth, result.frames, result.interrupted
    )


def _write_truth(simulation: Simulation, truth_frames: list[dict]) -> None:
    document = _truth_document(
        simulation.scenario,
        simulation.robot,
        simulation.intrinsics,
        simulation.world_from_cam,
        truth_frames,
    )
    atomic_write_text(simulation.truth, json.dumps(document, indent=1), force=simulation.force)


def simulate(
    scenario_path: Path,
    output: Path,
    force: bool = False,
    progress: Progress | None = None,
    states: TruthCache | None = None,
) -> SimulationResult:
    """prepare_simulation, then run_simulation."""
    return run_simulation(prepare_simulation(scenario_path, output, force), progress, states)


def _frames(
    scenario: Scenario,
    robot: Robot,
    intrinsics: CameraIntrinsics,
    world_from_cam: np.ndarray,
    truth_frames: list[dict],
    progress: Progress | None,
    states: TruthCache | None,
) -> Iterator[RgbdFrame]:
    rng = np.random.default_rng(scenario.seed)
    noise = D415Noise().scaled(scenario.camera.noise_scale) if scenario.camera.noise else None
    # the camera truly stands where the concealed extrinsic offset puts it
    actual_world_from_cam = world_from_cam @ camera_offset(scenario.effects).as_matrix()
    cam_from_world = invert_pose(actual_world_from_cam)
    names = tuple(spec.name for spec in robot.cable_specs)
    control = robot.cable_specs[0].control if names else "displacement"
    plan = frame_plan(scenario, names)
    creep = any(e.name == "viscoelastic_creep" for e in scenario.effects)

    def model_of(context: FrameContext) -> FEModel | None:
        return fe_model_with_effects(robot, robot.effects, context) if creep else None

    state: TruthState | None = None
    solved_key = None
    solved_with: tuple[FrameSpec, FrameContext] | None = None
    snapped = False  # past a snap-through the body's states depend on its path: no cache
    for index, spec_index in enumerate(plan.spec_index):
        frame = scenario.frames[spec_index]
        context = plan.contexts[index]
        modulus = creep_factor(scenario.effects, context.hold_s) if creep else 1.0
        key = (int(spec_index), tuple(plan.effective[index]), modulus)
        snap_mm = None
        if key != solved_key:  # a new [[frame]], or the effects changed the state in a hold
            # repeat=1: how long a state is held does not change it, so holds share it
            effective = dataclasses.replace(frame, actuation=tuple(plan.effective[index]),
                                            repeat=1)
            if states is not None and not snapped and (effective, modulus) in states:
                state = states[effective, modulus]
            else:
                left = state
                try:
                    state = solve_frame(robot, effective,
                                        None if left is None else left.equilibrium,
                                        model_of(context),
                                        () if solved_with is None else solved_with[0].loads)
                except ScenarioError as error:
                    raise ScenarioError(f"frame {index} ({index * scenario.frame_interval_s:g}"
                                        f" s): {error}") from error
                if left is not None and solved_with is not None:
                    snap_mm = _snap_through(robot, solved_with, model_of, left, effective,
                                            state, index, scenario.frame_interval_s)
                    snapped = snapped or snap_mm is not None
                if states is not None and not snapped:
                    states[effective, modulus] = state
            solved_with = (effective, context)
            view = _biased(render(_scene(scenario, robot, state), intrinsics,
                                  actual_world_from_cam, ambient=scenario.scene.ambient,
                                  light_direction=scenario.scene.light_direction,
                                  specular=scenario.scene.specular,
                                  shininess=scenario.scene.shininess),
                           depth_scale(scenario.effects))
            markers_robot = robot.marker_points.positions(state.equilibrium.positions_mm)
            markers_cam = (transform_points(cam_from_world, markers_robot)
                           if len(markers_robot) else markers_robot)
            solved_key = key
        depth, color = _sensor(view, intrinsics, rng, noise)
        # a marker is located in the depth image: a depth scale moves it along its ray
        observed = markers_cam * depth_scale(scenario.effects) + (
            scenario.marker_sigma_mm * rng.standard_normal(markers_cam.shape))
        time_ns = round(index * scenario.frame_interval_s * 1e9)
        record = _truth_frame(index, time_ns, robot, frame.actuation, state, markers_robot,
                              markers_cam, observed)
        if scenario.effects:
            record["effects"] = {
                "effective_actuation": _rounded(plan.effective[index]),
                "hold_s": round(context.hold_s, 9),
                "modulus_factor": round(modulus, 9),
            }
        if snap_mm is not None:
            record["snap_through_mm"] = round(snap_mm, 3)
        # the truth goes in before the frame is handed out: a Ctrl-C after the writer has
        # taken the frame must find its truth (run_simulation keeps as many as were written)
        truth_frames.append(record)
        yield RgbdFrame(
            time_ns=time_ns,
            color=color,
            depth_mm=depth,
            intrinsics=intrinsics,
            actuation=Actuation(names, control, np.array(frame.actuation, dtype=float)),
            markers=Markers(robot.marker_ids, observed) if scenario.publish_markers else None,
        )
        if progress is not None:
            progress(index + 1, scenario.frame_count)


def _snap_through(robot: Robot, solved_with: tuple[FrameSpec, FrameContext],
                  model_of: Callable[[FrameContext], FEModel | None], left: TruthState,
                  frame: FrameSpec, reached: TruthState, index: int,
                  interval_s: float) -> float | None:
    """mm: how far from the state the truth left (solved with `solved_with`) the way back
    from the state it reached at frame `index` (under `frame`) ends, when the body snapped
    through between them (ground_truth.return_separation), with a SnapThroughWarning; None
    when it did not."""
    before, context = solved_with
    separation = return_separation(robot, before, model_of(context), left, frame, reached)
    if separation == 0.0:
        return None
    warnings.warn(SnapThroughWarning(
        f"frame {index} ({index * interval_s:g} s): the truth robot snapped through to "
        f"another equilibrium (under the loads of the frame before, it has two, "
        f"{separation:.1f} mm apart): the recording shows a jump, not a smooth motion, and "
        "the frames after it depend on the path"), stacklevel=2)
    return separation


def _biased(view: RenderedView, scale: float) -> RenderedView:
    """The view with its depth scaled by a concealed depth_bias (itself when scale is 1)."""
    return view if scale == 1.0 else dataclasses.replace(view, depth_mm=view.depth_mm * scale)


def _scene(scenario: Scenario, robot: Robot, state: TruthState) -> list[SceneSurface]:
    colours = scenario.scene
    stickers = None if scenario.sticker_rgb is None else Spots(
        robot.rest_nodes_mm, robot.marker_points.positions(robot.rest_nodes_mm),
        scenario.sticker_radius_mm, np.array(scenario.sticker_rgb))
    surfaces = [
        SceneSurface(
            "robot",
            state.equilibrium.positions_mm,
            robot.mesh.surface_faces,
            np.array(colours.robot_rgb),
            smooth=True,
            spots=stickers,
        ),
        table_surface(colours.table_z_mm, TABLE_HALF_SIZE_MM, np.array(colours.table_rgb)),
    ]
    for i, contact in enumerate(state.contacts):
        if contact.kind == "probe":
            surfaces.append(
                probe_surface(contact.point_mm, contact.force_n, colours.probe_rgb, f"probe{i}")
            )
        else:
            surfaces.append(weight_surface(contact.point_mm, colours.weight_rgb, f"weight{i}"))
    return surfaces


def _sensor(
    view: RenderedView, intrinsics: CameraIntrinsics, rng: np.random.Generator,
    noise: D415Noise | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The D415's images of a view; None: ideal depth (rounded to mm) and colours."""
    if noise is not None:
        return apply_d415(view, intrinsics, rng, noise)
    return np.rint(view.depth_mm).astype(np.uint16), view.color


def _rounded(array: np.ndarray, digits: int = 5) -> list:
    return np.round(np.asarray(array, dtype=float), digits).tolist()


def _truth_frame(
    index: int,
    time_ns: int,
    robot: Robot,
    actuation: tuple[float, ...],
    state: TruthState,
    markers_robot: np.ndarray,
    markers_cam: np.ndarray,
    observed: np.ndarray,
) -> dict:
    equilibrium = state.equilibrium
    return {
        "index": index,
        "log_time_ns": time_ns,
        "time_s": time_ns * 1e-9,
        "actuation": {
            "names": [c.name for c in robot.cable_specs],
            "control": [c.control for c in robot.cable_specs],
            "values": list(actuation),
        },
        "cable_tensions_n": _rounded(equilibrium.cable_tensions_n, 7),
        "cable_displacements_mm": _rounded(equilibrium.cable_shortenings_mm),
        "contacts": [
            {
                "kind": c.kind,
                "point_mm": _rounded(c.point_mm),
                "rest_point_mm": _rounded(c.rest_point_mm),
                "force_n": _rounded(c.force_n, 7),
                "magnitude_n": round(float(np.linalg.norm(c.force_n)), 7),
                "normal": _rounded(c.normal),
            }
            for c in state.contacts
        ],
        "markers": {
            marker_id: {
                "robot_mm": _rounded(markers_robot[i]),
                "camera_mm": _rounded(markers_cam[i]),
                "observed_camera_mm": _rounded(observed[i]),
            }
            for i, marker_id in enumerate(robot.marker_ids)
        },
    }


def _truth_document(
    scenario: Scenario,
    robot: Robot,
    intrinsics: CameraIntrinsics,
    world_from_cam: np.ndarray,
    frames: list[dict],
) -> dict:
    actual = world_from_cam @ camera_offset(scenario.effects).as_matrix()
    return {
        "softforce_version": __version__,
        "scenario": scenario.source.name,
        "truth_model": {
            "robot": scenario.robot.name,
            "law": robot.material.law,
            "element": robot.element_name,
            "tetrahedra": robot.mesh.tet_count,
            "nodes": robot.mesh.node_count,
        },
        "camera": {
            "intrinsics": {
                "width": intrinsics.width,
                "height": intrinsics.height,
                "fx": intrinsics.fx,
                "fy": intrinsics.fy,
                "cx": intrinsics.cx,
                "cy": intrinsics.cy,
                "distortion": None if intrinsics.distortion is None else {
                    "model": intrinsics.distortion.model,
                    "coefficients": list(intrinsics.distortion.coefficients)},
            },
            # p_robot = R p_cam + T, the transform calibration estimates (docs/robot_model.md)
            "rotation": _rounded(world_from_cam[:3, :3], 12),
            "translation_mm": _rounded(world_from_cam[:3, 3], 9),
            # where the camera truly stood: moved by a concealed extrinsic_offset, if any
            "actual_rotation": _rounded(actual[:3, :3], 12),
            "actual_translation_mm": _rounded(actual[:3, 3], 9),
            "noise": scenario.camera.noise,
            "noise_scale": scenario.camera.noise_scale,
            "marker_sigma_mm": scenario.marker_sigma_mm,
        },
        # what the recording hides (docs/effects.md): only tests and studies read it
        "concealed_effects": [_effect_record(effect) for effect in scenario.effects],
        "frames": frames,
    }


def _effect_record(effect: Effect) -> dict:
    return {
        "name": effect.name,
        "kind": effect.spec.kind,
        "target": effect.target,
        "parameters": {
            p.name: {"value": effect[p.name], "unit": p.unit} for p in effect.spec.parameters
        },
    }
