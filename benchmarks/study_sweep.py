"""Depth noise and feature count against sensing error and frame rate (issue 8's sweep).

    OPENBLAS_NUM_THREADS=1 python benchmarks/study_sweep.py   # ~12 min on 2 shared cores

The sample probes scenario (sample_data/scenarios/probes.toml: the locking-free P2 truth on
its own mesh, Neo-Hookean; unloaded, 0.15 N, 0.25 N, then 0.25 N + 0.2 N on two bars) is
recorded once per depth noise level (`[camera] noise_scale` in NOISE_SCALES), each loaded
state held HOLD_FRAMES frames, then the robot unloaded again (phantoms). The truth states do
not depend on the camera, so they are solved once and reused for every level
(sim.simulate's truth-state cache, kept on disk). The
estimator is sample_data/diamond/diamond_p2.toml (the coarse P2 robot) with `[features]
count` in FEATURE_COUNTS, sensing with `--tare 1 --updates 6` and the truth's camera pose
(a pose-only calibration, no material calibration), scored by estimation.truth_errors.

Variants: `--features 51 --noise 0 1` restrict the runs; `--tag NAME --set TABLE.KEY=VALUE`
(repeatable) senses with other settings, and `--placement faces` with the features on the
body's faces (docs/robot_model.md), into folders and a results file ending in _NAME,
leaving the default's results and the figure alone (docs/sensing_studies.md, "Why the probes read
high", compares force models this way).

Writes, under out/study_sweep/ (recordings, robot variants, sense outputs, cached), the
results to results.json, and the figure docs/figures/sensing_sweep.png, which
docs/sensing_studies.md ("Noise and feature-count sweep") quotes. Reruns reuse the recordings and
the sense runs already done (--resense runs them again).
"""

from __future__ import annotations

import argparse
import json
import pickle
import re
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from softforce_cli.estimation.session import run_sensing  # noqa: E402
from softforce_cli.estimation.setup import SenseInputs, prepare_sensing  # noqa: E402
from softforce_cli.estimation.truth_errors import compare_with_truth, pose_from_truth, read_truth  # noqa: E402
from softforce_cli.io.atomic import atomic_write_bytes, atomic_write_text  # noqa: E402
from softforce_cli.model.features import PLACEMENTS  # noqa: E402
from softforce_cli.sim.simulate import TruthCache, simulate  # noqa: E402

OUT = ROOT / "out" / "study_sweep"
FIGURE = ROOT / "docs" / "figures" / "sensing_sweep.png"
SCENARIO = ROOT / "sample_data" / "scenarios" / "probes.toml"
ESTIMATOR = ROOT / "sample_data" / "diamond" / "diamond_p2.toml"
NOISE_SCALES = (0.0, 0.5, 1.0, 2.0)
SEED = 3  # probes.toml's
# Other noise realisations at the D415's level (scale 1): how much of a difference between
# two cells one draw of the noise makes.
OTHER_SEEDS = (4, 5, 6)
FEATURE_COUNTS = (25, 51, 101, 151)
TARE_FRAMES = 1
UPDATES = 6
# Each loaded state is held this many frames (fresh sensor noise on each): P2's estimate
# settles over the first frames of a hold (docs/sensing_studies.md), and more frames give the error
# statistics more than one sample per state. With the final unloaded hold, 1 + 4 * 3 = 13
# frames: 12 true contacts, 3 frames without contact.
HOLD_FRAMES = 3


def scenario_text(noise_scale: float, width: int, height: int, seed: int = SEED) -> str:
    """probes.toml with its truth robot path made absolute, the camera's resolution and
    noise_scale set, each loaded state held HOLD_FRAMES frames, and the unloaded first
    state held again at the end (frames without contact, for phantoms: its truth state is
    the first one, reused)."""
    text = SCENARIO.read_text().replace('robot = "../', f'robot = "{SCENARIO.parent.parent}/')
    text = text.replace(f"\nseed = {SEED}\n", f"\nseed = {seed}\n")
    head, *frames = text.split("\n[[frame]]")
    camera = f"[camera]\nwidth = {width}\nheight = {height}\nnoise_scale = {noise_scale}\n"
    head = head[: head.index("[camera]")] + camera
    held = [f.replace("\nactuation", f"\nrepeat = {HOLD_FRAMES}\nactuation", 1)
            for f in [*frames[1:], frames[0]]]
    return "\n[[frame]]".join([head, frames[0], *held])


