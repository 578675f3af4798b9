"""Shared fixtures: the sample robot, and the third-party SOFA meshes when ../shared exists."""

from __future__ import annotations

from pathlib import Path

import pytest

from softforce_cli.fem.allocator import keep_freed_memory

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
SAMPLE_ROBOT_FINE = ROOT / "sample_data" / "diamond_fine" / "diamond.toml"
SOFA_DIAMOND = ROOT.parent / "shared" / "robots" / "diamond"

keep_freed_memory()


@pytest.fixture(scope="session")
def sample_robot():
    from softforce_cli.model.robot import load_robot

    return load_robot(SAMPLE_ROBOT)


@pytest.fixture(scope="session")
def sofa_diamond_dir() -> Path:
    if not (SOFA_DIAMOND / "diamond.toml").is_file():
        pytest.skip("../shared/robots/diamond (SOFA's meshes) is not present")
    return SOFA_DIAMOND
