"""Vectorised numpy ray-caster: z-buffer composition of analytically ray-cast ellipsoids.

Each surface is cast only inside its projected bounding box (exact for an ellipsoid), the
nearest hit wins per pixel, then every surface shades its own pixels: albedo (painted
features in head-local coordinates, ``features.paint_face``) times Lambert + ambient light,
plus a small Blinn highlight. The class map comes from the same pass, so it is exact.

Shapes: frames are (S, S, 3) float32 in [0, 1] until ``effects`` turns them into uint8;
class maps are (S, S) uint8 in the order of ``lsr.data.classes.SEG_CLASSES``.
"""

from __future__ import annotations

import cv2
import numpy as np

from lsr.data.classes import SEG_CLASS_ID
from lsr.data.synth.features import FaceLayout, paint_face
from lsr.data.synth.geometry import Camera, Ellipsoid, HeadParts, HeadPose, PIVOT, ray_entry_z
from lsr.data.synth.persons import Identity, Scene

HAIR, HAT, NECK, CLOTH = (SEG_CLASS_ID[n] for n in ("hair", "hat", "neck", "cloth"))
L_EAR, R_EAR = SEG_CLASS_ID["l_ear"], SEG_CLASS_ID["r_ear"]
# Hair line height (head-local y) at the front (z = -0.7) and at the back (z = 0.9) per style.
_HAIR_LINE = {"short": (-0.72, 0.35), "fringe": (-0.64, 0.35), "long": (-0.7, 0.6), "bald": (-0.72, 0.3)}
_VIEW = np.array([0.0, 0.0, -1.0], np.float32)  # towards the camera


def background_image(scene: Scene, size: int) -> np.ndarray:
    """Static background of a video: (S, S, 3) float32 in [0, 1]."""
    a, b = np.float32(scene.colour_a), np.float32(scene.colour_b)
    if scene.background == "flat":
        return np.broadcast_to(a, (size, size, 3)).copy()
    coords = (np.arange(size, dtype=np.float32) - size / 2) / size
    if scene.background == "gradient":
        t = np.clip(0.5 + np.cos(scene.gradient_angle) * coords[None, :] + np.sin(scene.gradient_angle) * coords[:, None], 0, 1)
    else:
        rng = np.random.default_rng(scene.texture_seed)
        coarse = cv2.resize(rng.random((6, 6), dtype=np.float32), (size, size), interpolation=cv2.INTER_CUBIC)
        fine = cv2.resize(rng.random((24, 24), dtype=np.float32), (size, size), interpolation=cv2.INTER_LINEAR)
        t = np.clip(0.75 * coarse + 0.35 * fine - 0.05, 0, 1)
    return (a * (1 - t[..., None]) + b * t[..., None]).astype(np.float32)


def _hair_keep(identity: Identity, local: np.ndarray) -> np.ndarray:
    """Which entry points of the hair cap are hair (below that the face/neck shows): (n,) bool."""
    front, back = _HAIR_LINE[identity.hair_style]
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    t = np.clip((z + 0.7) / 1.6, 0.0, 1.0) ** 1.5
    line = front + (back - front) * t
    if identity.hair_style == "fringe":
        line = line + 0.025 * np.sin(x * 28.0) * (1 - t)
    keep = y < line
    if identity.hair_style == "bald":  # a horseshoe of hair at the back and sides, no crown
        keep &= (y > -0.3) & (z > 0.25)
    return keep


class _Surface:
    """One ray-cast primitive: an ellipsoid (or the vertical neck cylinder) with a hit filter."""

    def __init__(self, name: str, ellipsoid: Ellipsoid, keep=None, cylinder_y: tuple[float, float] | None = None):
        self.name, self.ellipsoid, self.keep, self.cylinder_y = name, ellipsoid, keep, cylinder_y


