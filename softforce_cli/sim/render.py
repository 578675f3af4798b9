"""Ideal RGB-D rendering of triangle surfaces by ray casting (open3d RaycastingScene).

The scene is built in the camera's optical frame (x right, y down, z forward): the vertices of
every surface are moved there once per frame, so that the rays of a pinhole camera all start
at the origin and depend only on the intrinsics (cached). Each ray's direction is
((u - cx) / fx, (v - cy) / fy, 1), or through a distorting lens the ray (x, y, 1) that pixel
sees (camera.rectification.pixel_rays), so the hit distance, in units of the direction's
length, is the depth along the optical z axis directly.

The output is ideal (noise-free, hole-free, float); softforce_cli.sim.depth_noise turns it into
what a RealSense D415 would deliver.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import open3d as o3d

from softforce_cli.camera.intrinsics import CameraIntrinsics
from softforce_cli.camera.rectification import pixel_rays
from softforce_cli.model.mesh import TetMesh
from softforce_cli.sim.camera_pose import invert_pose, transform_points

BACKGROUND_RGB = (40, 40, 40)  # neutral dark grey where no ray hits anything
AMBIENT = 0.7  # share of the base colour lit regardless of orientation (keeps colours flat)
TABLE_RGB = (150, 118, 84)  # a light wood
SHININESS = 40.0  # Blinn-Phong exponent of a glossy scene: a highlight about 10 degrees wide
SHADOW_OFFSET_MM = 0.05  # a shadow ray's start off its surface: above float32 rounding at 1 m


@dataclass(frozen=True, eq=False)
class Spots:
    """Round spots painted on a deforming surface (marker stickers on a robot's skin), placed
    in its rest shape, so that each stays on the same patch of skin as the body deforms.

    rest_vertices_mm : (n, 3) float64 the surface's vertices at rest (its material points).
    centres_mm       : (k, 3) float64 the spots' centres at rest.
    radius_mm        : their radius, measured at rest.
    color_rgb        : (3,) uint8 their colour.
    """

    rest_vertices_mm: np.ndarray
    centres_mm: np.ndarray
    radius_mm: float
    color_rgb: np.ndarray

    def painted(self, rest_points_mm: np.ndarray) -> np.ndarray:
        """(m,) bool: which rest points (m, 3) lie on a spot."""
        centres = np.asarray(self.centres_mm, dtype=float).reshape(-1, 3)
        if not len(centres):
            return np.zeros(len(rest_points_mm), dtype=bool)
        gaps = np.linalg.norm(rest_points_mm[:, None, :] - centres[None], axis=2)
        return gaps.min(axis=1) < self.radius_mm


@dataclass(frozen=True, eq=False)
class SceneSurface:
    """A triangle surface to render, in the world (robot) frame.

    name              : label for ground truth and debugging.
    vertices_mm       : (n, 3) float64 vertex positions in mm.
    faces             : (k, 3) int64 vertex indices; the winding (right-hand rule) gives the
                        normal reported in RenderedView.normals_cam.
    color_rgb         : (3,) uint8 base colour.
    vertex_colors_rgb : optional (n, 3) uint8 per-vertex colours, interpolated across faces;
                        replaces color_rgb where given.
    smooth            : interpolate area-weighted vertex normals across faces (smooth shading
                        and incidence) instead of using the flat face normal.
    spots             : optional Spots painted over those colours (rest_vertices_mm (n, 3)).
    """

    name: str
    vertices_mm: np.ndarray
    faces: np.ndarray
    color_rgb: np.ndarray
    vertex_colors_rgb: np.ndarray | None = None
    smooth: bool = False
    spots: Spots | None = None

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices_mm, dtype=float)
        faces = np.asarray(self.faces, dtype=np.int64)
        color = np.asarray(self.color_rgb)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(
                f"surface {self.name!r}: vertices_mm must be (n, 3), got {vertices.shape}"
            )
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"surface {self.name!r}: faces must be (k, 3), got {faces.shape}")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(f"surface {self.name!r}: face indices outside 0..{len(vertices) - 1}")
        if color.shape != (3,):
            raise ValueError(
                f"surface {self.name!r}: color_rgb must have 3 values, got {color.shape}"
            )
        object.__setattr__(self, "vertices_mm", vertices)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "color_rgb", color.astype(np.uint8))
        if self.vertex_colors_rgb is not None:
            vertex_colors = np.asarray(self.vertex_colors_rgb)
            if vertex_colors.shape != vertices.shape:
                raise ValueError(
                    f"surface {self.name!r}: vertex_colors_rgb must be {vertices.shape}, "
                    f"got {vertex_colors.shape}"
                )
            object.__setattr__(self, "vertex_colors_rgb", vertex_colors.astype(np.uint8))

    @classmethod
    def from_tet_mesh(
        cls, name: str, mesh: TetMesh, color_rgb: np.ndarray, smooth: bool = True
    ) -> SceneSurface:
        """The outward boundary of a tetrahedral mesh (all nodes kept, interior ones unused)."""
        return cls(name, mesh.nodes_mm, mesh.surface_faces, color_rgb, smooth=smooth)


@dataclass(frozen=True, eq=False)
class RenderedView:
    """An ideal RGB-D view, every array (h, w, ...) in image rows and columns.

    depth_mm       : (h, w) float64 depth along the optical z axis in mm, 0 where no hit.
    color          : (h, w, 3) uint8 RGB, shaded base colour; BACKGROUND_RGB where no hit.
    geometry_index : (h, w) int32 index into the rendered surface list, -1 where no hit.
    normals_cam    : (h, w, 3) float32 unit surface normal in the camera frame, oriented by
                     the surface's winding; 0 where no hit.
    cos_incidence  : (h, w) float32 |cos| of the angle between the viewing ray and the normal,
                     in [0, 1]: 1 facing the camera, 0 grazing or no hit.
    """

    depth_mm: np.ndarray
    color: np.ndarray
    geometry_index: np.ndarray
    normals_cam: np.ndarray
    cos_incidence: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(h, w) bool, True where a surface was hit."""
        return self.geometry_index >= 0


def table_surface(
    z_mm: float,
    half_size_mm: float,
    color_rgb: np.ndarray = TABLE_RGB,
    center_xy_mm: np.ndarray = (0.0, 0.0),
) -> SceneSurface:
    """A horizontal square table top at height `z_mm` in the robot frame, normal +z.

    half_size_mm : half the side length; center_xy_mm : (2,) centre of the square.
    """
    cx, cy = np.asarray(center_xy_mm, dtype=float)
    h = float(half_size_mm)
    vertices = np.array(
        [
            [cx - h, cy - h, z_mm],
            [cx + h, cy - h, z_mm],
            [cx + h, cy + h, z_mm],
            [cx - h, cy + h, z_mm],
        ]
    )
    faces = np.array([[0, 1, 2], [0, 2, 3]])  # counter-clockwise seen from above: normal +z
    return SceneSurface("table", vertices, faces, color_rgb)


@lru_cache(maxsize=8)
def _pixel_rays(intrinsics: CameraIntrinsics) -> tuple[o3d.core.Tensor, np.ndarray]:
    """Rays of every pixel from the optical centre, and their unit directions.

    -> (h, w, 6) float32 open3d tensor [0, 0, 0, x, y, 1], (x, y, 1) the ray the pixel sees
       ((u - cx) / fx, (v - cy) / fy, 1) through a lens without distortion; pixels through
       a distortion that maps no ray look backwards (0, 0, -1), at nothing),
       (3, h * w) float32 unit directions, one row per axis (read-only).
    """
    x, y = pixel_rays(intrinsics)
    seen = np.isfinite(x) & np.isfinite(y)
    directions = np.stack([np.where(seen, x, 0.0), np.where(seen, y, 0.0),
                           np.where(seen, 1.0, -1.0)], axis=-1)
    rays = np.concatenate([np.zeros_like(directions), directions], axis=-1).astype(np.float32)
    unit = (directions / np.linalg.norm(directions, axis=-1, keepdims=True)).reshape(-1, 3)
    unit = np.ascontiguousarray(unit.T, dtype=np.float32)
    unit.setflags(write=False)
    return o3d.core.Tensor(rays), unit


def _unit_rows(vectors: np.ndarray) -> np.ndarray:
    """Normalise rows of (n, 3); zero rows stay zero."""
    length = np.sqrt(vectors[:, 0] ** 2 + vectors[:, 1] ** 2 + vectors[:, 2] ** 2)[:, None]
    return np.divide(vectors, length, out=np.zeros_like(vectors), where=length > 0)


def smooth_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals: vertices (n, 3), faces (k, 3) -> (n, 3) float64.

    Vertices on no face get a zero normal (same result as softforce_cli.model.mesh's
    vertex_normals, with bincount instead of the slower np.add.at).
    """
    tri = vertices[faces]
    weighted = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    index = faces.ravel()
    summed = np.stack(
        [np.bincount(index, np.repeat(weighted[:, a], 3), len(vertices)) for a in range(3)], axis=1
    )
    return _unit_rows(summed)


def _shading_table(
    surfaces: list[SceneSurface], ambient: float, background_rgb: np.ndarray
) -> np.ndarray:
    """(s + 1, 256, 3) uint8 colour of surface i at incidence level l = round(255 cos);
    row s is the background."""
    shade = ambient + (1.0 - ambient) * np.arange(256) / 255.0
    base = np.array([s.color_rgb for s in surfaces], dtype=float).reshape(-1, 3)
    table = np.rint(base[:, None, :] * shade[None, :, None])
    background = np.broadcast_to(np.asarray(background_rgb, dtype=float), (1, 256, 3))
    return np.clip(np.concatenate([table, background]), 0, 255).astype(np.uint8)


def _interpolate(corner_values: np.ndarray, corners: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Barycentric interpolation at ray hits.

    corner_values (n, c) per-vertex values; corners (m, 3) vertex indices of the hit
    triangles; uv (m, 2) Embree's hit coordinates (weights of corners 1 and 2) -> (m, c).
    """
    w1, w2 = uv[:, 0:1], uv[:, 1:2]
    return (
        corner_values.take(corners[:, 0], axis=0) * (1.0 - w1 - w2)
        + corner_values.take(corners[:, 1], axis=0) * w1
        + corner_values.take(corners[:, 2], axis=0) * w2
    )


def _camera_frame_scene(
    surfaces: list[SceneSurface], cam_from_world: np.ndarray
) -> tuple[o3d.t.geometry.RaycastingScene, np.ndarray, dict[int, np.ndarray]]:
    """A ray casting scene of the surfaces that have faces, moved into the camera frame.

    -> scene; (g + 2,) int64 surface index of each geometry id, whose last entry,
    len(surfaces), stands for a miss; {surface index: (n, 3) float64 vertices in the camera frame}.
    """
    drawn = [i for i, s in enumerate(surfaces) if len(s.faces)]
    vertices_cam = {i: transform_points(cam_from_world, surfaces[i].vertices_mm) for i in drawn}
    scene = o3d.t.geometry.RaycastingScene()
    geometry_ids = [
        scene.add_triangles(
            o3d.core.Tensor(vertices_cam[i].astype(np.float32)),
            o3d.core.Tensor(surfaces[i].faces.astype(np.uint32)),
        )
        for i in drawn
    ]
    surface_of_id = np.full(max(geometry_ids, default=-1) + 2, len(surfaces), dtype=np.int64)
    surface_of_id[geometry_ids] = drawn
    return scene, surface_of_id, vertices_cam


def _interpolate_at_hits(
    surfaces: list[SceneSurface],
    vertices_cam: dict[int, np.ndarray],
    surface: np.ndarray,
    hits: dict[str, np.ndarray],
    normals: np.ndarray,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Smooth normals (written into `normals`, (p, 3) float32) and per-vertex colours and
    spots of the surfaces that ask for them, at the pixels they cover.

    surface (p,) surface index per pixel; hits: the ray caster's flat outputs.
    -> [(pixels (m,) int, albedo (m, 3) float32)] for surfaces with vertex colours or spots.
    """
    albedo_override = []
    for i in vertices_cam:
        s = surfaces[i]
        if not s.smooth and s.vertex_colors_rgb is None and s.spots is None:
            continue
        pixels = np.flatnonzero(surface == i)
        corners = s.faces.take(hits["primitive_ids"].take(pixels), axis=0)
        uv = hits["primitive_uvs"].take(pixels, axis=0)
        if s.smooth:
            vertex_normals = smooth_vertex_normals(vertices_cam[i], s.faces).astype(np.float32)
            normals[pixels] = _unit_rows(_interpolate(vertex_normals, corners, uv))
        if s.vertex_colors_rgb is None and s.spots is None:
            continue
        albedo = (np.tile(s.color_rgb.astype(np.float32), (len(pixels), 1))
                  if s.vertex_colors_rgb is None
                  else _interpolate(s.vertex_colors_rgb.astype(np.float32), corners, uv))
        if s.spots is not None:
            painted = s.spots.painted(_interpolate(s.spots.rest_vertices_mm, corners, uv))
            albedo[painted] = s.spots.color_rgb
        albedo_override.append((pixels, albedo))
    return albedo_override


def _lit(scene: o3d.t.geometry.RaycastingScene, normals: np.ndarray, dot: np.ndarray,
         directions: np.ndarray, t_hit: np.ndarray, toward_light: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray]:
    """Each hit's light from a distant lamp, toward_light (3,) in the camera frame -> (p,)
    float32 cos of the angle between the normal, turned to the camera, and the lamp's
    direction, and (p,) cos of its angle with the half-way vector between the lamp's and the
    camera's directions (Blinn-Phong's); both 0 where the face is turned from the lamp, a ray
    toward it meets the scene, or the pixel hit nothing.

    normals (p, 3) float32 as hit; dot (p,) normal . ray direction; directions (p, 3) the
    pixels' ray directions (depth units); t_hit (p,) their hit distances (inf: none)."""
    light = (toward_light / np.linalg.norm(toward_light)).astype(np.float32)
    facing = -np.sign(dot)[:, None] * normals  # the side the camera sees
    cos_light = np.clip(facing @ light, 0.0, 1.0)
    lit = np.flatnonzero(np.isfinite(t_hit) & (cos_light > 0.0))
    # start a hair off the surface (along its seen side), so a ray does not hit its own face
    starts = (directions[lit] * t_hit[lit, None] + SHADOW_OFFSET_MM * facing[lit])
    rays = np.hstack([starts, np.broadcast_to(light, starts.shape)]).astype(np.float32)
    blocked = np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
    cos_light[lit[blocked]] = 0.0
    half = _unit_rows(light - directions / np.linalg.norm(directions, axis=1, keepdims=True))
    cos_half = np.where(cos_light > 0.0, np.clip(np.einsum("ij,ij->i", facing, half), 0.0, 1.0),
                        0.0).astype(np.float32)
    return cos_light, cos_half


def render(
    surfaces: list[SceneSurface],
    intrinsics: CameraIntrinsics,
    world_from_cam: np.ndarray,
    *,
    ambient: float = AMBIENT,
    light_direction: np.ndarray | None = None,
    specular: float = 0.0,
    shininess: float = SHININESS,
    background_rgb: np.ndarray = BACKGROUND_RGB,
) -> RenderedView:
    """Ray cast `surfaces` through a pinhole camera into an ideal RGB-D view.

    surfaces       : triangle surfaces in the world (robot) frame; RenderedView.geometry_index
                     indexes this list.
    intrinsics     : image size, pinhole parameters (optical frame) and lens distortion.
    world_from_cam : (4, 4) pose of the camera's optical frame in the world, mm.
    ambient        : colour = base * (ambient + (1 - ambient) * cos_light), a Lambertian
                     term plus ambient light; 1 gives flat base colours. The shade is
                     quantised to 1/255 of cos_light (a lookup table).
    light_direction: (3,) toward a distant light, world frame (any length), or None: the
                     light at the camera, cos_light = cos_incidence and no shadow. A distant
                     light leaves the faces turned from it and the points it cannot reach (hard
                     shadows, a second ray cast) at the ambient share.
    specular       : a glossy scene's white highlight, 255 specular cos_half^shininess
                     levels added to every channel (Blinn-Phong: cos_half, of the angle
                     between the normal and the half-way vector between the light's and the
                     camera's directions, is cos_incidence with the light at the camera); 0
                     gives matte surfaces.
    background_rgb : (3,) colour where no ray hits.
    """
    h, w = intrinsics.height, intrinsics.width
    rays, unit_directions = _pixel_rays(intrinsics)
    scene, surface_of_id, vertices_cam = _camera_frame_scene(surfaces, invert_pose(world_from_cam))
    # Flat per-pixel views of the outputs (no copies). Every pixel is processed, background
    # included (a miss has normal 0 and its own row in the shading table), and gathers use
    # np.take: on 300k pixels, boolean-mask selection and fancy indexing are several times slower.
    hits = {name: tensor.numpy() for name, tensor in scene.cast_rays(rays).items()}
    hits = {name: array.reshape(h * w, *array.shape[2:]) for name, array in hits.items()}
    hit = np.isfinite(hits["t_hit"])
    # A miss has the invalid id 2^32 - 1: clamped to the last entry, the background.
    surface = surface_of_id.take(np.minimum(hits["geometry_ids"], len(surface_of_id) - 1))
    normals = hits["primitive_normals"]  # (h * w, 3) float32 unit, 0 on a miss
    albedo_override = _interpolate_at_hits(surfaces, vertices_cam, surface, hits, normals)
    # Column by column: several times faster than einsum on (h * w, 3) float32.
    dot = sum(normals[:, axis] * unit_directions[axis] for axis in range(3))
    cos_incidence = np.minimum(np.abs(dot), 1.0)
    cos_light, cos_half = (cos_incidence, cos_incidence) if light_direction is None else _lit(
        scene, normals, dot, rays.numpy().reshape(h * w, 6)[:, 3:], hits["t_hit"],
        invert_pose(world_from_cam)[:3, :3] @ np.asarray(light_direction, dtype=float))

    shading = _shading_table(surfaces, ambient, background_rgb).reshape(-1, 3)
    level = np.rint(cos_light * 255.0).astype(np.int64)
    color = shading.take(surface * 256 + level, axis=0)
    for pixels, albedo in albedo_override:
        shade = ambient + (1.0 - ambient) * cos_light[pixels]
        color[pixels] = np.clip(np.rint(albedo * shade[:, None]), 0, 255).astype(np.uint8)
    if specular > 0.0:
        gloss = np.where(hit, specular * 255.0 * cos_half.astype(float) ** shininess, 0.0)
        color = np.clip(np.rint(color + gloss[:, None]), 0, 255).astype(np.uint8)

    return RenderedView(
        depth_mm=np.where(hit, hits["t_hit"], 0.0).astype(float).reshape(h, w),
        color=color.reshape(h, w, 3),
        geometry_index=np.where(hit, surface, -1).astype(np.int32).reshape(h, w),
        normals_cam=normals.reshape(h, w, 3),
        cos_incidence=cos_incidence.reshape(h, w),
    )
