"""The head model: ellipsoids in head-local space, the camera, and exact 68-point landmarks.

Spaces. Head-local: x towards the image right of a frontal face, y down, z away from the
camera, units ~ the head half-width. Camera: the same axes; a point maps to pixels by an
orthographic camera ``px = cx + scale * x``, ``py = cy + scale * y`` (pixel centres at integer
coordinates, as in dlib/OpenCV), so rays are lines of constant (x, y) along +z.
A head point p goes to the camera by ``R (p - PIVOT) + PIVOT + shift`` with
``R = landmarks.motion.head_pose.rotation_matrix(yaw, pitch, roll)``: the head turns about the top of the
neck, and the pose recorded in ``pose.npy`` is exactly (yaw, pitch, roll) of that R.

Landmarks (iBUG-68). Brows, eyes, lips and the nose base come from the feature curves of
``features.py`` lifted onto the front surface, nose bridge 27..30 runs down the nose ridge to the
tip (the front-most nose point). The jaw 0..16 follows the *visible* silhouette, as an annotator
marks it: each jaw point has an anatomical spot on the rim of the jaw ellipsoid (on the frontal
outline, from ear level (0) through the chin (8) to the other ear (16)); if that spot turns away
from the camera it "marches" along the ellipsoid meridian towards the face centre until it
reaches the occluding contour (normal perpendicular to the view), like 3DDFA's landmark marching.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from landmarks.motion.head_pose import rotation_matrix
from lsr.data.synth.features import FaceLayout, face_layout, landmarks_uv
from lsr.data.synth.persons import Identity

PIVOT = np.array([0.0, 0.45, 0.1])  # top of the neck, head-local = camera at rest
FRAME_CENTRE_Y = 0.45  # camera y = 0 sits at 45% of the image height
BASE_SCALE = 0.345  # pixels per head unit / image size: face (cheek to cheek ~1.45) ~50% of the width
JAW_LEVEL_TOP = -0.02  # head-local y of jaw points 0 and 16 (ear level)


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


@dataclasses.dataclass(frozen=True)
class Ellipsoid:
    """{p : (p - c)^T M (p - c) <= 1}, M = rot diag(1/r^2) rot^T. centre (3,), radii (3,), rot (3, 3)."""

    centre: np.ndarray
    radii: np.ndarray
    rot: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(3))

    @functools.cached_property
    def quadric(self) -> np.ndarray:
        return self.rot @ np.diag(1.0 / self.radii**2) @ self.rot.T

    @functools.cached_property
    def half_extent(self) -> np.ndarray:
        """(3,) half sizes of the axis-aligned bounding box."""
        return np.sqrt(np.diag(self.rot @ np.diag(self.radii**2) @ self.rot.T))

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> "Ellipsoid":
        """The ellipsoid after p -> rotation p + translation."""
        return Ellipsoid(rotation @ self.centre + translation, self.radii, rotation @ self.rot)


def ray_entry_z(ellipsoid: Ellipsoid, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Depth z where rays (x, y, -inf -> +inf) enter the ellipsoid; inf where they miss.

    x, y: broadcastable arrays (e.g. (1, W) and (H, 1)); returns their broadcast shape, float32
    when inputs are float32. Orthographic rays make the quadratic's leading coefficient constant.
    """
    m = ellipsoid.quadric
    qx, qy = x - ellipsoid.centre[0], y - ellipsoid.centre[1]
    a = m[2, 2]
    b = m[0, 2] * qx + m[1, 2] * qy
    c = m[0, 0] * qx * qx + 2.0 * m[0, 1] * qx * qy + m[1, 1] * qy * qy - 1.0
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        z = ellipsoid.centre[2] + (-b - np.sqrt(disc)) / a
    return np.where(disc >= 0, z, np.inf)


@dataclasses.dataclass(frozen=True)
class HeadParts:
    """The head's ellipsoids in head-local space for one frame."""

    cranium: Ellipsoid
    jaw: Ellipsoid
    nose: Ellipsoid
    nose_bridge: Ellipsoid
    ear_left: Ellipsoid
    ear_right: Ellipsoid
    hair_cap: Ellipsoid
    hair_back: Ellipsoid
    hat_cap: Ellipsoid
    hat_brim: Ellipsoid

    @property
    def face(self) -> tuple[Ellipsoid, ...]:
        return (self.cranium, self.jaw, self.nose, self.nose_bridge)


