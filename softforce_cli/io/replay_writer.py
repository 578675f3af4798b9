"""A recording replayed with its sensing results, for Foxglove: one MCAP holding the camera
topics of the recording (written as mcap_writer.py writes them) and, at each frame's time,

| topic                      | schema                   | content                              |
|----------------------------|--------------------------|--------------------------------------|
| /tf                        | foxglove.FrameTransform  | camera pose in the `robot` frame     |
| /softforce/robot_points    | foxglove.PointCloud      | points segmented as the robot        |
| /softforce/object_points   | foxglove.PointCloud      | points of other objects near it      |
| /softforce/robot_surface   | foxglove.SceneUpdate     | the deformed surface, triangle list  |
| /softforce/forces          | foxglove.SceneUpdate     | one arrow per contact force          |

Foxglove works in metres: millimetres are converted here, at the file's edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.ArrowPrimitive_pb2 import ArrowPrimitive
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TriangleListPrimitive_pb2 import TriangleListPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from mcap.well_known import MessageEncoding
from mcap_protobuf.schema import register_schema
from scipy.spatial.transform import Rotation

from softforce_cli.camera.frame import RgbdFrame
from softforce_cli.io import recording_format as fmt
from softforce_cli.io.mcap_writer import RecordingWriter

ROBOT_FRAME_ID = "robot"
TF_TOPIC = "/tf"
ROBOT_POINTS_TOPIC = "/softforce/robot_points"
OBJECT_POINTS_TOPIC = "/softforce/object_points"
SURFACE_TOPIC = "/softforce/robot_surface"
FORCES_TOPIC = "/softforce/forces"
M_PER_MM = 1e-3
SURFACE_RGBA = (0.5, 0.64, 0.85, 0.6)
ARROW_RGBA = (0.9, 0.2, 0.1, 1.0)
# An arrow's head is this fraction of its length, its shaft this thick for a 40 mm arrow.
HEAD_FRACTION = 0.25
SHAFT_DIAMETER_MM = 2.0


@dataclass(frozen=True)
class FrameResults:
    """One frame's results in the robot frame, mm.

    robot_points_mm (n, 3), object_points_mm (m, 3); surface_nodes_mm (v, 3) and
    surface_faces (f, 3) into them, or None when the shape is unknown; arrow_tails_mm (c, 3)
    and arrow_vectors_mm (c, 3) the force arrows (tail to tip), already scaled to mm.
    """

    robot_points_mm: np.ndarray
    object_points_mm: np.ndarray
    surface_nodes_mm: np.ndarray | None
    surface_faces: np.ndarray | None
    arrow_tails_mm: np.ndarray
    arrow_vectors_mm: np.ndarray


class ReplayWriter(RecordingWriter):
    """RecordingWriter that also writes each frame's results and the camera's pose.

    camera_rotation (3, 3) and camera_translation_mm (3,): the camera's pose in the robot
    frame (the calibration's robot_from_camera).
    """

    def __init__(self, path, camera_rotation: np.ndarray, camera_translation_mm: np.ndarray,
                 *, force: bool = False, metadata=None) -> None:
        super().__init__(path, force=force, metadata=metadata)
        self._camera = (np.asarray(camera_rotation, dtype=float),
                        np.asarray(camera_translation_mm, dtype=float))
        try:
            schemas = {kind: register_schema(self._writer, kind)
                       for kind in (FrameTransform, PointCloud, SceneUpdate)}
            self._result_channels = {
                topic: self._writer.register_channel(topic, MessageEncoding.Protobuf,
                                                     schemas[kind])
                for topic, kind in ((TF_TOPIC, FrameTransform),
                                    (ROBOT_POINTS_TOPIC, PointCloud),
                                    (OBJECT_POINTS_TOPIC, PointCloud),
                                    (SURFACE_TOPIC, SceneUpdate), (FORCES_TOPIC, SceneUpdate))}
        except BaseException:
            self.abort()
            raise

    def write_replay_frame(self, frame: RgbdFrame, results: FrameResults) -> None:
        """The frame's results, then the frame itself (same log time, same chunk)."""
        time_ns = int(frame.time_ns)
        rotation, translation = self._camera
        messages = {
            TF_TOPIC: camera_transform(rotation, translation, time_ns),
            ROBOT_POINTS_TOPIC: point_cloud(results.robot_points_mm, time_ns),
            OBJECT_POINTS_TOPIC: point_cloud(results.object_points_mm, time_ns),
            SURFACE_TOPIC: surface_update(results.surface_nodes_mm, results.surface_faces,
                                          time_ns),
            FORCES_TOPIC: arrows_update(results.arrow_tails_mm, results.arrow_vectors_mm,
                                        time_ns),
        }
        for topic, message in messages.items():
            self._writer.add_message(channel_id=self._result_channels[topic], log_time=time_ns,
                                     publish_time=time_ns, sequence=self.frames_written,
                                     data=message.SerializeToString())
        self.write_frame(frame)


def camera_transform(rotation: np.ndarray, translation_mm: np.ndarray,
                     time_ns: int) -> FrameTransform:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    t = M_PER_MM * np.asarray(translation_mm, dtype=float)
    return FrameTransform(timestamp=fmt.timestamp_from_ns(time_ns),
                          parent_frame_id=ROBOT_FRAME_ID, child_frame_id=fmt.OPTICAL_FRAME_ID,
                          translation=Vector3(x=t[0], y=t[1], z=t[2]),
                          rotation=Quaternion(x=x, y=y, z=z, w=w))


def point_cloud(points_mm: np.ndarray, time_ns: int) -> PointCloud:
    """(n, 3) mm -> a PointCloud of float32 x, y, z in metres, robot frame."""
    data = (M_PER_MM * np.asarray(points_mm, dtype=float).reshape(-1, 3)).astype("<f4")
    fields = [PackedElementField(name=name, offset=4 * i, type=PackedElementField.FLOAT32)
              for i, name in enumerate("xyz")]
    return PointCloud(timestamp=fmt.timestamp_from_ns(time_ns), frame_id=ROBOT_FRAME_ID,
                      pose=_identity(), point_stride=12, fields=fields, data=data.tobytes())


def surface_update(nodes_mm: np.ndarray | None, faces: np.ndarray | None,
                   time_ns: int) -> SceneUpdate:
    """The deformed surface as one indexed triangle list (no entity when unknown)."""
    if nodes_mm is None or faces is None:
        return SceneUpdate()
    used, indices = np.unique(np.asarray(faces).ravel(), return_inverse=True)
    points = [Point3(x=p[0], y=p[1], z=p[2]) for p in M_PER_MM * nodes_mm[used]]
    triangles = TriangleListPrimitive(pose=_identity(), points=points,
                                      color=Color(**dict(zip("rgba", SURFACE_RGBA, strict=True))),
                                      indices=indices.astype(int).tolist())
    return SceneUpdate(entities=[_entity("robot_surface", time_ns, triangles=[triangles])])


def arrows_update(tails_mm: np.ndarray, vectors_mm: np.ndarray, time_ns: int) -> SceneUpdate:
    """One arrow per row, from its tail along its vector (an empty entity when there are
    none, so that the last frame's arrows do not linger)."""
    arrows = []
    color = Color(**dict(zip("rgba", ARROW_RGBA, strict=True)))
    for tail, vector in zip(np.reshape(tails_mm, (-1, 3)), np.reshape(vectors_mm, (-1, 3)),
                            strict=True):
        length = float(np.linalg.norm(vector))
        if length == 0:
            continue
        x, y, z, w = quaternion_from_x_axis(vector / length)
        t = M_PER_MM * tail
        pose = Pose(position=Vector3(x=t[0], y=t[1], z=t[2]),
                    orientation=Quaternion(x=x, y=y, z=z, w=w))
        arrows.append(ArrowPrimitive(
            pose=pose, shaft_length=M_PER_MM * length * (1 - HEAD_FRACTION),
            head_length=M_PER_MM * length * HEAD_FRACTION,
            shaft_diameter=M_PER_MM * SHAFT_DIAMETER_MM,
            head_diameter=M_PER_MM * 2.5 * SHAFT_DIAMETER_MM, color=color))
    return SceneUpdate(entities=[_entity("forces", time_ns, arrows=arrows)])


def quaternion_from_x_axis(direction: np.ndarray) -> np.ndarray:
    """(4,) x, y, z, w of the shortest rotation taking +x to the unit vector `direction`
    (Foxglove draws an arrow along its pose's +x)."""
    d = np.asarray(direction, dtype=float)
    x_axis = np.array([1.0, 0.0, 0.0])
    if np.dot(x_axis, d) < -1 + 1e-12:  # opposite: half a turn about z
        return np.array([0.0, 0.0, 1.0, 0.0])
    q = np.r_[np.cross(x_axis, d), 1.0 + np.dot(x_axis, d)]
    return q / np.linalg.norm(q)


def _entity(name: str, time_ns: int, **primitives) -> SceneEntity:
    return SceneEntity(timestamp=fmt.timestamp_from_ns(time_ns), frame_id=ROBOT_FRAME_ID,
                       id=name, frame_locked=True, **primitives)


def _identity() -> Pose:
    return Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1))
