"""Facial features as 2D shapes in the head's frontal parametrisation, shared by landmarks and paint.

Head-local axes (units ~ head half-width): x towards the image right of a frontal face, y down,
z away from the camera (the face is at z ~ -0.9). A feature is a region of the (u, v) = (x, y)
plane; it is painted on whatever front surface point has those (u, v), and its landmarks are
points of the same curves lifted onto that surface (``geometry.py``). Because one function
gives both, landmarks sit exactly on the painted borders (eye and lip outlines, brow centre
lines).

"Left" follows ``landmarks.shape.ibug68``: the image-left feature of a frontal face (iBUG 17-21, 36-41),
which gets class ``l_brow`` / ``l_eye`` (see docs/DATA_FORMAT.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lsr.data.classes import SEG_CLASS_ID
from lsr.data.synth.persons import Identity

SKIN, NOSE, MOUTH, U_LIP, L_LIP = (SEG_CLASS_ID[n] for n in ("skin", "nose", "mouth", "u_lip", "l_lip"))
L_EYE, R_EYE, L_BROW, R_BROW, GLASSES = (SEG_CLASS_ID[n] for n in ("l_eye", "r_eye", "l_brow", "r_brow", "eyeglasses"))
INNER_CORNER = 0.85  # inner lip corners at 85% of the mouth half-width
FRONT_Z = -0.35  # features are painted only on the front of the head (local z below this)


@dataclasses.dataclass(frozen=True)
class FaceLayout:
    """Where the features of one frame are (identity shape + expression), in (u, v) units."""

    eye_x: float  # |u| of the eye centres
    eye_y: float
    eye_half_width: float
    eye_up: float  # upper lid height at the centre when open
    eye_down: float
    eye_open: float
    gaze: tuple[float, float]
    iris_radius: float
    brow_x: float
    brow_y: float
    brow_half_width: float
    brow_thickness: float
    brow_arch: float
    mouth_y: float
    mouth_half_width: float
    upper_lip: float
    lower_lip: float
    mouth_gap: float  # inner opening at the centre
    smile: float
    nose_base_y: float
    nose_half_width: float


def face_layout(identity: Identity, frame: dict, nose_bottom: float, nose_half_width: float) -> FaceLayout:
    """Layout for one frame. frame: a ``Motion.frame(i)`` dict (mouth_open, smile, ...)."""
    eye_size, lip = identity.eye_size, identity.lip_size
    smile = float(frame["smile"])
    return FaceLayout(
        eye_x=0.3 * identity.eye_spacing,
        eye_y=-0.1,
        eye_half_width=0.135 * eye_size,
        eye_up=0.062 * eye_size,
        eye_down=0.042 * eye_size,
        eye_open=float(frame["eye_open"]),
        gaze=(float(frame["gaze_x"]), float(frame["gaze_y"])),
        iris_radius=0.058 * eye_size,
        brow_x=0.3 * identity.eye_spacing,
        brow_y=-0.265 - 0.05 * float(frame["brow_raise"]),
        brow_half_width=0.175,
        brow_thickness=0.024 * identity.brow_thickness,
        brow_arch=0.035 * identity.brow_arch,
        mouth_y=0.38 * identity.face_length,
        mouth_half_width=(0.21 + 0.035 * smile) * lip,
        upper_lip=0.045 * lip,
        lower_lip=0.055 * lip,
        mouth_gap=0.13 * float(frame["mouth_open"]),
        smile=smile,
        nose_base_y=nose_bottom,
        nose_half_width=nose_half_width,
    )


# ---------------------------------------------------------------- curves (one source of truth)
def eye_lids(layout: FaceLayout, side: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eye ``side`` (-1 image-left, +1 image-right) at s in [-1, 1] (image left -> right).

    Returns u, upper-lid v, lower-lid v. The almond closes as ``eye_open`` -> 0.
    """
    u = side * layout.eye_x + s * layout.eye_half_width
    outer = s * side  # +1 at the outer corner
    profile = np.sqrt(np.clip(1.0 - s**2, 0.0, None)) * (1.0 - 0.12 * outer)
    centre_v = layout.eye_y - 0.012 * outer  # outer corners a little higher
    upper = centre_v - layout.eye_up * layout.eye_open * profile
    lower = centre_v + layout.eye_down * (0.25 + 0.75 * layout.eye_open) * profile
    return u, upper, lower


