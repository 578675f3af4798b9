"""Shared fixtures: the sample robot, and the third-party SOFA meshes when ../shared exists."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from softforce_cli.fem.allocator import keep_freed_memory

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
SAMPLE_ROBOT_FINE = ROOT / "sample_data" / "diamond_fine" / "diamond.toml"
SOFA_DIAMOND = ROOT.parent / "shared" / "robots" / "diamond"

keep_freed_memory()


def sample_probes_scenario(width: int, height: int, frames: int | None = None) -> str:
    """sample_data/scenarios/probes.toml at another resolution, its first `frames` frames
    (None: all), with its truth robot by absolute path so that a copy anywhere reads it."""
    folder = ROOT / "sample_data" / "scenarios"
    source = (folder / "probes.toml").read_text()
    relative = re.search(r'^robot = "(.+)"$', source, re.MULTILINE).group(1)
    if frames is not None:
        starts = [m.start() for m in re.finditer(r"^\[\[frame\]\]", source, re.MULTILINE)]
        source = source[:starts[frames]] if frames < len(starts) else source
    return (source.replace(f'"{relative}"', json.dumps((folder / relative).resolve().as_posix()))
            .replace("width = 424", f"width = {width}")
            .replace("height = 240", f"height = {height}"))


@pytest.fixture(scope="session")
def sample_robot():
    from softforce_cli.model.robot import load_robot

    return load_robot(SAMPLE_ROBOT)


@pytest.fixture(scope="session")
def sofa_diamond_dir() -> Path:
    if not (SOFA_DIAMOND / "diamond.toml").is_file():
        pytest.skip("../shared/robots/diamond (SOFA's meshes) is not present")
    return SOFA_DIAMOND
