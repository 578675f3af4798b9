"""Lens distortion (camera.lens) and rectification (camera.rectification).

References: librealsense's own projection (pyrealsense2.rs2_project_point_to_pixel, the
function its depth-to-colour alignment uses) for its four models, OpenCV's rational formula
evaluated by hand, and a pinhole render of the same scene for the rectified image.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pyrealsense2 as rs
import pytest

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.camera.intrinsics import CameraIntrinsics, points_from_depth
from softforce_cli.camera.lens import LensDistortion, LensModelError, distort, undistort
from softforce_cli.camera.realsense import intrinsics_from_rs
from softforce_cli.camera.rectification import rectification_map, rectified
from softforce_cli.errors import RecordingError
from softforce_cli.io.mcap_reader import RecordingWarning, iter_frames, read_summary
from softforce_cli.io.mcap_writer import RecordingWriter
from softforce_cli.sim.render import SceneSurface, render
from tests.cli_runner import softforce

BROWN = [0.1, -0.05, 0.001, 0.002, 0.01]
RS_MODELS = {
    "brown_conrady": BROWN,
    "modified_brown_conrady": BROWN,
    "inverse_brown_conrady": BROWN,
    "kannala_brandt4": [0.05, -0.01, 0.003, -0.001, 0.0],
}
# a D455-like colour lens at 640x480 (its corners move by about 4 pixels)
D455_LIKE = LensDistortion("plumb_bob", (-0.055, 0.065, 0.0005, 0.0007, -0.02))
CAMERA = CameraIntrinsics(640, 480, 385.0, 385.0, 321.3, 238.6, distortion=D455_LIKE)


def rs_intrinsics(model: str, coeffs: list[float]) -> rs.intrinsics:
    out = rs.intrinsics()
    out.width, out.height, out.fx, out.fy, out.ppx, out.ppy = 640, 480, 600.0, 610.0, 320.5, 240.2
    out.model, out.coeffs = getattr(rs.distortion, model), coeffs
    return out


def normalised_points(count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    points = np.random.default_rng(seed).uniform([-0.5, -0.4], [0.5, 0.4], (count, 2))
    return points[:, 0], points[:, 1]


@pytest.mark.parametrize("model", RS_MODELS)
def test_every_librealsense_model_projects_as_librealsense_does(model):
    device = rs_intrinsics(model, RS_MODELS[model])
    lens = intrinsics_from_rs(device).distortion
    x, y = normalised_points(40)
    xd, yd = distort(lens, x, y)
    ours = np.column_stack([600.0 * xd + 320.5, 610.0 * yd + 240.2])
    theirs = np.array([rs.rs2_project_point_to_pixel(device, [a, b, 1.0])
                       for a, b in zip(x, y, strict=True)])
    # float32 inside librealsense: 1e-4 px
    np.testing.assert_allclose(ours, theirs, atol=2e-4)
    assert np.max(np.abs(ours - np.column_stack([600 * x + 320.5, 610 * y + 240.2]))) > 5


@pytest.mark.parametrize("lens", [
    LensDistortion("plumb_bob", tuple(BROWN)),
    LensDistortion("modified_brown_conrady", tuple(BROWN)),
    LensDistortion("kannala_brandt", (0.05, -0.01, 0.003, -0.001)),
    LensDistortion("rational_polynomial", (0.3, -0.1, 0.001, -0.002, 0.02, 0.25, -0.05, 0.01)),
])
def test_undistort_inverts_distort(lens):
    x, y = normalised_points(500, seed=1)
    back = undistort(lens, *distort(lens, x, y))
    np.testing.assert_allclose(np.column_stack(back), np.column_stack([x, y]), atol=1e-9)


def test_rational_polynomial_is_opencvs_formula():
    k1, k2, p1, p2, k3, k4, k5, k6 = 0.3, -0.1, 0.001, -0.002, 0.02, 0.25, -0.05, 0.01
    x, y = 0.31, -0.22
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    expected = (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    lens = LensDistortion("rational_polynomial", (k1, k2, p1, p2, k3, k4, k5, k6))
    assert np.allclose(distort(lens, np.array(x), np.array(y)), expected, atol=1e-15)
    # without a denominator, OpenCV's plumb_bob
    plain = LensDistortion("rational_polynomial", (k1, k2, p1, p2, k3, 0.0, 0.0, 0.0))
    bob = LensDistortion("plumb_bob", (k1, k2, p1, p2, k3))
    assert np.allclose(distort(plain, np.array(x), np.array(y)),
                       distort(bob, np.array(x), np.array(y)), atol=1e-15)


def test_camera_info_models_and_their_errors():
    assert LensDistortion.from_camera_info("plumb_bob", [0.0] * 5) is None
    assert LensDistortion.from_camera_info("anything", []) is None  # a pinhole image
    assert LensDistortion.from_camera_info("equidistant", [0.1, 0, 0, 0]).model == (
        "kannala_brandt")
    assert LensDistortion.from_camera_info("plumb_bob", [0.1, 0.2, 0, 0]).coefficients == (
        0.1, 0.2, 0.0, 0.0, 0.0)  # no k3: 0
    assert LensDistortion.from_camera_info("kannala_brandt4", [0.1, 0, 0, 0, 0]).coefficients == (
        0.1, 0.0, 0.0, 0.0)  # librealsense's fifth 0
    with pytest.raises(LensModelError, match="'fisheye62' is not one softforce knows"):
        LensDistortion.from_camera_info("fisheye62", [0.1] * 6)
    with pytest.raises(LensModelError, match="takes 4 coefficients"):
        LensDistortion.from_camera_info("kannala_brandt", [0.1] * 5)
    with pytest.raises(LensModelError, match="finite"):
        LensDistortion.from_camera_info("plumb_bob", [float("nan"), 0, 0, 0, 0])
    ftheta = rs_intrinsics("ftheta", [0.9, 0, 0, 0, 0])
    with pytest.raises(RecordingError, match="colour stream's lens"):
        intrinsics_from_rs(ftheta)


def box_on_table() -> list[SceneSurface]:
    """A 120 mm box 480 mm from the camera, towards the image's corner, on a table 600 mm
    away that fills the image (a camera at the origin looking down +z)."""
    table = SceneSurface("table", np.array([[-900, -900, 600], [900, -900, 600],
                                            [900, 900, 600], [-900, 900, 600.0]]),
                         np.array([[0, 2, 1], [0, 3, 2]]), (150, 118, 84))
    corners = np.array([[x, y, z] for x in (150, 270) for y in (80, 200) for z in (480, 600)],
                       dtype=float)
    faces = np.array([[0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5]])
    return [table, SceneSurface("box", corners, faces, (40, 90, 210))]


def rendered_frame(intrinsics: CameraIntrinsics) -> RgbdFrame:
    view = render(box_on_table(), intrinsics, np.eye(4), ambient=1.0)
    return RgbdFrame(0, view.color, np.rint(view.depth_mm).astype(np.uint16), intrinsics)


def test_a_rectified_frame_is_the_pinhole_cameras_image():
    raw = rendered_frame(CAMERA)
    pinhole = rendered_frame(replace(CAMERA, distortion=None))
    fixed = rectified(raw)
    assert fixed.intrinsics == pinhole.intrinsics and fixed.intrinsics.distortion is None
    # nearest-pixel resampling: every pixel but those within a pixel of an edge agrees
    same = (fixed.depth_mm == pinhole.depth_mm) & np.all(fixed.color == pinhole.color, axis=-1)
    assert same.mean() > 0.985
    seen = fixed.depth_mm > 0
    assert seen.mean() > 0.98  # the barrel lens sees past the pinhole image's corners
    # the box's points: read through K alone, the raw image puts its top face's corners
    # millimetres off; rectified, within the pixel's footprint (1.25 mm at 480 mm)
    box = pinhole.depth_mm == 480
    for frame, low, high in ((fixed, 0.0, 1.3), (raw, 2.0, 8.0)):
        points = points_from_depth(frame.depth_mm, frame.intrinsics)
        top = points[frame.depth_mm == 480]
        span = np.array([top[:, 0].min(), top[:, 0].max(), top[:, 1].min(), top[:, 1].max()])
        error = np.abs(span - [150, 270, 80, 200]).max()
        assert low <= error <= high, (frame.intrinsics.distortion, span)
    assert box.any()


def test_the_rectification_map_is_cached_and_read_only():
    source, empty = rectification_map(CAMERA)
    assert rectification_map(replace(CAMERA))[0] is source
    assert not source.flags.writeable and not empty.flags.writeable
    assert len(empty) == 0  # a barrel lens sees beyond the pinhole image's corners
    pincushion = replace(CAMERA, distortion=LensDistortion("plumb_bob", (0.1, 0, 0, 0, 0)))
    source, empty = rectification_map(pincushion)
    corner = np.zeros((480, 640), bool)
    corner.reshape(-1)[empty] = True
    assert 0 < corner.mean() < 0.2 and corner[0, 0] and corner[-1, -1] and not corner[240, 320]


def test_recordings_carry_the_lens_and_are_read_rectified(tmp_path):
    path = tmp_path / "lens.mcap"
    raw = rendered_frame(CAMERA)
    with RecordingWriter(path) as writer:
        for i in range(2):
            writer.write_frame(replace(raw, time_ns=i * 33_000_000))
    summary = read_summary(path)
    assert summary.intrinsics.distortion == D455_LIKE
    assert summary.to_dict()["distortion"]["model"] == "plumb_bob"
    shown = softforce("record", "info", path)
    assert shown.returncode == 0 and "plumb_bob -0.055 0.065" in shown.stdout
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)  # a known model: nothing to say
        frames = list(iter_frames(path))
    expected = rectified(raw)
    for frame in frames:
        assert frame.intrinsics.distortion is None
        np.testing.assert_array_equal(frame.depth_mm, expected.depth_mm)
        np.testing.assert_array_equal(frame.color, expected.color)