def head_parts(identity: Identity, mouth_open: float) -> HeadParts:
    """Ellipsoids of ``identity`` with the jaw dropped by ``mouth_open`` in [0, 1]."""
    hw, hl = identity.head_width, identity.head_length
    cranium = Ellipsoid(np.array([0.0, -0.2, 0.08]), np.array([0.74 * hw, 0.92 * hl, 0.95]))
    jaw_drop = 0.06 * mouth_open
    jaw = Ellipsoid(
        np.array([0.0, -0.05 + 0.13 * (identity.face_length - 1.0) + jaw_drop, -0.1]),
        np.array([0.7 * identity.jaw_width, 0.79 * identity.face_length, 0.8]),
    )
    nose = Ellipsoid(
        np.array([0.0, 0.05 * identity.nose_length, -0.84]),
        np.array([0.12 * identity.nose_width, 0.2 * identity.nose_length, 0.16 * identity.nose_depth]),
        _rot_x(-28.0),  # tip forward at the bottom
    )
    bridge = Ellipsoid(
        np.array([0.0, -0.07, -0.83]), np.array([0.05 * identity.nose_width, 0.19 * identity.nose_length, 0.075]), _rot_x(-14.0)
    )
    ear_r = 0.72 * hw
    ears = [
        Ellipsoid(np.array([side * ear_r, -0.03, 0.1]), np.array([0.06, 0.19, 0.12]) * identity.ear_size, _rot_y(side * 25.0))
        for side in (-1, 1)
    ]
    volume = identity.hair_volume
    hair_cap = Ellipsoid(cranium.centre + np.array([0.0, -0.03, 0.03]), cranium.radii * np.array([1.07, 1.05, 1.06]) * volume)
    hair_back = Ellipsoid(np.array([0.0, 0.42, 0.42]), np.array([0.9 * hw * volume, 1.15, 0.52]))
    hat_cap = Ellipsoid(hair_cap.centre, hair_cap.radii * 1.05)
    hat_brim = Ellipsoid(np.array([0.0, -0.7, -0.25]), np.array([0.85 * hw, 0.03, 0.95]), _rot_x(-10.0))
    return HeadParts(cranium, jaw, nose, bridge, ears[0], ears[1], hair_cap, hair_back, hat_cap, hat_brim)


