"""The markers as evidence about the camera (diagnosis.markers): a turn about the vertical that
slides the surfaces along themselves, fitted from the Diamond's nine markers seen by the
sample scenes' camera (580 mm above, looking down) through 0.5 mm noise, against the same
markers turned by hand."""

import numpy as np
import pytest

from softforce_cli.diagnosis.background import observed_table
from softforce_cli.diagnosis.basis import Basis
from softforce_cli.diagnosis.fitting import fit_values, held_out
from softforce_cli.diagnosis.markers import marker_field, marker_inputs, marker_rms_mm
from softforce_cli.diagnosis.selection import clear_improvement, noise_floor_mm
from softforce_cli.diagnosis.sensitivities import ColumnSet
from softforce_cli.model.effects import frame_contexts
from tests.test_diagnosis_background import BODY, CAMERA, _candidate, _plane_at

# the default Diamond's markers: apex, four elbows, four bars (sample_data/diamond)
MARKERS = np.array([[0.0, 0.0, 126.0], *[[101.0 * c, 101.0 * s, 45.0] for c, s in
                                          ((0, 1), (-1, 0), (0, -1), (1, 0))],
                    *[[50.28 * c, 50.28 * s, 86.04] for c, s in
                      ((0, 1), (-1, 0), (0, -1), (1, 0))]])
FRAMES = 16


def test_marker_entries_are_the_coordinates_seen_less_predicted():
    predicted = np.stack([MARKERS, MARKERS + np.array([0.0, 0.0, -2.0])])  # two states
    observed = [MARKERS + 0.1, MARKERS + np.array([0.0, 0.0, -1.0])]
    observed[1][4] = np.nan  # the east elbow unseen in frame 1
    field = marker_field(observed, predicted, np.array([0, 1]))
    assert len(field.frame) == 3 * (9 + 8)
    np.testing.assert_array_equal(field.node[:6], [0, 1, 2, 3, 4, 5])
    np.testing.assert_allclose(field.mean_mm[:27], 0.1)
    np.testing.assert_allclose(field.mean_mm[27:].reshape(-1, 3), [[0.0, 0.0, 1.0]] * 8)
    assert 3 * 4 + 2 not in field.node[27:]  # no entry for the unseen marker
    # each marker's distance from the model: 0.1 mm along x, y and z, then 1 mm along z
    rms = marker_rms_mm(field, [f"m{k}" for k in range(9)])
    assert rms["m4"] == pytest.approx(np.sqrt(3) * 0.1)  # seen in frame 0 only
    assert rms["m0"] == pytest.approx(np.sqrt((3 * 0.01 + 1.0) / 2))
    # a recording without markers beside one with: its frames count as unseen
    mixed = marker_field([MARKERS, np.zeros((0, 3)), MARKERS], predicted, np.array([0, 1, 0]))
    np.testing.assert_array_equal(np.unique(mixed.frame), [0, 2])
    # a robot without markers, or too few seen to fix a turn
    assert marker_field([np.zeros((0, 3))] * 2, predicted[:, :0], np.array([0, 1])) is None
    few = [np.where(np.arange(9)[:, None] < 2, MARKERS, np.nan)] * 2
    assert marker_field(few, predicted, np.array([0, 1])) is None


def _markers_seen(turn_deg: float, seed: int):
    """Field and Inputs of FRAMES frames in two alternating states held for two frames, the
    markers seen through a camera turned `turn_deg` about its axis (the vertical), with 0.5 mm
    noise and a 0.3 mm static mismatch of the model at each marker."""
    from softforce_cli.model.effects import make_effect, observed_points_robot

    rng = np.random.default_rng(seed)
    predicted = np.stack([MARKERS, MARKERS + np.array([0.0, 3.0, -2.0])])
    of_frame = (np.arange(FRAMES) // 2) % 2
    turn = (make_effect("extrinsic_offset", rotation_z_deg=turn_deg),)
    mismatch = 0.3 * rng.standard_normal(MARKERS.shape)
    observed = [observed_points_robot(predicted[s], turn, CAMERA) + mismatch
                + 0.5 * rng.standard_normal(MARKERS.shape) for s in of_frame]
    field = marker_field(observed, predicted, of_frame)
    basis = Basis(np.zeros((2, 1, 3)), np.zeros((2, 1, 3)), np.zeros((2, 0, 1)), ColumnSet(()),
                  of_frame, tuple(frame_contexts(0.5 * np.arange(FRAMES), np.zeros((FRAMES, 1)))),
                  (), CAMERA, np.zeros((2, 0)), np.zeros((2, 0, 1, 3)),
                  observed_table([_plane_at(-37.0)], BODY, 0.5))
    return field, marker_inputs(field, predicted, basis), of_frame


@pytest.mark.parametrize("seed", [1, 2])
def test_markers_see_a_camera_turned_about_the_vertical(seed):
    field, inputs, of_frame = _markers_seen(1.0, seed)
    floor = noise_floor_mm(field, of_frame)
    assert floor == pytest.approx(0.5, rel=0.2)  # the markers' noise, per coordinate
    camera = _candidate("extrinsic_offset")
    values = fit_values(camera, inputs, field, relative=False)
    assert values[5] == pytest.approx(1.0, abs=0.1)  # rotation_z_deg
    # the table stays where it is seen: no tilt, no move along the vertical
    assert np.abs(values[[2, 3, 4]]).max() < 0.15
    segments = np.arange(FRAMES) // 2
    assert clear_improvement(held_out(camera, inputs, field, segments, values, False), floor)


@pytest.mark.parametrize("seed", [1, 2])
def test_markers_of_a_calibrated_camera_name_no_camera_effect(seed):
    field, inputs, of_frame = _markers_seen(0.0, seed)
    floor = noise_floor_mm(field, of_frame)
    segments = np.arange(FRAMES) // 2
    for name in ("extrinsic_offset", "depth_bias"):
        camera = _candidate(name)
        values = fit_values(camera, inputs, field, relative=False)
        assert not clear_improvement(held_out(camera, inputs, field, segments, values, False),
                                     floor)