def _cast(surface: _Surface, grid_x: np.ndarray, grid_y: np.ndarray, pose: HeadPose):
    """Entry depths of ``surface`` on its pixel box: (z (h, w) float32 with inf = miss, y0, x0)."""
    e = surface.ellipsoid
    half = e.half_extent
    size = grid_x.shape[1]
    if surface.cylinder_y is not None:  # vertical elliptic cylinder, radii x and z, clipped in y
        lo, hi = surface.cylinder_y
        box_y = (lo, hi)
    else:
        box_y = (e.centre[1] - half[1], e.centre[1] + half[1])
    x0 = max(0, int(np.searchsorted(grid_x[0], e.centre[0] - half[0])))
    x1 = min(size, int(np.searchsorted(grid_x[0], e.centre[0] + half[0])) + 1)
    y0 = max(0, int(np.searchsorted(grid_y[:, 0], box_y[0])))
    y1 = min(size, int(np.searchsorted(grid_y[:, 0], box_y[1])) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    xs, ys = grid_x[:, x0:x1], grid_y[y0:y1]
    if surface.cylinder_y is not None:
        radial = 1.0 - ((xs - e.centre[0]) / e.radii[0]) ** 2
        with np.errstate(invalid="ignore"):
            z = np.where(radial >= 0, e.centre[2] - e.radii[2] * np.sqrt(radial), np.inf)
        z = np.broadcast_to(z, (y1 - y0, x1 - x0)).astype(np.float32)
    else:
        z = ray_entry_z(e, xs, ys).astype(np.float32)
    if surface.keep is not None:
        iy, ix = np.nonzero(np.isfinite(z))
        points = np.stack([xs[0, ix], ys[iy, 0], z[iy, ix]], axis=1)
        drop = ~surface.keep(pose.to_local(points))
        z[iy[drop], ix[drop]] = np.inf
    return z, y0, x0


def _lambert(normals: np.ndarray, light_dir: np.ndarray, light: float, ambient: float, shine: float) -> np.ndarray:
    """Per-point brightness (n,) for unit camera-space normals (n, 3)."""
    to_light = -light_dir
    diffuse = np.clip(normals @ to_light, 0.0, None)
    half = to_light + _VIEW
    half = half / np.linalg.norm(half)
    spec = np.clip(normals @ half, 0.0, None) ** 24 * shine
    return ambient + light * diffuse + spec


def render_head(
    identity: Identity,
    parts: HeadParts,
    layout: FaceLayout,
    pose: HeadPose,
    camera: Camera,
    background: np.ndarray,
    light_dir: np.ndarray,
    light: float,
    ambient: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame: (S, S, 3) float32 image in [0, ~1.2], (S, S) uint8 class map, (S, S) float32 depth (inf = background)."""
    size = camera.size
    grid_x, grid_y = camera.pixel_grid()
    rotation, translation = pose.rotation, pose.translation
    to_cam = lambda e: e.transformed(rotation, translation)  # noqa: E731
    neck_top = PIVOT + pose.shift
    surfaces = [
        _Surface("torso", Ellipsoid(neck_top + np.array([0.0, 1.25, 0.2]), np.array([1.55, 0.72, 0.55]))),
        _Surface("neck", Ellipsoid(neck_top + np.array([0.0, 0.0, 0.05]), np.array([0.3, 1.0, 0.29])), cylinder_y=(neck_top[1] - 0.3, neck_top[1] + 1.0)),
        _Surface("cranium", to_cam(parts.cranium)),
        _Surface("jaw", to_cam(parts.jaw)),
        _Surface("nose_bridge", to_cam(parts.nose_bridge)),
        _Surface("nose", to_cam(parts.nose)),
        _Surface("ear_left", to_cam(parts.ear_left)),
        _Surface("ear_right", to_cam(parts.ear_right)),
    ]
    surfaces.append(_Surface("hair_cap", to_cam(parts.hair_cap), keep=lambda p: _hair_keep(identity, p)))
    if identity.hair_style == "long":
        surfaces.append(_Surface("hair_back", to_cam(parts.hair_back), keep=lambda p: (p[:, 1] < 1.2) & (p[:, 2] > -0.1)))
    if identity.hat:
        surfaces.append(_Surface("hat_cap", to_cam(parts.hat_cap), keep=lambda p: p[:, 1] < -0.7 + 0.25 * np.clip(p[:, 2], 0, None)))
        surfaces.append(_Surface("hat_brim", to_cam(parts.hat_brim)))

    depth = np.full((size, size), np.inf, np.float32)
    owner = np.zeros((size, size), np.int8)  # 0 = background, k + 1 = surfaces[k]
    for k, surface in enumerate(surfaces):
        cast = _cast(surface, grid_x, grid_y, pose)
        if cast is None:
            continue
        z, y0, x0 = cast
        region = depth[y0 : y0 + z.shape[0], x0 : x0 + z.shape[1]]
        closer = z < region
        region[closer] = z[closer]
        owner[y0 : y0 + z.shape[0], x0 : x0 + z.shape[1]][closer] = k + 1

    image = background.copy()
    classes = np.zeros((size, size), np.uint8)
    light_dir = np.asarray(light_dir, np.float32)
    face_ids = [k + 1 for k, s in enumerate(surfaces) if s.name in ("cranium", "jaw", "nose", "nose_bridge")]
    nose_ids = [k + 1 for k, s in enumerate(surfaces) if s.name in ("nose", "nose_bridge")]
    face_mask = (owner >= min(face_ids)) & (owner <= max(face_ids))  # the face surfaces are consecutive
    assert max(face_ids) - min(face_ids) == len(face_ids) - 1
    for k, surface in enumerate(surfaces):
        if surface.name in ("cranium", "jaw", "nose_bridge"):
            continue  # shaded together with the nose below
        mask = face_mask if surface.name == "nose" else owner == k + 1
        iy, ix = np.nonzero(mask)
        if iy.size == 0:
            continue
        points = np.stack([grid_x[0, ix], grid_y[iy, 0], depth[iy, ix]], axis=1)
        normals = _normals(surfaces, owner[iy, ix], points)
        shine = 0.0
        if surface.name == "nose":  # the whole face
            local = pose.to_local(points)
            albedo, cls = paint_face(identity, layout, local[:, 0], local[:, 1], local[:, 2], np.isin(owner[iy, ix], nose_ids))
            shine = 0.12
        elif surface.name.startswith("ear"):
            local = pose.to_local(points)
            albedo, cls = _paint_ear(identity, parts, surface.name, local)
        elif surface.name.startswith("hair"):
            local = pose.to_local(points)
            strands = 0.82 + 0.18 * np.sin(np.arctan2(local[:, 0], local[:, 2] + 0.3) * 60.0 + local[:, 1] * 9.0)
            albedo = np.asarray(identity.hair_colour, np.float32) * strands[:, None]
            cls, shine = HAIR, 0.25
        elif surface.name.startswith("hat"):
            albedo, cls = np.broadcast_to(np.float32(identity.hat_colour), points.shape), HAT
        elif surface.name == "neck":
            under_chin = np.clip((points[:, 1] - (PIVOT[1] + pose.shift[1] - 0.1)) / 0.35, 0.45, 1.0)
            albedo = np.float32(identity.skin) * under_chin[:, None].astype(np.float32)
            cls = NECK
        else:  # torso
            cloth = np.float32(identity.cloth_colour)
            albedo = np.broadcast_to(cloth, points.shape).copy()
            if identity.cloth_stripes:
                albedo *= (0.75 + 0.25 * (np.sin(points[:, 1] * 40.0) > 0))[:, None]
            cls = CLOTH
        brightness = _lambert(normals, light_dir, light, ambient, shine)
        image[iy, ix] = albedo * brightness[:, None]
        classes[iy, ix] = cls
    return image, classes, depth


def _normals(surfaces: list[_Surface], owners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Unit camera-space normals (n, 3) of points lying on surfaces[owners - 1]."""
    normals = np.empty_like(points)
    names = [s.name for s in surfaces]
    skull_ids = (names.index("cranium") + 1, names.index("jaw") + 1)
    for owner_id in np.unique(owners):
        if owner_id in skull_ids:
            continue  # smooth union below
        sel = owners == owner_id
        surface = surfaces[owner_id - 1]
        e = surface.ellipsoid
        delta = points[sel] - e.centre
        if surface.cylinder_y is not None:
            delta[:, 1] = 0.0
        normal = delta @ e.quadric  # M symmetric: (M d)^T = d^T M
        normals[sel] = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    skull = (owners == skull_ids[0]) | (owners == skull_ids[1])
    if skull.any():
        normals[skull] = _smooth_union_normals([surfaces[names.index("cranium")].ellipsoid, surfaces[names.index("jaw")].ellipsoid], points[skull])
    return normals


def _smooth_union_normals(ellipsoids: list[Ellipsoid], points: np.ndarray, sharpness: float = 8.0) -> np.ndarray:
    """Normals of the smooth union (soft-min of the implicit functions) of ``ellipsoids`` at points (n, 3).

    Shading the union of cranium and jaw with this gradient hides the crease where they meet;
    the silhouette (the geometry) is unchanged.
    """
    total = np.zeros_like(points)
    weights = np.zeros(points.shape[0], points.dtype)
    for e in ellipsoids:
        delta = points - e.centre
        grad = delta @ e.quadric
        implicit = np.einsum("ij,ij->i", delta, grad) - 1.0
        weight = np.exp(-sharpness * np.clip(implicit, 0.0, None))
        total += weight[:, None] * grad / np.linalg.norm(grad, axis=1, keepdims=True)
        weights += weight
    total /= weights[:, None]
    return total / np.linalg.norm(total, axis=1, keepdims=True)


def _paint_ear(identity: Identity, parts: HeadParts, name: str, local: np.ndarray) -> tuple[np.ndarray, int]:
    ear = parts.ear_left if name == "ear_left" else parts.ear_right
    d = (local - ear.centre) @ ear.rot / ear.radii  # ear-local, unit radius
    inner = d[:, 1] ** 2 + d[:, 2] ** 2 < 0.35
    albedo = np.broadcast_to(np.float32(identity.skin), local.shape).copy()
    albedo[inner] *= 0.72
    return albedo, (L_EAR if name == "ear_left" else R_EAR)
