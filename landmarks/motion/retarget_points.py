"""Cross-identity landmark retargeting: drive a source face with another person's motion.

LSR's generators see the driving landmarks directly (thesis §4.3), so when the driver is a
different person their face shape (jaw width, eye spacing, nose length) would leak into the
output. ``retarget_relative`` keeps the source's own geometry and transfers only the driver's
*motion* relative to a reference frame of the driver ("relative motion", as in FOMM / LivePortrait).

All similarity fits use ``RIGID_INDEX`` (eyes, nose, upper jaw), points that move little with
expression, so that mouth and brow motion is not mistaken for head motion. Purely 2D: yaw and
pitch, which a 2D similarity cannot express, travel with the expression deltas.
"""

from __future__ import annotations

import numpy as np

from landmarks.shape.ibug68 import NUM_LANDMARKS

# Points barely moved by expressions: upper jaw (0-2, 14-16), nose (27-35), eye corners and lids (36-47).
RIGID_INDEX: tuple[int, ...] = (0, 1, 2, 14, 15, 16, *range(27, 36), *range(36, 48))


def similarity_procrustes(
    source_points: np.ndarray, target_points: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama) taking ``source_points`` onto ``target_points``.

    source_points, target_points: (N, 2) float, N >= 2, finite, same N.
    returns: (scale float, R (2, 2) proper rotation, t (2,)) minimising
        sum ||scale * R @ source_i + t - target_i||^2. Reflections are never returned.
    """
    source = np.asarray(source_points, dtype=np.float64)
    target = np.asarray(target_points, dtype=np.float64)
    if source.ndim != 2 or source.shape[1] != 2 or source.shape != target.shape or len(source) < 2:
        raise ValueError(
            f"points must be two (N, 2) arrays of the same N >= 2, got {source.shape} and {target.shape}"
        )
    if not (np.isfinite(source).all() and np.isfinite(target).all()):
        raise ValueError("points contain NaN/inf: fit similarities on valid frames only")
    source_mean, target_mean = source.mean(0), target.mean(0)
    source_centred, target_centred = source - source_mean, target - target_mean
    source_var = (source_centred**2).sum() / len(source)
    if source_var < 1e-12:
        raise ValueError("source points all coincide: the similarity is undefined")
    covariance = target_centred.T @ source_centred / len(source)  # (2, 2)
    u, singular, vt = np.linalg.svd(covariance)
    sign = np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])  # no reflection
    rotation = u @ sign @ vt
    scale = float(np.trace(np.diag(singular) @ sign) / source_var)
    translation = target_mean - scale * rotation @ source_mean
    return scale, rotation, translation


def apply_similarity(points: np.ndarray, scale: float, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """``scale * R @ p + t`` for points (..., 2) -> (..., 2) float64. NaN points stay NaN."""
    points = np.asarray(points, dtype=np.float64)
    if points.shape[-1] != 2:
        raise ValueError(f"points must have a last axis of 2 (x, y), got shape {points.shape}")
    return points @ (scale * np.asarray(rotation)).T + np.asarray(translation)


def invert_similarity(scale: float, rotation: np.ndarray, translation: np.ndarray):
    """The inverse of ``apply_similarity``'s (scale, R, t): (1 / scale, R^T, -R^T t / scale)."""
    inverse_rotation = rotation.T
    return 1.0 / scale, inverse_rotation, -(inverse_rotation @ translation) / scale


def _check_shape(landmarks: np.ndarray, name: str, *, finite: bool) -> np.ndarray:
    points = np.asarray(landmarks, dtype=np.float64)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"{name} must have shape ({NUM_LANDMARKS}, 2), got {np.shape(landmarks)}")
    if finite and not np.isfinite(points).all():
        raise ValueError(f"{name} contains NaN/inf: pick a frame where a face was found")
    return points


def _check_driver(driver: np.ndarray) -> tuple[np.ndarray, bool]:
    frames = np.asarray(driver, dtype=np.float64)
    single = frames.shape == (NUM_LANDMARKS, 2)
    if single:
        frames = frames[None]
    if frames.ndim != 3 or frames.shape[1:] != (NUM_LANDMARKS, 2):
        raise ValueError(f"driver must have shape (T, {NUM_LANDMARKS}, 2) or ({NUM_LANDMARKS}, 2), got {np.shape(driver)}")
    return frames, single


def _fit_rigid(source: np.ndarray, target: np.ndarray):
    rigid = list(RIGID_INDEX)
    return similarity_procrustes(source[rigid], target[rigid])


