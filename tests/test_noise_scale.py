"""`[camera] noise_scale`: the virtual D415's depth noise, scaled, on a tiny scene.

The camera looks straight down from 580 mm at a table at z = -37.5 mm, so every table pixel
sees the plane at the analytic depth 617.5 mm; the measured spread there is compared with
Intel's stereo formula sigma_z = z^2 * subpixel / (f * baseline) times the scale, plus the
1 mm quantisation. The truth robot is the coarse P1 sample robot at rest (one cheap solve,
shared through the truth-state cache), not the P2 truth.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.errors import ScenarioError
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.sim.scenario import load_scenario
from softforce_cli.sim.simulate import simulate
from tests.cli_runner import assert_one_line_error, softforce
from tests.conftest import ROOT

ROBOT = ROOT / "sample_data" / "diamond" / "diamond.toml"
WIDTH, HEIGHT = 160, 120
TABLE_DEPTH_MM = 580.0 + 37.5
# the D415 parameters of docs/virtual_camera.md: subpixel 0.08 px, baseline 55 mm
SUBPIXEL_PX, BASELINE_MM = 0.08, 55.0


def scenario(folder: Path, camera_lines: str, name: str) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(
        f'robot = "{ROBOT}"\nseed = 7\n[camera]\nwidth = {WIDTH}\nheight = {HEIGHT}\n'
        f"{camera_lines}\n[[frame]]\nactuation = [0.0, 0.0, 0.0, 0.0]\n"
    )
    return path


@pytest.fixture(scope="module")
def depths(tmp_path_factory) -> dict[str, np.ndarray]:
    """One frame's depth (and colour) per camera setting, one truth solve for all."""
    folder = tmp_path_factory.mktemp("noise_scale")
    states: dict = {}
    images = {}
    settings = {"default": "", "ideal": "noise = false", "x0": "noise_scale = 0",
                "x0.5": "noise_scale = 0.5", "x1": "noise_scale = 1.0", "x2": "noise_scale = 2"}
    for name, lines in settings.items():
        result = simulate(scenario(folder, lines, name), folder / f"{name}.mcap", states=states)
        frame = next(iter_frames(result.recording))
        images[name] = frame.depth_mm
        images[name + "_color"] = frame.color
    assert len(states) == 1  # solved once, reused by the other recordings
    return images


def test_default_scale_gives_bit_identical_images(depths):
    np.testing.assert_array_equal(depths["x1"], depths["default"])
    np.testing.assert_array_equal(depths["x1_color"], depths["default_color"])


def test_depth_noise_on_a_flat_patch_scales_as_asked(depths):
    # table pixels: the noise-free image reads the plane's depth, rounded, and every noisy
    # image has a value there (the holes are drawn identically at every scale)
    table = np.abs(depths["x0"].astype(float) - TABLE_DEPTH_MM) <= 0.5
    assert table.sum() > 0.4 * WIDTH * HEIGHT
    for name in ("x0.5", "x1", "x2"):
        np.testing.assert_array_equal(depths[name] == 0, depths["x0"] == 0)
    fx = CameraIntrinsics.from_fov(WIDTH, HEIGHT, 69.0).fx
    sigma = TABLE_DEPTH_MM**2 * SUBPIXEL_PX / (fx * BASELINE_MM)  # about 4.8 mm here
    for name, scale in (("x0.5", 0.5), ("x1", 1.0), ("x2", 2.0)):
        error = depths[name][table].astype(float) - TABLE_DEPTH_MM
        expected = np.sqrt((scale * sigma) ** 2 + 1 / 12)  # plus rounding to whole mm
        # about 17,000 pixels: the sample standard deviation is within 0.6% (1 sigma) of it
        assert error.std() == pytest.approx(expected, rel=0.03), name
        assert abs(error.mean()) < 0.05 * expected, name


def test_zero_scale_leaves_holes_and_quantisation_only(depths):
    """Scale 0: the ideal depth rounded to whole mm (what `noise = false` records) wherever
    the sensor model does not punch a hole; the holes stay."""
    valid = depths["x0"] > 0
    np.testing.assert_array_equal(depths["x0"][valid], depths["ideal"][valid])
    assert np.count_nonzero(depths["ideal"][~valid]) > 0.02 * WIDTH * HEIGHT


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        ("noise_scale = -1", "camera.noise_scale must be >= 0, got -1"),
        ('noise_scale = "high"', "camera.noise_scale must be a finite number"),
        ("noise_scale = nan", "camera.noise_scale must be a finite number"),
        ("noise = false\nnoise_scale = 2", "noise = false turns off"),
    ],
)
def test_bad_noise_scale_is_one_clear_error(tmp_path, lines, message):
    path = scenario(tmp_path, lines, "bad")
    with pytest.raises(ScenarioError, match=re.escape(message)):
        load_scenario(path)


def test_bad_noise_scale_from_the_command_line(tmp_path):
    result = softforce("simulate", scenario(tmp_path, "noise_scale = -0.5", "bad"),
                       "-o", tmp_path / "bad.mcap")
    assert_one_line_error(result, "camera.noise_scale must be >= 0")
    assert not (tmp_path / "bad.mcap").exists()
