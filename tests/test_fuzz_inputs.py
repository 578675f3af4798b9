"""Fuzz: mutated robot files, meshes, scenarios, marker CSV, actuation CSV, calibration JSON.

TOML files are parsed, mutated at a random key (deleted, renamed, given another type, a unit
in a string, a value scaled by 1000, NaN, infinity, a huge or negative number, an unknown key
beside it) and written back; text files also get byte-level damage (cuts, flipped bytes,
invalid UTF-8, garbage lines). Robot files and meshes go through `softforce model show`,
scenarios through `softforce simulate` (with the simulation itself replaced by a no-op: a
valid mutant costs only its validation, the part that reads the file), actuation CSV through
`softforce record --actuation`, marker CSV and calibration JSON through their readers. Each
case must end in one clean error line or exit 0 (see tests/test_fuzz_harness.py).
"""

from __future__ import annotations

import copy
import json
import math
import random
import re
import shutil
import tomllib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from softforce_cli.calibration.markers_csv import read_markers_csv
from softforce_cli.calibration.result import FORMAT, read_calibration
from tests.test_fuzz_harness import call_reader, classify, fuzz_cases, report, run_cli

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
SCENARIOS = sorted((ROOT / "sample_data" / "scenarios").glob("*.toml"))
ODD_VALUES = ["text", "5 mm", "", 0, -1, 0.0, -0.0, 1e300, -1e300, math.nan, math.inf,
              -math.inf, 10**12, True, [], [1.0, 2.0], [[1.0]], {"a": 1}, {}]

# --- a small TOML writer (tomllib reads only) -------------------------------------------


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") \
            if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"