def recordings(width: int, height: int, scales: tuple[float, ...] = NOISE_SCALES
               ) -> dict[tuple[float, int], Path]:
    """One recording per noise level of `scales` (and per seed of OTHER_SEEDS at scale 1);
    the truth states solved for the first are kept in truth_states.pkl and reused for the
    others (and by later runs)."""
    OUT.mkdir(parents=True, exist_ok=True)
    cache_file = OUT / "truth_states.pkl"
    states: TruthCache = pickle.loads(cache_file.read_bytes()) if cache_file.exists() else {}
    paths = {}
    for scale, seed in [(scale, SEED) for scale in scales] + [
            (1.0, seed) for seed in OTHER_SEEDS if 1.0 in scales]:
        suffix = "" if seed == SEED else f"_seed{seed}"
        path = OUT / f"probes_{width}x{height}_noise{scale:g}{suffix}.mcap"
        if not path.exists():
            scenario = path.with_suffix(".toml")
            scenario.write_text(scenario_text(scale, width, height, seed))
            began, solved = time.perf_counter(), len(states)
            simulate(scenario, path, force=True, states=states)
            print(f"simulated {path.name} in {time.perf_counter() - began:.0f} s "
                  f"({len(states) - solved} truth states solved)", file=sys.stderr)
            if len(states) > solved:
                atomic_write_bytes(cache_file, pickle.dumps(states), force=True)
        paths[scale, seed] = path
    return paths


def robot_variant(count: int, placement: str = "spread") -> Path:
    """diamond_p2.toml with `[features] count` and `placement` set and its mesh path made
    absolute."""
    text = ESTIMATOR.read_text()
    text = text.replace('path = "diamond_coarse.vtu"',
                        f'path = "{ESTIMATOR.parent / "diamond_coarse.vtu"}"')
    text, replaced = re.subn(r"(?m)^count = \d+$", f'count = {count}\nplacement = "{placement}"',
                             text)
    assert replaced == 1, "diamond_p2.toml no longer sets [features] count on a line of its own"
    name = f"diamond_p2_features{count}" + ("" if placement == "spread" else f"_{placement}")
    path = OUT / f"{name}.toml"
    path.write_text(text)
    return path


def truth_pose(recording: Path) -> Path:
    """The camera pose of a simulated recording's truth as a pose-only calibration."""
    path = OUT / "pose.json"
    path.write_text(json.dumps(pose_from_truth(recording.with_suffix(".truth.json"))))
    return path


def sense_and_score(recording: Path, robot: Path, pose: Path, name: str,
                    overrides: dict | None = None) -> dict:
    """Sense a recording, compare it with its truth: the error summary, frame times.
    overrides: further {"table.key": value} settings (estimation.settings.load_settings)."""
    folder = OUT / name
    inputs = SenseInputs(recording=recording, robot=robot, calibration=pose, output=folder,
                         force=True, tare_frames=TARE_FRAMES,
                         overrides={"estimation.updates_per_frame": UPDATES,
                                    **(overrides or {})})
    prepared = prepare_sensing(inputs)
    cpu = time.process_time()
    run_sensing(prepared.frames, prepared.sensor, folder, prepared.header, force=True)
    cpu_s = time.process_time() - cpu
    document = json.loads((folder / "sense.json").read_text())
    comparison = compare_with_truth(document, read_truth(recording.with_suffix(".truth.json")))
    ok = [sum(f["timings_ms"].values()) for f in document["frames"] if f["status"] == "ok"]
    return {**comparison.summary(),
            "frame_ms_median": round(float(np.median(ok)), 1),
            "fps": round(1e3 / float(np.median(ok)), 3),
            "cpu_ms_per_frame": round(1e3 * cpu_s / len(document["frames"]), 1),
            "relinearizations": prepared.sensor.relinearizations}