def front_z(parts: HeadParts, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Head-local z of the front-most face surface (cranium, jaw, nose, bridge) at (u, v): (n,)."""
    return np.min([ray_entry_z(e, u, v) for e in parts.face], axis=0)


def nose_landmark_frame(nose: Ellipsoid) -> tuple[float, float, np.ndarray]:
    """Nose base height, half-width at the base (in u), and the tip (3,) (front-most nose point)."""
    # Front-most point: minimise z over the ellipsoid = c - (M^-1 e_z) / sqrt(e_z^T M^-1 e_z).
    inv = nose.rot @ np.diag(nose.radii**2) @ nose.rot.T
    tip = nose.centre - inv[:, 2] / np.sqrt(inv[2, 2])
    bottom = nose.centre[1] + np.sqrt(inv[1, 1])  # lowest v of the silhouette
    base = bottom - 0.045 * nose.radii[1] / 0.2
    # Half-width of the silhouette at v = base: the frontal outline is an ellipse in (u, v).
    outline_v = np.sqrt(inv[1, 1])
    half = nose.radii[0] * np.sqrt(max(0.0, 1.0 - ((base - nose.centre[1]) / outline_v) ** 2))
    return float(base), float(half), tip


@dataclasses.dataclass(frozen=True)
class Camera:
    """Orthographic camera of one frame: ``px = cx + scale * x``, ``py = cy + scale * y``."""

    size: int
    scale: float
    cx: float
    cy: float

    def to_pixels(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) camera points -> (n, 2) pixel x, y."""
        return np.stack([self.cx + self.scale * points[:, 0], self.cy + self.scale * points[:, 1]], axis=1)

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera x of each column (1, S) and y of each row (S, 1), float32."""
        idx = np.arange(self.size, dtype=np.float32)
        return ((idx - self.cx) / self.scale)[None, :], ((idx - self.cy) / self.scale)[:, None]


def make_camera(size: int, face_scale: float, offset_x: float, offset_y: float) -> Camera:
    """Framing like VoxCeleb2 crops: head and a bit of shoulders, face ~50% of the width."""
    return Camera(size, BASE_SCALE * size * face_scale, (size - 1) / 2 + offset_x * size, FRAME_CENTRE_Y * size + offset_y * size)


@dataclasses.dataclass(frozen=True)
class HeadPose:
    """Rigid head transform of one frame: p_cam = rotation (p - PIVOT) + PIVOT + shift."""

    rotation: np.ndarray
    shift: np.ndarray

    @staticmethod
    def from_angles(yaw: float, pitch: float, roll: float, shift_x: float, shift_y: float) -> "HeadPose":
        return HeadPose(rotation_matrix(yaw, pitch, roll), np.array([shift_x, shift_y, 0.0]))

    @property
    def translation(self) -> np.ndarray:
        return PIVOT + self.shift - self.rotation @ PIVOT

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) head-local -> camera."""
        return points @ self.rotation.T + self.translation

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) camera -> head-local."""
        return (points - self.translation) @ self.rotation


def jaw_points(jaw: Ellipsoid, pose: HeadPose, samples: int = 96) -> np.ndarray:
    """Jaw landmarks 0..16 in head-local space (17, 3), marched onto the visible silhouette."""
    top = np.arcsin(np.clip((jaw.centre[1] - JAW_LEVEL_TOP) / jaw.radii[1], -1, 1))
    theta = np.linspace(np.pi + top, -top, 17)  # image-left ear level -> chin (pi/2) -> image-right
    psi = np.linspace(0.0, np.radians(85.0), samples)
    cos_psi, sin_psi = np.cos(psi)[None, :], np.sin(psi)[None, :]
    unit = np.stack(
        [cos_psi * np.cos(theta)[:, None], cos_psi * np.sin(theta)[:, None], -np.broadcast_to(sin_psi, (17, samples))], axis=-1
    )  # (17, samples, 3) on the unit sphere
    normals = unit / jaw.radii  # gradient direction of the axis-aligned jaw ellipsoid
    facing = normals @ pose.rotation[2]  # camera-z of the rotated normal (< 0: faces the camera)
    visible = facing <= 0.0
    first = np.where(visible.any(axis=1), visible.argmax(axis=1), samples - 1)
    # Linear interpolation to the zero crossing between the last hidden and first visible sample.
    prev = np.maximum(first - 1, 0)
    rows = np.arange(17)
    f0, f1 = facing[rows, prev], facing[rows, first]
    weight = np.where((first > 0) & (f0 != f1), f0 / np.where(f0 != f1, f0 - f1, 1.0), 1.0)
    on_sphere = unit[rows, prev] * (1 - weight)[:, None] + unit[rows, first] * weight[:, None]
    on_sphere /= np.linalg.norm(on_sphere, axis=1, keepdims=True)
    return jaw.centre + on_sphere * jaw.radii


def head_landmarks(identity: Identity, parts: HeadParts, frame: dict, pose: HeadPose) -> tuple[np.ndarray, FaceLayout]:
    """All 68 landmarks in head-local space (68, 3) and the frame's ``FaceLayout``."""
    base, half, tip = nose_landmark_frame(parts.nose)
    layout = face_layout(identity, frame, base, half)
    uv = landmarks_uv(layout)
    points = np.zeros((68, 3))
    points[:, :2] = np.nan_to_num(uv)
    bridge_v = np.linspace(layout.eye_y - 0.02, tip[1], 4)
    points[27:31, 0], points[27:31, 1] = tip[0], bridge_v
    points[:, 2] = front_z(parts, points[:, 0], points[:, 1])
    points[30] = tip
    points[0:17] = jaw_points(parts.jaw, pose)
    return points, layout