def retarget_relative(driver: np.ndarray, driver_reference: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Transfer the driver's motion (relative to its reference frame) onto the source's face.

    driver: (T, 68, 2) float driving landmarks (or one (68, 2) frame); NaN frames stay NaN.
    driver_reference: (68, 2) a driver frame whose pose/expression should map to the source's
        own (typically the driver's first or most neutral frame).
    source: (68, 2) the source subject's landmarks (its shape and placement are kept).
    returns: (T, 68, 2) float64 (or (68, 2) for one frame).

    Algorithm, per frame t (similarities fitted on ``RIGID_INDEX`` by ``similarity_procrustes``):
      1. head motion: H_t = similarity(driver_reference -> driver_t);
      2. expression: delta_t = H_t^-1(driver_t) - driver_reference, the deformation left once
         the rigid head motion is removed, in the driver reference's coordinates;
      3. placement: P = similarity(driver_reference -> source) maps the driver's normalised frame
         to the source's; its scale is the face-size ratio, its rotation the relative roll;
      4. source expression: source + P_linear(delta_t) (deltas scaled and rotated, not translated);
      5. re-apply head motion around the source: output_t = (P o H_t o P^-1)(step 4), i.e. the
         same rotation and relative zoom, with the translation scaled by the face-size ratio.
    When driver_t == driver_reference the output is the source (up to float rounding).
    """
    frames, single = _check_driver(driver)
    reference = _check_shape(driver_reference, "driver_reference", finite=True)
    source_points = _check_shape(source, "source", finite=True)
    place_scale, place_rotation, place_translation = _fit_rigid(reference, source_points)
    unplace = invert_similarity(place_scale, place_rotation, place_translation)
    place_linear = place_scale * place_rotation
    output = np.full_like(frames, np.nan)
    for index, frame in enumerate(frames):
        if not np.isfinite(frame).all():
            continue
        motion = _fit_rigid(reference, frame)  # step 1
        expression_delta = apply_similarity(frame, *invert_similarity(*motion)) - reference  # step 2
        expressive_source = source_points + expression_delta @ place_linear.T  # steps 3-4
        in_driver_frame = apply_similarity(expressive_source, *unplace)  # step 5: P^-1, H_t, P
        moved = apply_similarity(in_driver_frame, *motion)
        output[index] = apply_similarity(moved, place_scale, place_rotation, place_translation)
    return output[0] if single else output


def retarget_absolute(
    driver: np.ndarray, source: np.ndarray, *, driver_reference: np.ndarray | None = None
) -> np.ndarray:
    """The driver's own landmarks, moved onto the source's placement (its shape is NOT adapted).

    driver: (T, 68, 2) float (or one (68, 2) frame); NaN frames stay NaN.
    source: (68, 2) the source's landmarks: only their position, size and roll are used.
    driver_reference: (68, 2) the driver frame aligned onto the source; default the first
        finite driver frame. One similarity (reference -> source, on ``RIGID_INDEX``) is applied
        to every frame, so the driver's motion is kept exactly, only re-placed and re-sized.
    returns: (T, 68, 2) float64 (or (68, 2)). Use it for same-identity driving; use
        ``retarget_relative`` when driver and source are different people.
    """
    frames, single = _check_driver(driver)
    source_points = _check_shape(source, "source", finite=True)
    if driver_reference is None:
        valid = np.isfinite(frames).all(axis=(1, 2))
        if not valid.any():
            raise ValueError("every driver frame is NaN: there is no face to retarget")
        driver_reference = frames[np.argmax(valid)]
    reference = _check_shape(driver_reference, "driver_reference", finite=True)
    output = apply_similarity(frames, *_fit_rigid(reference, source_points))
    return output[0] if single else output


def retarget_driving(driver: np.ndarray, driver_reference: np.ndarray, source: np.ndarray,
                     reference_gaps: np.ndarray | None = None) -> np.ndarray:
    """What ``lsr reenact`` and ``lsr eval`` drive another person with: ``retarget_relative``, then the mouth as
    open as the driver's (``landmarks.shape.expression.mouth_opening``, which is normalised by the eye distance).

    A closed mouth is closed for everyone, so the opening transfers as it is; as a relative delta it would inherit
    whatever the source's anchor and the driver's reference frame showed (an open mouth in either left the output
    never closing or never opening fully). The eyes close as the driver's do, in proportion to the source's own
    (``landmarks.parts.eyes.lids.lids_as_driver``), measured against ``reference_gaps``: (2,) or (T, 2), the driver's
    reference lid gaps (``landmarks.parts.eyes.lids.LidReference``, robust to a blink), None for those of
    ``driver_reference``. Shapes as in ``retarget_relative``.
    """
    from landmarks.parts.eyes.lids import lid_gaps, lids_as_driver
    from landmarks.shape.expression import mouth_opening, set_mouth_opening

    moved = retarget_relative(driver, driver_reference, source)
    frames, single = _check_driver(driver)
    valid = np.isfinite(frames).all(axis=(1, 2))
    output = np.atleast_3d(moved) if not single else moved[None]
    output = output.copy()
    output[valid] = set_mouth_opening(output[valid], mouth_opening(frames[valid]))
    gaps = np.broadcast_to(lid_gaps(driver_reference) if reference_gaps is None else reference_gaps, (len(frames), 2))
    output[valid] = lids_as_driver(output[valid], frames[valid], gaps[valid], source)
    return output[0] if single else output