def dump_toml(document: dict) -> str:
    lines, tables = [], []
    for key, value in document.items():
        if isinstance(value, dict):
            tables.append(f"\n[{_key(key)}]")
            tables += [f"{_key(k)} = {_value(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                tables.append(f"\n[[{_key(key)}]]")
                tables += [f"{_key(k)} = {_value(v)}" for k, v in item.items()]
        else:
            lines.append(f"{_key(key)} = {_value(value)}")
    return "\n".join(lines + tables) + "\n"


def _places(node, path=()):
    """Every (container, key) pair of a parsed document, depth first."""
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for key, value in items:
        yield node, key, (*path, key)
        if isinstance(value, dict | list):
            yield from _places(value, (*path, key))


def mutate_document(document: dict, rng: random.Random) -> dict:
    """A copy of `document` with one to three random mutations of keys, types and values."""
    document = copy.deepcopy(document)
    for _ in range(rng.randint(1, 3)):
        places = list(_places(document))
        container, key, _ = rng.choice(places)
        value = container[key]
        operation = rng.choice(["delete", "rename", "type", "scale", "unit", "extra", "empty"])
        if operation == "delete":
            if isinstance(container, dict):
                del container[key]
            elif len(container) > 1:
                container.pop(key)
        elif operation == "rename" and isinstance(container, dict):
            container[f"{key}{rng.choice(['s', '_', 'x'])}"] = container.pop(key)
        elif operation == "scale" and isinstance(value, int | float) and not isinstance(
                value, bool):
            container[key] = value * rng.choice([1000, 0.001, -1, 0])
        elif operation == "unit" and isinstance(value, int | float) and not isinstance(
                value, bool):
            container[key] = f"{value} {rng.choice(['mm', 'N', 'MPa', 'kg', 'm'])}"
        elif operation == "extra" and isinstance(container, dict):
            container[rng.choice(["units", "comment", "Young", "mass"])] = rng.choice(ODD_VALUES)
        elif operation == "empty" and isinstance(value, list | dict):
            container[key] = type(value)()
        else:
            container[key] = copy.deepcopy(rng.choice(ODD_VALUES))
    return document


def damage_text(text: str, rng: random.Random) -> bytes:
    """Byte-level damage: a cut, flipped bytes, invalid UTF-8, a garbage line or a NUL."""
    data = bytearray(text.encode())
    operation = rng.choice(["cut", "flip", "utf8", "garbage", "nul", "empty"])
    if operation == "cut":
        return bytes(data[: rng.randrange(len(data))])
    if operation == "flip":
        for _ in range(rng.randint(1, 5)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    elif operation == "utf8":
        data[rng.randrange(len(data))] = 0xFF
    elif operation == "garbage":
        at = text.find("\n", rng.randrange(len(text))) + 1
        junk = "".join(rng.choice("[]{}=,\"'#x1.e- \t") for _ in range(rng.randint(1, 40)))
        data[at:at] = (junk + "\n").encode()
    elif operation == "nul":
        data[rng.randrange(len(data))] = 0
    else:
        return b""
    return bytes(data)


def mutated_text(text: str, rng: random.Random) -> bytes:
    if rng.random() < 0.75:
        return dump_toml(mutate_document(tomllib.loads(text), rng)).encode()
    return damage_text(text, rng)


# --- robot files and meshes --------------------------------------------------------------


@pytest.fixture(scope="module")
def robot_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("robot")
    shutil.copy(ROBOT.with_name("diamond_coarse.vtu"), folder)
    return folder


def test_mutated_robot_files(robot_dir):
    text, counts = ROBOT.read_text(), Counter()
    rng = random.Random("robot")
    for case in range(fuzz_cases(50)):
        path = robot_dir / f"robot{case}.toml"
        path.write_bytes(mutated_text(text, rng))
        counts[classify(run_cli("model", "show", path, "--json"))] += 1
        path.unlink()
    report("robot TOML", counts)
    assert counts["error"] > 0.5 * sum(counts.values())  # most mutants are invalid


def test_damaged_mesh_files(robot_dir):
    mesh = ROBOT.with_name("diamond_coarse.vtu").read_bytes()
    counts, rng = Counter(), random.Random("mesh")
    for case in range(fuzz_cases(20)):
        folder = robot_dir / f"mesh{case}"
        folder.mkdir()
        shutil.copy(ROBOT, folder)
        (folder / "diamond_coarse.vtu").write_bytes(
            damage_text(mesh.decode("latin-1"), rng) if case % 2 else
            mesh[: rng.randrange(len(mesh))])
        counts[classify(run_cli("model", "show", folder / "diamond.toml", "--json"))] += 1
        shutil.rmtree(folder)
    report("mesh file (.vtu)", counts)


# --- scenarios ---------------------------------------------------------------------------


def test_mutated_scenarios(tmp_path, monkeypatch):
    import softforce_cli.sim.simulate as simulate

    def validated_only(simulation, progress=None):
        return simulate.SimulationResult(simulation.recording, simulation.truth, 0, False)

    monkeypatch.setattr(simulate, "run_simulation", validated_only)
    counts, rng = Counter(), random.Random("scenario")
    for case in range(fuzz_cases(30)):
        source = SCENARIOS[case % len(SCENARIOS)]
        # the robot path is relative to the scenario: make it absolute for the copy
        robot = (source.parent / tomllib.loads(source.read_text())["robot"]).resolve()
        text = re.sub(r'^robot = ".*"$', f'robot = "{robot}"', source.read_text(), flags=re.M)
        path = tmp_path / f"scenario{case}.toml"
        path.write_bytes(mutated_text(text, rng))
        outcome = run_cli("simulate", path, "-o", tmp_path / f"out{case}.mcap")
        counts[classify(outcome)] += 1
    report("scenario TOML", counts)
    assert counts["error"] > 0.3 * sum(counts.values())


# --- CSV and JSON ------------------------------------------------------------------------

MARKERS_CSV = "id,x_mm,y_mm,z_mm\n# camera frame\napex,1.5,-20.25,410.0\ntip,30,40,420\n"
ACTUATION_CSV = "time_s,north_mm,west_mm\n0.0,0,0\n# hold\n2.5,5,5.5\n4.0,1e1,0\n"
CSV_ODD_CELLS = ["", "nan", "inf", "-inf", "1e999", "x", "5mm", "1,5", '"', "0x10", "  ",
                 "id", "time_s", "\u00e9", "1" * 400]


def garbage_csv(text: str, rng: random.Random) -> bytes:
    """Mutated CSV: odd cells, dropped or extra cells and rows, shuffled rows, byte damage."""
    if rng.random() < 0.3:
        return damage_text(text, rng)
    rows = [line.split(",") for line in text.splitlines()]
    for _ in range(rng.randint(1, 3)):
        row = rng.choice(rows)
        operation = rng.choice(["cell", "drop", "add", "shuffle", "duplicate", "header"])
        if operation == "cell":
            row[rng.randrange(len(row))] = rng.choice(CSV_ODD_CELLS)
        elif operation == "drop" and len(row) > 1:
            row.pop(rng.randrange(len(row)))
        elif operation == "add":
            row.append(rng.choice(CSV_ODD_CELLS))
        elif operation == "shuffle":
            rng.shuffle(rows)
        elif operation == "duplicate":
            rows.append(list(row))
        else:
            rows[0] = [rng.choice(CSV_ODD_CELLS) for _ in rows[0]]
    return ("\n".join(",".join(row) for row in rows) + "\n").encode()


def test_garbage_marker_csv(tmp_path):
    counts, rng = Counter(), random.Random("markers")
    for case in range(fuzz_cases(100)):
        path = tmp_path / f"m{case}.csv"
        path.write_bytes(garbage_csv(MARKERS_CSV, rng))
        counts[call_reader(read_markers_csv, path)] += 1
    report("marker CSV", counts)


def test_garbage_actuation_csv(tmp_path):
    """`softforce record --actuation` reads the CSV before opening the (here missing) source,
    so a valid mutant ends in the clean "does not exist" error of the .db3."""
    counts, rng = Counter(), random.Random("actuation")
    for case in range(fuzz_cases(60)):
        path = tmp_path / f"a{case}.csv"
        path.write_bytes(garbage_csv(ACTUATION_CSV, rng))
        outcome = run_cli("record", "--from", tmp_path / "missing.db3", "-o",
                          tmp_path / "out.mcap", "--actuation", path)
        kind = classify(outcome)
        counts["error (the CSV)" if f"{path}" in " ".join(outcome.stderr.split())
               or path.name in outcome.stderr else kind] += 1
    report("actuation CSV", counts)


def calibration_document() -> dict:
    angle = 0.3
    rotation = [[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0],
                [0.0, 0.0, 1.0]]
    return {
        "format": FORMAT, "version": 1, "robot": {"name": "diamond", "file": "diamond.toml"},
        "source": "markers.csv", "rotation": rotation, "translation_mm": [1.0, 2.0, 400.0],
        "actuation": {"names": ["north", "west"], "controls": ["displacement"] * 2,
                      "control": "displacement", "values": [1.0, 2.0],
                      "tensions_n": [0.1, 0.2], "slack": [False, False]},
        "residual_rms_mm": 0.5, "residual_history_mm": [2.0, 0.5],
        "markers": [{"id": "apex", "observed_camera_mm": [0.0, 0.0, 400.0],
                     "model_robot_mm": [0.0, 0.0, 126.0], "residual_vector_mm": [0.1, 0.0, 0.0],
                     "used": True, "outlier": False, "left_out_mm": None}],
        "unobserved": [], "converged": True,
        "settings": {"outer_iterations": 5, "inner_iterations": 4},
        "elapsed_s": 1.5, "warnings": [], "robust": False,
    }


def test_garbage_calibration_json(tmp_path):
    base = calibration_document()
    path = tmp_path / "base.json"
    path.write_text(json.dumps(base))
    read_calibration(path)  # the unmutated document is valid: mutants start from a good one
    counts, rng = Counter(), random.Random("calibration")
    for case in range(fuzz_cases(100)):
        path = tmp_path / f"c{case}.json"
        if rng.random() < 0.8:
            document = mutate_document(base, rng)
            text = json.dumps(document, default=float).replace("NaN", rng.choice(
                ["NaN", "1e999", "null"]))
            path.write_text(text)
        else:
            path.write_bytes(damage_text(json.dumps(base, indent=1), rng))
        counts[call_reader(read_calibration, path)] += 1
    report("calibration JSON", counts)
    assert np.isfinite(sum(counts.values()))
