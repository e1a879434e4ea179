"""Edit a face's 68 landmarks by expression and head pose: the sliders of ``lsr app``'s expression tab.

``edit_landmarks(points, yaw=, pitch=, roll=, mouth=, eyes=, smile=, brows=)`` moves the points of one face the way
those motions move a face, in the face's own frame (its eye line and size), so one setting does the same thing to
any face in any picture:

* mouth: added opening of the inner lips in inter-ocular distances (IOD; a talking mouth spans about 0-0.3, a yawn
  0.5), the jaw dropping with it (``landmarks.shape.expression.set_mouth_opening``);
* eyes: a factor on the lid gap (0 closed, 1 as it is, 1.5 wide open), the lids moving about the eye's centre line;
* smile: the mouth corners move out and up by this many IOD (negative: down), the lips beside them half as much;
* brows: the brows move up by this many IOD (negative: down, a frown), the inner ends a little more;
* yaw / pitch / roll in degrees (``landmarks.motion.head_pose`` conventions): roll turns the face about its centre on screen;
  yaw and pitch move each point as ``landmarks.motion.head_pose``'s canonical 3D face moves when turned, scaled to this face.

Expression first, then pose. Works on (68, 2) float pixels, returns a new float64 array.
"""

from __future__ import annotations

import numpy as np

from landmarks.align import face_geometry
from landmarks.shape.ibug68 import NUM_LANDMARKS

BROWS = slice(17, 27)
INNER_BROWS = (21, 22)
MOUTH_CORNERS = (48, 54)
BESIDE_CORNERS = {48: (49, 59, 60), 54: (53, 55, 64)}
EYE_LIDS = ((37, 41), (38, 40), (43, 47), (44, 46))  # (upper, lower) lid points, both eyes
CANONICAL_IOD = 64.0  # eye centres of landmarks.motion.head_pose's canonical face, model units


def _face_frame(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre, inter-ocular distance, unit x axis along the eye line (image-left eye to image-right eye))."""
    left, right, _ = face_geometry(points)
    axis = right - left
    iod = float(np.linalg.norm(axis))
    if not np.isfinite(iod) or iod <= 0:
        raise ValueError("cannot edit a face whose eye centres coincide or are not finite")
    centre = (left + right) / 2 * 0.5 + points[48:68].mean(0) * 0.5  # between the eyes and the mouth
    return centre, iod, axis / iod


def _turn(points: np.ndarray, yaw: float, pitch: float, centre: np.ndarray, iod: float, x_axis: np.ndarray) -> np.ndarray:
    from landmarks.motion.head_pose import CANONICAL_FACE_3D, rotation_matrix

    turned = CANONICAL_FACE_3D @ rotation_matrix(yaw, pitch, 0.0).T
    delta = (turned[:, :2] - CANONICAL_FACE_3D[:, :2]) * (iod / CANONICAL_IOD)  # (68, 2) in the face's x, y frame
    y_axis = np.array([-x_axis[1], x_axis[0]])  # image down, for an upright face
    return points + delta[:, :1] * x_axis + delta[:, 1:] * y_axis


def edit_landmarks(landmarks: np.ndarray, *, yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0,
                   mouth: float = 0.0, eyes: float = 1.0, smile: float = 0.0, brows: float = 0.0) -> np.ndarray:
    """One face's landmarks (68, 2) edited as the module docstring says -> (68, 2) float64."""
    from landmarks.shape.expression import mouth_opening, set_mouth_opening

    points = np.array(landmarks, np.float64)
    if points.shape != (NUM_LANDMARKS, 2) or not np.isfinite(points).all():
        raise ValueError(f"landmarks must be finite (68, 2), got {np.shape(landmarks)}")
    if eyes < 0:
        raise ValueError(f"eyes is a factor on the lid gap and must be >= 0, got {eyes}")
    centre, iod, x_axis = _face_frame(points)
    up = -np.array([-x_axis[1], x_axis[0]])  # towards the top of the head
    if mouth:
        points = set_mouth_opening(points, max(0.0, float(mouth_opening(points)) + mouth))
    if eyes != 1.0:
        for upper, lower in EYE_LIDS:
            middle = (points[upper] + points[lower]) / 2
            points[upper] = middle + (points[upper] - middle) * eyes
            points[lower] = middle + (points[lower] - middle) * eyes
    if smile:
        mouth_centre = points[48:68].mean(0)
        for corner in MOUTH_CORNERS:
            outward = np.sign(np.dot(points[corner] - mouth_centre, x_axis)) * x_axis
            move = smile * iod * (outward * 0.6 + up * 0.8)
            points[corner] += move
            points[list(BESIDE_CORNERS[corner])] += move * 0.5
    if brows:
        points[BROWS] += brows * iod * up
        points[list(INNER_BROWS)] += 0.3 * brows * iod * up
    if yaw or pitch:
        points = _turn(points, yaw, pitch, centre, iod, x_axis)
    if roll:
        angle = np.radians(roll)  # clockwise on screen (image y points down)
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        points = (points - centre) @ rotation.T + centre
    return points
