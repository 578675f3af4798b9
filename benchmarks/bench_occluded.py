"""Cost of finding contacts whose tip the camera cannot see (vision.contacts.occluded_tips) at
the D415's 640x480, on the frames of bench_sense's recording (the sample probes, simulated at
640x480; the coarse Diamond at rest as the model, the truth's camera pose)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_sense import ROBOT, _recording
from benchmarks.timing import BenchRow, median_time
from softforce_cli.calibration.rigid import RigidTransform
from softforce_cli.estimation.truth_errors import read_truth
from softforce_cli.io.mcap_reader import iter_frames
from softforce_cli.model.robot import load_robot
from softforce_cli.vision.contacts import object_regions, occluded_tips
from softforce_cli.vision.pipeline import process_frame, robot_distance_mm
from softforce_cli.vision.point_cloud import cloud_from_frame
from softforce_cli.vision.segmentation import learn_robot_colour
from softforce_cli.vision.settings import VisionSettings, settings_for_camera

REPEATS = 20


def run() -> list[BenchRow]:
    recording = _recording()
    camera = read_truth(recording.with_suffix(".truth.json"))["camera"]
    pose = RigidTransform(np.array(camera["rotation"]), np.array(camera["translation_mm"]))
    robot = load_robot(ROBOT)
    mesh = robot.mesh
    frames = list(iter_frames(recording))
    surface = np.vstack([mesh.nodes_mm[mesh.surface_nodes],
                         mesh.nodes_mm[mesh.surface_faces].mean(axis=1)])
    first = frames[0]
    robot_rgb = learn_robot_colour(
        cloud_from_frame(first.depth_mm, first.color, first.intrinsics, pose), surface)
    settings = settings_for_camera(VisionSettings(), first.intrinsics.fx,
                                   robot_distance_mm(mesh.bounds_mm, pose))
    # every fifth frame: each held state (unloaded, one probe, two probes) twice
    inputs = []
    for frame in frames[::5]:
        result = process_frame(frame.depth_mm, frame.color, frame.intrinsics, pose,
                               mesh.bounds_mm, mesh.nodes_mm[robot.feature_nodes],
                               robot.feature_normals, robot_rgb, settings)
        segmentation = result.segmentation
        objects = segmentation.objects.points_mm
        touching = segmentation.robot_tree.query_ball_point(
            objects, settings.contact_radius_mm, return_length=True
        ) > settings.contact_min_neighbours
        inputs.append((objects, object_regions(segmentation), touching,
                       segmentation.robot_tree))

    def timed(hidden: bool) -> list[float]:
        return [median_time(lambda i=i: occluded_tips(
            i[0], i[1], np.zeros_like(i[2]) if hidden else i[2], i[3], settings,
            pose.translation_mm), REPEATS) for i in inputs]

    sizes = [len(i[0]) for i in inputs]
    rows = []
    for hidden, name, what in [
        (False, "occluded tips, 640x480", "as the frames are: every probe touches in view"),
        (True, "occluded tips, 640x480, every object taken as hidden",
         "worst case: Algorithm 2's contact points ignored, every probe extended"),
    ]:
        times = timed(hidden)
        rows.append(BenchRow(
            name, float(np.median(times)), REPEATS * len(times), "< 2 ms a frame",
            f"{1e3 * np.median(times):.2f} ms (max {1e3 * max(times):.2f})",
            f"{what}; {len(inputs)} frames, 0-{max(sizes)} object points"))
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
