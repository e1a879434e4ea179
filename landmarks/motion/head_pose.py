"""Head pose (yaw, pitch, roll in degrees) from 68 landmarks with cv2.solvePnP.

The canonical 3D face is written by this project (``build_canonical_face``), not
taken from any dataset. How it is made, in model units (~millimetres), with
x to the image right, y down, z away from the camera (OpenCV camera axes, so a
frontal face has its nose at negative z):

1. A mean frontal 2D shape, drawn parametrically around the eye line (y = 0):
   jaw 0-16: lower half-ellipse x = -72 cos t, y = 118 sin t, t = 0..pi in 16 equal steps
   (point 0 at the image-left end of the eye line, 8 the chin at y = 118);
   brows 17-26: five points each from x = +-60 (outer) to +-12 (inner), arched
   y = -16 - 8 sin(pi u), u = 0..1; nose bridge 27-30: x = 0, y = -2, 11, 24, 37 (30 = tip);
   nose base 31-35: x = -16, -8, 0, 8, 16, y = 43, 46, 48, 46, 43; eyes 36-47:
   centres x = +-32, corners at +-15 from the centre, lids at 1/3 and 2/3 of the width,
   y = -5 (upper) and +5 (lower); outer lips 48-59: corners (+-26, 72), upper lip
   y = 66, 63, 64 at x = 17, 7, 0, lower lip y = 80, 83, 84; inner lips 60-67: corners
   (+-22, 72), y = 70 (upper) and 74 (lower) at x = +-8, 0.
2. Depths from a simple head model: every point sits on the front of an ellipsoid
   with semi-axes 80 (x), 130 (y), 90 (z) centred at (0, 20, 0):
   z = -90 sqrt(max(0, 1 - (x/80)^2 - ((y-20)/130)^2)).
3. Local offsets on top of the ellipsoid: nose bridge protrudes -4, -10, -16, -25
   (27..30, tip most), nose base -12 (wings 31/35: -6); eyes are recessed +8; the
   brows protrude -3; the lips protrude -5.
4. Finally the model is centred on the mean of its 68 points.

Camera: pinhole, focal length = image width in pixels, principal point at the
image centre, no distortion.

Sign conventions (image directions, as the viewer sees the picture):
  yaw   > 0: the face turns towards the image right (the subject turns to their left);
  pitch > 0: the face tilts up (nose moves towards the image top);
  roll  > 0: the face rotates clockwise on screen (top of the head moves to the image right,
             the image-right eye drops).
The rotation from model to camera is R = Rz(roll) Rx(-pitch) Ry(-yaw) (yaw applied first).
"""

from __future__ import annotations

import cv2
import numpy as np

from landmarks.shape.ibug68 import NUM_LANDMARKS