def plot(results: list[dict], path: Path) -> None:
    """Location and intensity errors against noise, one line per feature count (the other
    seeds' draws at scale 1 as open markers); the frame rate against the feature count."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    main = [r for r in results if r["seed"] == SEED]
    for count in FEATURE_COUNTS:
        rows = sorted((r for r in main if r["features"] == count),
                      key=lambda r: r["noise_scale"])
        scales = [r["noise_scale"] for r in rows]
        line, = axes[0].plot(scales, [r["location_error_median_mm"] for r in rows], "o-",
                             label=f"{count} features")
        axes[1].plot(scales, [100 * r["intensity_error_median"] for r in rows], "o-",
                     color=line.get_color(), label=f"{count} features, median")
        axes[1].plot(scales, [100 * r["intensity_error_p90"] for r in rows], "s--",
                     color=line.get_color(), alpha=0.5, label=f"{count} features, 90th pct")
        others = [r for r in results if r["features"] == count and r["seed"] != SEED]
        axes[0].plot([r["noise_scale"] for r in others],
                     [r["location_error_median_mm"] for r in others], "o", mfc="none",
                     color=line.get_color())
        axes[1].plot([r["noise_scale"] for r in others],
                     [100 * r["intensity_error_median"] for r in others], "o", mfc="none",
                     color=line.get_color())
    for scale in NOISE_SCALES:
        rows = sorted((r for r in main if r["noise_scale"] == scale),
                      key=lambda r: r["features"])
        line, = axes[2].plot([r["features"] for r in rows],
                             [1e3 / r["cpu_ms_per_frame"] for r in rows], "o-",
                             label=f"noise x{scale:g}, per CPU second")
        axes[2].plot([r["features"] for r in rows], [r["fps"] for r in rows], "x:",
                     color=line.get_color(), alpha=0.6, label=f"noise x{scale:g}, wall median")
    axes[0].set(xlabel="depth noise scale (1 = D415)", ylabel="location error, median (mm)",
                title="Where (open: other noise seeds)", ylim=(0, None))
    axes[1].set(xlabel="depth noise scale (1 = D415)", ylabel="intensity error (%)",
                title="How hard (open: other noise seeds)", ylim=(0, None))
    axes[2].set(xlabel="feature points", ylabel="frames per second",
                title="Frame rate (the machine shared, load 2-5)", xticks=list(FEATURE_COUNTS),
                ylim=(0, None))
    for axis in axes:
        axis.grid(alpha=0.3)
        axis.legend(fontsize=6.5)
    fig.suptitle("Coarse P2 estimator vs the locking-free truth, probes at 640x480, "
                 "--tare 1 --updates 6, no material calibration", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--resense", action="store_true",
                        help="sense again even where a result is cached")
    parser.add_argument("--features", type=int, nargs="+", default=list(FEATURE_COUNTS),
                        help="feature counts to sense with (default: all)")
    parser.add_argument("--noise", type=float, nargs="+", default=None,
                        help="only the recordings of these noise scales (default: all)")
    parser.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE",
                        help="a sense setting for every run, e.g. estimation.force_model=normal "
                             "(the runs go to their own folders and results file with --tag)")
    parser.add_argument("--tag", default="",
                        help="name of this variant: its folders and results file end with it, "
                             "and the figure and results.json are left alone")
    parser.add_argument("--placement", default="spread", choices=PLACEMENTS,
                        help="the robot file's `[features] placement` (docs/robot_model.md)")
    args = parser.parse_args()
    overrides = dict(_setting(text) for text in args.set)
    if (overrides or args.placement != "spread") and not args.tag:
        parser.error("--set and --placement need --tag (a variant must not overwrite the "
                     "default's results)")
    paths = recordings(args.width, args.height,
                       NOISE_SCALES if args.noise is None else tuple(args.noise))
    pose = truth_pose(next(iter(paths.values())))
    suffix = f"_{args.tag}" if args.tag else ""
    cache_file = OUT / f"sense_results_{args.width}x{args.height}{suffix}.json"
    cached = {} if not cache_file.exists() else json.loads(cache_file.read_text())
    for count in args.features:
        robot = robot_variant(count, args.placement)
        for (scale, seed), recording in paths.items():
            key = f"features{count}_noise{scale:g}" + ("" if seed == SEED else f"_seed{seed}")
            if args.resense or key not in cached:
                began = time.perf_counter()
                cached[key] = {"features": count, "noise_scale": scale, "seed": seed,
                               **sense_and_score(recording, robot, pose, key + suffix,
                                                 overrides)}
                print(f"{key}: {time.perf_counter() - began:.0f} s {cached[key]}",
                      file=sys.stderr)
                atomic_write_text(cache_file, json.dumps(cached, indent=1), force=True)
    results = list(cached.values())
    if args.tag:
        print(json.dumps(results, indent=1))
        return
    document = {"resolution": [args.width, args.height], "estimator": str(ESTIMATOR),
                "scenario": str(SCENARIO), "hold_frames": HOLD_FRAMES,
                "tare_frames": TARE_FRAMES, "updates": UPDATES, "results": results}
    atomic_write_text(OUT / "results.json", json.dumps(document, indent=1), force=True)
    plot(results, FIGURE)
    print(json.dumps(document, indent=1))


def _setting(text: str) -> tuple[str, object]:
    """"estimation.force_model=normal" -> ("estimation.force_model", "normal"), numbers and
    booleans as such (TOML's syntax for the value)."""
    key, _, value = text.partition("=")
    try:
        return key, tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        return key, value


if __name__ == "__main__":
    main()