def brow_line(layout: FaceLayout, side: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brow ``side`` at s in [-1, 1]: u, centre-line v, half thickness (thinner at the outer end)."""
    u = side * layout.brow_x + s * layout.brow_half_width
    outer = s * side
    v = layout.brow_y - layout.brow_arch * (1.0 - (s - 0.25 * side) ** 2) + 0.02 * np.clip(outer, 0, None)
    half = layout.brow_thickness * (1.0 - 0.45 * np.clip(outer, 0.0, None))
    return u, v, half


def lip_curves(layout: FaceLayout, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """Mouth at s in [-1, 1] (image left -> right): u, outer-upper, inner-upper, inner-lower, outer-lower v."""
    u = s * layout.mouth_half_width
    line = layout.mouth_y - 0.045 * layout.smile * s**2
    inner = np.clip(1.0 - (s / INNER_CORNER) ** 2, 0.0, None)
    inner_upper = line - 0.3 * layout.mouth_gap * inner
    inner_lower = line + 0.7 * layout.mouth_gap * inner
    edge = np.clip(1.0 - s**2, 0.0, None) ** 0.6
    bow = 1.0 - 0.35 * np.exp(-((s / 0.14) ** 2))  # cupid's bow dip at the centre
    outer_upper = inner_upper - layout.upper_lip * edge * bow * (1.0 - 0.3 * layout.smile)
    outer_lower = inner_lower + layout.lower_lip * edge
    return u, outer_upper, inner_upper, inner_lower, outer_lower


def landmarks_uv(layout: FaceLayout) -> np.ndarray:
    """(u, v) of points 17..67 (brows, nose, eyes, lips); jaw 0..16 is done in ``geometry``.

    Returns (68, 2) float64 with rows 0..16 NaN; rows 27..35 hold only (u, v) targets on the
    nose, lifted in ``geometry``.
    """
    points = np.full((68, 2), np.nan)
    s5 = np.linspace(-1.0, 1.0, 5)
    for first, side in ((17, -1), (22, 1)):
        u, v, _ = brow_line(layout, side, s5)
        points[first : first + 5] = np.stack([u, v], 1)
    third = np.array([-1.0, -1 / 3, 1 / 3, 1.0])
    for first, side in ((36, -1), (42, 1)):
        u, upper, lower = eye_lids(layout, side, third)
        # iBUG order: left corner, upper 1/3, upper 2/3, right corner, lower 2/3, lower 1/3.
        points[first : first + 6, 0] = [u[0], u[1], u[2], u[3], u[2], u[1]]
        points[first : first + 6, 1] = [upper[0], upper[1], upper[2], upper[3], lower[2], lower[1]]
    s_out = np.array([-1.0, -0.55, -0.22, 0.0, 0.22, 0.55, 1.0])
    u, outer_upper, _, _, outer_lower = lip_curves(layout, s_out)
    points[48:55] = np.stack([u, outer_upper], 1)  # 48 left corner .. 54 right corner
    points[55:60] = np.stack([u[5:0:-1], outer_lower[5:0:-1]], 1)  # 55..59 lower, right -> left
    s_in = INNER_CORNER * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    u, _, inner_upper, inner_lower, _ = lip_curves(layout, s_in)
    points[60:65] = np.stack([u, inner_upper], 1)
    points[65:68] = np.stack([u[3:0:-1], inner_lower[3:0:-1]], 1)
    base = layout.nose_base_y
    half = layout.nose_half_width
    points[31:36, 0] = np.array([-0.8, -0.42, 0.0, 0.42, 0.8]) * half
    points[31:36, 1] = base - np.array([0.035, 0.012, 0.0, 0.012, 0.035])
    return points


# ---------------------------------------------------------------- paint
def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _in_box(mask: np.ndarray, u: np.ndarray, v: np.ndarray, u0: float, half_u: float, v0: float, half_v: float) -> np.ndarray:
    """Indices of points with mask set and (u, v) within the box centred at (u0, v0)."""
    return np.flatnonzero(mask & (np.abs(u - u0) <= half_u) & (np.abs(v - v0) <= half_v))


def paint_face(identity: Identity, layout: FaceLayout, u: np.ndarray, v: np.ndarray, z: np.ndarray, on_nose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Albedo and class of face-surface points.

    u, v, z: (n,) head-local coordinates of hits on the cranium, jaw or nose; on_nose: (n,) bool.
    Returns albedo (n, 3) float32 in [0, 1] and classes (n,) uint8.
    """
    n = u.shape[0]
    skin = np.asarray(identity.skin, np.float32)
    albedo = np.broadcast_to(skin, (n, 3)).copy()
    classes = np.where(on_nose, NOSE, SKIN).astype(np.uint8)
    front = z < FRONT_Z
    # Soft tone variation: darker eye sockets and nose sides, rosier cheeks (helps a HOG detector see
    # the face structure as in real photos).
    shade = np.ones(n, np.float32)
    for side in (-1, 1):
        du, dv = u - side * layout.eye_x, v - layout.eye_y + 0.02
        shade -= 0.35 * np.exp(-(du**2 / 0.15**2 + dv**2 / 0.09**2))
        cheek = np.exp(-((u - side * 0.38) ** 2 + (v - 0.18) ** 2) / 0.03)
        albedo[:, 0] += 0.05 * cheek
    shade -= 0.12 * np.exp(-((u / 0.2) ** 2 + ((v - layout.nose_base_y - 0.03) / 0.03) ** 2))  # under-nose shadow
    albedo *= shade[:, None]

    if identity.beard:  # chin, jaw and moustache; stubble-like mix with the skin
        _, outer_upper, _, _, outer_lower = lip_curves(layout, np.clip(u / layout.mouth_half_width, -1, 1))
        around_lips = (v > outer_upper - 0.015) & (v < outer_lower + 0.015) & (np.abs(u) < layout.mouth_half_width + 0.015)
        moustache = (v > layout.nose_base_y + 0.03) & (v < outer_upper) & (np.abs(u) < layout.mouth_half_width + 0.02)
        chin = v > layout.mouth_y - 0.05 + 0.35 * np.clip(np.abs(u) - 0.25, 0, None)
        beard = (z < 0.1) & ~around_lips & (moustache | chin)
        texture = 0.7 + 0.3 * np.sin(u * 180.0) * np.sin(v * 150.0)
        mix = np.asarray(identity.hair_colour, np.float32) * texture[:, None]
        albedo[beard] = 0.55 * albedo[beard] + 0.45 * mix[beard]

    # Each feature is evaluated only on the points inside its (u, v) box (speed).
    for side, cls in ((-1, L_BROW), (1, R_BROW)):
        idx = _in_box(front, u, v, side * layout.brow_x, layout.brow_half_width, layout.brow_y - 0.02, 0.1)
        s = (u[idx] - side * layout.brow_x) / layout.brow_half_width
        _, centre, half = brow_line(layout, side, s)
        brow = idx[(np.abs(s) <= 1.0) & (np.abs(v[idx] - centre) <= half)]
        classes[brow] = cls
        hair = 0.8 + 0.2 * np.sin(u[brow] * 260.0 + v[brow] * 80.0)
        albedo[brow] = np.asarray(identity.brow_colour, np.float32) * hair[:, None]

    # Eyes: sclera, iris, pupil; a dark lash line above the upper lid.
    for side, cls in ((-1, L_EYE), (1, R_EYE)):
        idx = _in_box(front, u, v, side * layout.eye_x, layout.eye_half_width, layout.eye_y, 0.12)
        ui, vi = u[idx], v[idx]
        s = (ui - side * layout.eye_x) / layout.eye_half_width
        _, upper, lower = eye_lids(layout, side, s)
        lash = idx[(vi < upper) & (vi > upper - 0.026 - 0.012 * (1 - np.abs(s)))]
        albedo[lash] *= 0.15
        inside = (vi >= upper) & (vi <= lower)
        eye = idx[inside]
        if eye.size == 0:
            continue
        classes[eye] = cls
        ue, ve = ui[inside], vi[inside]
        iris_u = side * layout.eye_x + layout.gaze[0] * 0.35 * layout.eye_half_width
        iris_v = layout.eye_y + layout.gaze[1] * 0.015
        r = np.sqrt((ue - iris_u) ** 2 + (ve - iris_v) ** 2)
        colour = np.broadcast_to(np.float32([0.85, 0.82, 0.8]), (ue.size, 3)).copy()
        colour[r < layout.iris_radius] = np.asarray(identity.iris, np.float32)
        colour[r < layout.iris_radius * 0.45] = 0.03
        # Upper-lid shadow on the eyeball.
        colour *= (0.6 + 0.4 * _smoothstep(0.0, 0.03, ve - upper[inside]))[:, None]
        albedo[eye] = colour

    # Lips and inner mouth (teeth on top, dark mouth below).
    idx = _in_box(front, u, v, 0.0, layout.mouth_half_width, layout.mouth_y + 0.04, 0.22)
    ui, vi = u[idx], v[idx]
    s = ui / layout.mouth_half_width
    _, outer_upper, inner_upper, inner_lower, outer_lower = lip_curves(layout, s)
    lips = (vi >= outer_upper) & (vi <= outer_lower)
    mouth = lips & (vi > inner_upper) & (vi < inner_lower)
    middle = 0.5 * (inner_upper + inner_lower)
    lip_colour = np.asarray(identity.lip_colour, np.float32)
    upper_lip, lower_lip = idx[lips & ~mouth & (vi <= middle)], idx[lips & ~mouth & (vi > middle)]
    classes[upper_lip], classes[lower_lip], classes[idx[mouth]] = U_LIP, L_LIP, MOUTH
    albedo[upper_lip] = lip_colour * 0.85
    albedo[lower_lip] = lip_colour
    # A dark line where the lips meet keeps a closed mouth visible.
    albedo[idx[lips & (np.abs(vi - middle) < 0.008) & (np.abs(s) < INNER_CORNER)]] *= 0.45
    albedo[idx[mouth]] = np.float32([0.25, 0.05, 0.06])
    albedo[idx[mouth & (vi < inner_upper + 0.035)]] = np.float32([0.9, 0.88, 0.82])  # teeth

    # Nostrils.
    for side in (-1, 1):
        idx = _in_box(on_nose, u, v, side * 0.45 * layout.nose_half_width, 0.3 * layout.nose_half_width, layout.nose_base_y - 0.022, 0.018)
        du = (u[idx] - side * 0.45 * layout.nose_half_width) / (0.3 * layout.nose_half_width)
        dv = (v[idx] - layout.nose_base_y + 0.022) / 0.018
        albedo[idx[du**2 + dv**2 < 1.0]] *= 0.3

    if identity.glasses:
        rim = np.zeros(n, bool)
        for side in (-1, 1):
            du = (u - side * layout.eye_x) / 0.165
            dv = (v - layout.eye_y - 0.005) / 0.1
            radius = (np.abs(du) ** 3 + np.abs(dv) ** 3) ** (1 / 3)
            rim |= front & (radius > 1.0) & (radius < 1.15)
            albedo[front & (radius <= 1.0)] *= 0.92  # lens tint
        rim |= front & (np.abs(u) < layout.eye_x - 0.16) & (np.abs(v - layout.eye_y + 0.03) < 0.012)
        rim |= (np.abs(u) > layout.eye_x + 0.17) & (np.abs(v - layout.eye_y + 0.01) < 0.013) & (z < 0.15)
        albedo[rim] = np.asarray(identity.glasses_colour, np.float32)
        classes[rim] = GLASSES
    return albedo, classes