def _rx(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def build_canonical_face() -> np.ndarray:
    """The canonical 3D 68-point face described in the module docstring: (68, 3) float64."""
    points = np.zeros((NUM_LANDMARKS, 3))
    t = np.linspace(0.0, np.pi, 17)
    points[0:17, 0], points[0:17, 1] = -72.0 * np.cos(t), 118.0 * np.sin(t)
    u = np.linspace(0.0, 1.0, 5)
    arch = -16.0 - 8.0 * np.sin(np.pi * u)
    points[17:22, 0], points[17:22, 1] = -60.0 + 48.0 * u, arch  # image-left brow, outer -> inner
    points[22:27, 0], points[22:27, 1] = 12.0 + 48.0 * u, arch[::-1]  # image-right brow, inner -> outer
    points[27:31, 0], points[27:31, 1] = 0.0, [-2.0, 11.0, 24.0, 37.0]
    points[31:36, 0], points[31:36, 1] = [-16, -8, 0, 8, 16], [43, 46, 48, 46, 43]
    for first, centre in ((36, -32.0), (42, 32.0)):
        # iBUG eye order: corner, two upper lid points, corner, two lower lid points (clockwise on screen).
        left, right = centre - 15.0, centre + 15.0
        third = (right - left) / 3.0
        points[first : first + 6, 0] = [left, left + third, left + 2 * third, right, left + 2 * third, left + third]
        points[first : first + 6, 1] = [0.0, -5.0, -5.0, 0.0, 5.0, 5.0]
    points[48:60, 0] = [-26, -17, -7, 0, 7, 17, 26, 17, 7, 0, -7, -17]
    points[48:60, 1] = [72, 66, 63, 64, 63, 66, 72, 80, 83, 84, 83, 80]
    points[60:68, 0] = [-22, -8, 0, 8, 22, 8, 0, -8]
    points[60:68, 1] = [72, 70, 70, 70, 72, 74, 74, 74]
    # Depth: front of an ellipsoid head, then local relief (nose out, eyes in, brows and lips out).
    radial = 1.0 - (points[:, 0] / 80.0) ** 2 - ((points[:, 1] - 20.0) / 130.0) ** 2
    points[:, 2] = -90.0 * np.sqrt(np.clip(radial, 0.0, None))
    points[27:31, 2] += [-4.0, -10.0, -16.0, -25.0]
    points[31:36, 2] += [-6.0, -12.0, -12.0, -12.0, -6.0]
    points[36:48, 2] += 8.0
    points[17:27, 2] += -3.0
    points[48:68, 2] += -5.0
    return points - points.mean(axis=0)


CANONICAL_FACE_3D: np.ndarray = build_canonical_face()
"""(68, 3) float64 canonical face in model units (~mm), centred; see the module docstring."""


def rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Model-to-camera rotation for angles in degrees (conventions in the module docstring): (3, 3)."""
    yaw_r, pitch_r, roll_r = np.radians([yaw, pitch, roll])
    return _rz(roll_r) @ _rx(-pitch_r) @ _ry(-yaw_r)


def angles_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """Inverse of ``rotation_matrix``: (3, 3) -> (3,) yaw, pitch, roll in degrees."""
    # R = Rz(c) Rx(b) Ry(a): row 2 is (-cos b sin a, sin b, cos b cos a); R01 = -sin c cos b, R11 = cos c cos b.
    b = np.arcsin(np.clip(rotation[2, 1], -1.0, 1.0))
    a = np.arctan2(-rotation[2, 0], rotation[2, 2])
    c = np.arctan2(-rotation[0, 1], rotation[1, 1])
    return np.degrees(np.array([-a, -b, c]))


def camera_matrix(image_size: tuple[int, int]) -> np.ndarray:
    """Pinhole intrinsics for image_size (H, W): focal = W, principal point at the centre."""
    height, width = image_size
    return np.array([[width, 0.0, width / 2.0], [0.0, width, height / 2.0], [0.0, 0.0, 1.0]])


def project_canonical(
    yaw: float,
    pitch: float,
    roll: float,
    image_size: tuple[int, int],
    scale: float | None = None,
    translation: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Rotate the canonical face and project it: (68, 2) float32 pixel x, y.

    scale: pixels per model unit at the face centre (default: face ~40% of the width);
    translation: pixel offset of the face centre from the image centre.
    """
    height, width = image_size
    scale = 0.4 * width / 150.0 if scale is None else scale
    focal = float(width)
    depth = focal / scale
    centre = np.array([translation[0] * depth / focal, translation[1] * depth / focal, depth])
    camera_points = CANONICAL_FACE_3D @ rotation_matrix(yaw, pitch, roll).T + centre
    projected = camera_points[:, :2] / camera_points[:, 2:3] * focal + np.array([width / 2.0, height / 2.0])
    return projected.astype(np.float32)


def estimate_head_pose(landmarks: np.ndarray, image_size: tuple[int, int], index: tuple[int, ...] | None = None) -> np.ndarray:
    """Yaw, pitch, roll in degrees of one face.

    landmarks: (68, 2) float x, y pixels; image_size: (H, W). Returns (3,) float32;
    all-NaN when the landmarks contain NaN (a missing frame).
    index: fit only these points (e.g. ``landmarks.motion.retarget_points.RIGID_INDEX``: a dropped jaw then does not read as
    the head pitching down); None = all 68.
    """
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must be (68, 2), got {landmarks.shape}")
    if not np.isfinite(landmarks).all():
        return np.full(3, np.nan, np.float32)
    model = CANONICAL_FACE_3D
    if index is not None:
        model, landmarks = model[list(index)], landmarks[list(index)]
    intrinsics = camera_matrix(image_size)
    # EPnP gives a pose without an initial guess; iterative LM refines it (reprojection error).
    ok, rvec, tvec = cv2.solvePnP(model, landmarks, intrinsics, None, flags=cv2.SOLVEPNP_EPNP)
    if ok and tvec[2, 0] > 0:
        ok, rvec, tvec = cv2.solvePnP(model, landmarks, intrinsics, None, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    else:
        ok, rvec, tvec = cv2.solvePnP(model, landmarks, intrinsics, None, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return np.full(3, np.nan, np.float32)
    rotation, _ = cv2.Rodrigues(rvec)
    return angles_from_rotation(rotation).astype(np.float32)
