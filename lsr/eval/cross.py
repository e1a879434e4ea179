"""Cross-identity re-enactment metrics of ``lsr eval`` (thesis §4.4.3, extended to see the re-enactment itself).

Identity i is driven by identity i+1's hold-out landmarks the way ``lsr reenact`` drives it: retargeted
(``landmarks.motion.retarget_mesh.retarget_face`` in the mode of ``--retarget``, the driver's first frame mapped onto the
anchor shot's face; the anchor is ``landmarks.shape.expression.pick_anchor`` of the K shots), and every method's output
composited into the anchor shot (``landmarks.scene.compositing.composite_face``, what ``lsr reenact --paste-back`` delivers).
All metrics are on the composited frame; its landmarks are detected once per frame.

Per frame (``evaluate_method`` -> one record each):
  * ``output_mouth`` / ``output_eye``: ``landmarks.shape.expression`` openings of the detected landmarks (NaN: no face);
    ``driver_mouth`` / ``driver_eye``: those of the *real* driver landmarks (not the targets);
  * ``yaw_error`` / ``pitch_error`` / ``roll_error``: |pose(detected) - pose(target)| in degrees
    (``landmarks.motion.head_pose.estimate_head_pose`` on ``RIGID_INDEX``, so that a dropped jaw does not read as pitch;
    wrapped to [0, 180]);
  * ``nmke``: detected vs target landmarks (``lsr.eval.metrics.nmke``);
  * ``idsim_source``: ID-SIM of the frame to the mean embedding of i's K shots;
  * ``sharpness_face``: Laplacian variance inside the face region (``metrics.face_mask`` of the target
    landmarks) over that inside the anchor's face region on the anchor shot (1 = as sharp as the real face);
  * ``scene_mse`` / ``scene_psnr``: against the anchor shot over the pixels outside
    ``landmarks.scene.compositing.head_region([anchor, target], person=True)``, the region a composite with the scene's matte
    must leave as it was;
  * ``scene_flicker``: mean |frame_t - frame_t-1| (grey levels, RGB mean) over the pixels outside both frames'
    head regions (NaN for the first frame).
Per sequence (method, K, identity, driver; ``summarise_cross``): Pearson correlation of driver and output openings and
the mouth and eye gains (least-squares slope of output on driver opening, with intercept), over the frames with a
face; per (method, K), the mean correlation and the gains pooled over the sequences (``pooled_gain``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from landmarks.parts.eyes.lids import LOOK_AHEAD
from lsr.eval import idsim, metrics

MIN_FRAMES = 3  # fewer paired frames than this: no correlation or gain (NaN)

CONVENTION = (
    "identity i driven by identity i+1's hold-out landmarks (--cross-drivers N: by each of i+1 ... i+N) as "
    "`lsr reenact` drives it: retargeted "
    "(landmarks.motion.retarget_mesh.retarget_face, --retarget: 2d = retarget_driving's relative motion of the 68 "
    "points, 3d = the anchor's own mesh turned by the driver's head rotation, expression in the canonical head "
    "frame; either way the mouth as open as the driver's and the eyes as far closed, against the median of the "
    f"driver's lid gaps (landmarks.parts.eyes.lids.LidReference, as lsr reenact reads a driver's first {LOOK_AHEAD} faces "
    "ahead); "
    "the driver's first frame mapped onto the anchor shot = "
    "pick_anchor of the K shots: most "
    "frontal, closed mouth), every method's output composited into the anchor shot (composite_face); all metrics "
    "on the composited frame, its landmarks detected once. mouth / eye corr = Pearson correlation, per driven "
    "sequence, of the driver's real (not retargeted) mouth / eye opening (inner-lip / eyelid gap over the "
    "inter-ocular distance) with the output's detected one, mean over sequences; mouth / eye gain = least-squares "
    "slope of output on driver opening (1 = the driver's amplitude), one intercept per sequence, pooled over the "
    "sequences (sum of covariances over sum of driver variances: a driver whose opening barely moves adds little; "
    "the mean of per-sequence slopes is in eval_report.json as mouth_gain_per_sequence / eye_gain_per_sequence); "
    f"frames without a face dropped, a sequence left out under {MIN_FRAMES} frames or with zero variance. "
    "yaw / pitch / roll err = |head pose of the "
    "detected landmarks - that of the target landmarks| (solvePnP of the rigid points: upper jaw, nose, eyes, on a "
    "canonical face, so a dropped jaw is not pitch), degrees. NMKE = detected "
    "vs target landmarks over the target's eye distance. ID-SIM to source = to the mean embedding of i's K shots. "
    "sharpness (face) = Laplacian variance inside the target's face region (68-point hull dilated by "
    f"{metrics.FACE_DILATION:g} x inter-ocular distance) over that inside the anchor's face on the anchor shot; "
    "median over frames. scene PSNR = PSNR against the anchor shot over the pixels outside the head regions "
    "(landmarks.scene.compositing.head_region of the anchor and target faces, grown as the person-matte composite grows it: "
    "hair beyond the head ellipse moves with the head), which a composite must leave as they were: "
    "mean over frames with finite PSNR, '(+N inf)' counts bit-identical scenes, 'inf' = all identical. scene "
    "flicker = mean |difference| of consecutive composited frames (grey levels, RGB mean) outside both frames' "
    "head regions, mean per sequence, then over sequences. no face = composited frames without a detected face"
)


# ---- pure per-frame / per-sequence measures ------------------------------------------------------------


def _paired(driver: np.ndarray, output: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The frames where both values are finite, or None when fewer than MIN_FRAMES or either has zero variance."""
    driver, output = np.asarray(driver, np.float64), np.asarray(output, np.float64)
    if driver.shape != output.shape or driver.ndim != 1:
        raise ValueError(f"driver and output openings must be two (T,) arrays, got {driver.shape} and {output.shape}")
    keep = np.isfinite(driver) & np.isfinite(output)
    driver, output = driver[keep], output[keep]
    if len(driver) < MIN_FRAMES or np.ptp(driver) == 0 or np.ptp(output) == 0:
        return None
    return driver, output


def opening_correlation(driver: np.ndarray, output: np.ndarray) -> float:
    """Pearson correlation of driver and output openings over a sequence. driver, output: (T,) float (NaN = no
    face, dropped) -> float in [-1, 1]; NaN with fewer than MIN_FRAMES paired frames or zero variance."""
    pair = _paired(driver, output)
    if pair is None:
        return math.nan
    return float(np.clip(np.corrcoef(*pair)[0, 1], -1.0, 1.0))


def opening_gain(driver: np.ndarray, output: np.ndarray) -> float:
    """Least-squares slope (with intercept) of output on driver opening. (T,), (T,) -> float; 1 = the driver's
    amplitude, < 1 damped, 0 frozen. NaN as for ``opening_correlation``. ``pooled_gain`` of one sequence."""
    return pooled_gain([(driver, output)])


def pooled_gain(sequences: Sequence[tuple[np.ndarray, np.ndarray]]) -> float:
    """The least-squares slope of output on driver opening over several sequences, each with its own intercept:
    sum of the sequences' covariances over the sum of their driver variances. A sequence weighs as much as its
    driver's opening moves, so a driver that barely opens its mouth, whose own slope is mostly the detector's
    noise, adds little (the mean of per-sequence slopes let such drivers set the number). sequences: (driver,
    output) pairs of (T,) openings (NaN = no face, dropped; a pair with fewer than MIN_FRAMES frames or no
    driver variance is left out) -> float; NaN when none is left."""
    covariance = variance = 0.0
    for driver, output in sequences:
        pair = _paired(driver, output)
        if pair is not None:
            centred = pair[0] - pair[0].mean()
            covariance += float(centred @ (pair[1] - pair[1].mean()))
            variance += float(centred @ centred)
    return covariance / variance if variance > 0 else math.nan


def pose_errors(output_pose: np.ndarray, target_pose: np.ndarray) -> np.ndarray:
    """|yaw, pitch, roll difference| in degrees, wrapped to [0, 180]. (3,), (3,) -> (3,) float64 (NaN in, NaN out)."""
    difference = np.asarray(output_pose, np.float64) - np.asarray(target_pose, np.float64)
    return np.abs((difference + 180.0) % 360.0 - 180.0)


def scene_mse(frame: np.ndarray, scene: np.ndarray, outside: np.ndarray) -> float:
    """MSE (grey levels^2) of ``frame`` against ``scene`` over the ``outside`` pixels. frame, scene: (H, W, 3) uint8;
    outside: (H, W) bool -> float (NaN when outside is empty). PSNR: ``metrics.psnr_from_mse``."""
    return float(metrics.mse(frame, scene, mask=outside))


def scene_flicker(previous: np.ndarray, current: np.ndarray, previous_outside: np.ndarray, current_outside: np.ndarray) -> float:
    """Mean absolute difference (grey levels 0-255, mean over RGB) between consecutive frames over the pixels
    outside both frames' head regions. (H, W, 3) uint8 x 2, (H, W) bool x 2 -> float (NaN when none is left)."""
    if previous.shape != current.shape or previous.ndim != 3 or previous.dtype != np.uint8 or current.dtype != np.uint8:
        raise ValueError(f"frames must be two (H, W, 3) uint8 images of one size, got {previous.shape} and {current.shape}")
    both = np.asarray(previous_outside, bool) & np.asarray(current_outside, bool)
    if both.shape != previous.shape[:2]:
        raise ValueError(f"outside regions must be {previous.shape[:2]}, got {both.shape}")
    if not both.any():
        return math.nan
    difference = np.abs(previous.astype(np.int16) - current.astype(np.int16)).mean(axis=-1)  # (H, W)
    return float(difference[both].mean())


def face_sharpness(frame: np.ndarray, frame_landmarks: np.ndarray, scene: np.ndarray, scene_landmarks: np.ndarray) -> float:
    """Laplacian variance inside ``frame``'s face region over that inside ``scene``'s (``metrics.face_mask`` of each
    one's landmarks). (H, W, 3) uint8, (68, 2), (H', W', 3) uint8, (68, 2) -> float (NaN for a flat reference)."""
    output = metrics.masked_laplacian_variance(frame, metrics.face_mask(frame_landmarks, frame.shape[:2]))
    reference = metrics.masked_laplacian_variance(scene, metrics.face_mask(scene_landmarks, scene.shape[:2]))
    return output / reference if reference > 0 else math.nan


def figure_frames(driver_landmarks: np.ndarray, image_size: tuple[int, int],
                  gazes: np.ndarray | None = None) -> list[tuple[str, int]]:
    """The driver frames the cross-identity figure shows: its widest mouth opening ("mouth"), its roundest open
    mouth ("O": inner-lip gap over inner-lip width, among the frames opened more than the median), its smallest
    eye opening ("blink"), its iris furthest from its median position ("glance", when ``gazes`` are given: (T,)
    horizontal iris offsets, NaN unknown) and its largest |yaw| relative to its first frame ("turn").
    driver_landmarks: (T, 68, 2) finite -> up to 5 (label, index), one per distinct frame (labels of a frame
    chosen twice are joined by '+')."""
    from landmarks.shape.expression import eye_opening, mouth_opening
    from landmarks.motion.head_pose import estimate_head_pose

    points = metrics.check_landmarks(driver_landmarks)
    if points.ndim != 3 or not np.isfinite(points).all():
        raise ValueError(f"driver_landmarks must be (T, 68, 2) finite, got {points.shape}")
    if not len(points):
        return []
    yaws = np.array([estimate_head_pose(p, image_size)[0] for p in points], np.float64)
    turn = np.abs((yaws - yaws[0] + 180.0) % 360.0 - 180.0)
    openings = mouth_opening(points)
    width = np.linalg.norm(points[:, 64] - points[:, 60], axis=-1) / np.maximum(metrics.eye_distance(points), 1e-9)
    roundness = np.where(openings >= np.median(openings), openings / np.maximum(width, 1e-9), -np.inf)
    picks = {"mouth": np.nanargmax(openings), "O": int(np.argmax(roundness)), "blink": np.nanargmin(eye_opening(points))}
    if gazes is not None and np.isfinite(gazes).sum() >= 2:
        aside = np.abs(np.asarray(gazes, np.float64) - np.nanmedian(gazes))
        picks["glance"] = int(np.nanargmax(aside))
    picks["turn"] = np.nanargmax(turn) if np.isfinite(turn).any() else 0
    chosen: dict[int, list[str]] = {}
    for label, index in picks.items():
        chosen.setdefault(int(index), []).append(label)
    return [("+".join(labels), index) for index, labels in chosen.items()]


# ---- one driven sequence -----------------------------------------------------------------------------


@dataclasses.dataclass
class CrossSequence:
    """One (K, identity) cross-identity drive, shared by every method. Frames are S x S in the shots' pixels.

    anchor: index into the K shots; anchor_shot: (S, S, 3) uint8; anchor_landmarks: (68, 2);
    driver_frames: (T, S', S', 3) uint8 and driver_landmarks: (T, 68, 2) the driver's real hold-outs;
    targets: (T, 68, 2) the retargeted landmarks every method is given; target_poses: (T, 3) degrees;
    outside: (T, S, S) bool, the scene region per frame; source_embedding: (128,) mean of the K shots';
    target_meshes: (T, 468, 3) the retargeted meshes (NaN rows: none), None without meshes."""

    k: int
    identity: str
    driver: str
    driver_rows: np.ndarray
    anchor: int
    anchor_shot: np.ndarray
    anchor_landmarks: np.ndarray
    driver_frames: np.ndarray
    driver_landmarks: np.ndarray
    targets: np.ndarray
    target_poses: np.ndarray
    outside: np.ndarray
    source_embedding: np.ndarray
    target_meshes: np.ndarray | None = None


def prepare_sequence(k: int, identity: str, driver: str, driver_rows: np.ndarray, shots: Sequence[np.ndarray],
                     shot_landmarks: np.ndarray, driver_frames: np.ndarray, driver_landmarks: np.ndarray,
                     source_embedding: np.ndarray, *, shot_meshes: np.ndarray | None = None,
                     driver_meshes: np.ndarray | None = None, retarget: str = "2d") -> CrossSequence:
    """Pick the anchor, retarget the driver onto it (its first frame as the reference, its lids' reference the
    running median, as ``lsr reenact`` does: ``landmarks.motion.retarget_mesh.retarget_face`` in mode ``retarget``) and
    precompute what every method's frames are
    measured against. shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2) finite; driver_landmarks: (T, 68, 2)
    finite, T >= 1; shot_meshes (K, 468, 3) and driver_meshes (T, 468, 3): face meshes (NaN rows: none), or None.
    target_meshes: the retargeted meshes (T, 468, 3) (NaN rows: none) when both are given."""
    from landmarks.parts.eyes.lids import running_reference_gaps
    from landmarks.shape.expression import pick_anchor
    from landmarks.motion.retarget_mesh import retarget_face
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.retarget_points import RIGID_INDEX
    from landmarks.scene.compositing import head_region

    driver_landmarks = metrics.check_landmarks(driver_landmarks)
    if driver_landmarks.ndim != 3 or not len(driver_landmarks) or not np.isfinite(driver_landmarks).all():
        raise ValueError(f"driver_landmarks must be (T >= 1, 68, 2) finite, got {driver_landmarks.shape}")
    size = shots[0].shape[:2]
    anchor = pick_anchor(shot_landmarks, size)
    anchor_landmarks = np.asarray(shot_landmarks[anchor], np.float64)
    with_meshes = shot_meshes is not None and driver_meshes is not None
    targets, target_meshes = retarget_face(  # (T, 68, 2), (T, 468, 3) or None
        driver_landmarks, driver_landmarks[0], anchor_landmarks, driver_meshes if with_meshes else None,
        driver_meshes[0] if with_meshes else None, shot_meshes[anchor] if with_meshes else None, retarget,
        running_reference_gaps(driver_landmarks), running_reference_gaps(driver_meshes) if with_meshes else None)
    poses = np.stack([estimate_head_pose(t, size, RIGID_INDEX) for t in targets]).astype(np.float64)  # (T, 3)
    # the composite moves the person with the head (its matte): the region it may change reaches further
    outside = np.stack([~head_region([anchor_landmarks, t], size, person=True) for t in targets])  # (T, S, S)
    return CrossSequence(int(k), identity, driver, np.asarray(driver_rows), anchor, shots[anchor], anchor_landmarks,
                         driver_frames, driver_landmarks, targets, poses, outside, source_embedding, target_meshes)


def composite(sequence: CrossSequence, outputs: np.ndarray) -> np.ndarray:
    """Each output frame composited into the anchor shot at its target: (T, S, S, 3) uint8 -> (T, S, S, 3) uint8."""
    from landmarks.scene.compositing import composite_face
    from landmarks.scene.person_matte import scene_layers

    identity_crop = np.eye(2, 3)  # outputs are already in the shots' pixel frame
    layers = scene_layers(sequence.anchor_shot, sequence.anchor_landmarks)
    return np.stack([composite_face(scene=sequence.anchor_shot, scene_landmarks=sequence.anchor_landmarks,
                                    target_landmarks=target, face_crop=output, crop_matrix=identity_crop,
                                    layers=layers).frame
                     for output, target in zip(outputs, sequence.targets)])


def evaluate_method(sequence: CrossSequence, name: str, composited: np.ndarray, analysis: Any) -> list[dict[str, Any]]:
    """One record per composited frame (module docstring). composited: (T, S, S, 3) uint8 from ``composite``;
    analysis: ``lsr.eval.protocol.FaceAnalysis`` (one detection per frame, memoised)."""
    from landmarks.shape.expression import eye_opening, mouth_opening
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.retarget_points import RIGID_INDEX

    size = composited.shape[1:3]
    driver_mouth, driver_eye = mouth_opening(sequence.driver_landmarks), eye_opening(sequence.driver_landmarks)
    records = []
    for row, frame in enumerate(composited):
        target = sequence.targets[row]
        found = analysis.landmarks(frame)
        if found is not None:
            errors = pose_errors(estimate_head_pose(found, size, RIGID_INDEX), sequence.target_poses[row])
            mouth, eye, error = float(mouth_opening(found)), float(eye_opening(found)), float(metrics.nmke(found, target))
        else:
            errors, mouth, eye, error = np.full(3, np.nan), math.nan, math.nan, math.nan
        embedding = analysis.embedding(frame, found if found is not None else target)  # the face is drawn at the target
        mse = scene_mse(frame, sequence.anchor_shot, sequence.outside[row])
        flicker = (scene_flicker(composited[row - 1], frame, sequence.outside[row - 1], sequence.outside[row])
                   if row else math.nan)
        records.append({
            "method": name, "k": sequence.k, "identity": sequence.identity, "driver": sequence.driver,
            "frame": int(sequence.driver_rows[row]), "anchor": sequence.anchor, "no_face": found is None,
            "idsim_source": idsim.cosine_similarity(embedding, sequence.source_embedding),
            "nmke": error, "yaw_error": float(errors[0]), "pitch_error": float(errors[1]), "roll_error": float(errors[2]),
            "driver_mouth": float(driver_mouth[row]), "driver_eye": float(driver_eye[row]),
            "output_mouth": mouth, "output_eye": eye,
            "sharpness_face": face_sharpness(frame, target, sequence.anchor_shot, sequence.anchor_landmarks),
            "scene_mse": mse, "scene_psnr": float(metrics.psnr_from_mse(mse)) if np.isfinite(mse) else math.nan,
            "scene_flicker": flicker,
        })
    return records


# ---- summary -----------------------------------------------------------------------------------------------


def _finite_mean(values: Sequence[float]) -> float:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def summarise_cross(records: Sequence[dict[str, Any]], methods: Sequence[str], ks: Sequence[int]) -> list[dict[str, Any]]:
    """One row per (method, K) with cross records (keys: method, k, frames, sequences, mouth_corr, mouth_gain,
    eye_corr, eye_gain (``pooled_gain``), mouth_gain_per_sequence, eye_gain_per_sequence (the mean of
    ``opening_gain`` over the sequences), yaw_error, pitch_error, roll_error, nmke, idsim_source, sharpness_face,
    scene_psnr,
    scene_psnr_infinite, scene_psnr_of_mean_mse, scene_flicker, no_face); see CONVENTION."""
    rows = []
    for name in methods:
        for k in ks:
            group = [r for r in records if r["method"] == name and r["k"] == k]
            if not group:
                continue
            sequences: dict[tuple[str, str], list[dict[str, Any]]] = {}
            for record in group:
                sequences.setdefault((record["identity"], record["driver"]), []).append(record)
            mouth_corr, mouth_gain, eye_corr, eye_gain, flicker = [], [], [], [], []
            mouths, eyes = [], []
            for members in sequences.values():
                column = {key: np.array([r[key] for r in members], np.float64)
                          for key in ("driver_mouth", "output_mouth", "driver_eye", "output_eye", "scene_flicker")}
                mouths.append((column["driver_mouth"], column["output_mouth"]))
                eyes.append((column["driver_eye"], column["output_eye"]))
                mouth_corr.append(opening_correlation(*mouths[-1]))
                mouth_gain.append(opening_gain(*mouths[-1]))
                eye_corr.append(opening_correlation(*eyes[-1]))
                eye_gain.append(opening_gain(*eyes[-1]))
                flicker.append(_finite_mean(column["scene_flicker"].tolist()))
            scene = metrics.summarise_psnr(np.array([r["scene_psnr"] for r in group]),
                                           np.array([r["scene_mse"] for r in group if np.isfinite(r["scene_mse"])]))
            rows.append({
                "method": name, "k": k, "frames": len(group), "sequences": len(sequences),
                "mouth_corr": _finite_mean(mouth_corr), "mouth_gain": pooled_gain(mouths),
                "eye_corr": _finite_mean(eye_corr), "eye_gain": pooled_gain(eyes),
                "mouth_gain_per_sequence": _finite_mean(mouth_gain), "eye_gain_per_sequence": _finite_mean(eye_gain),
                **{key: _finite_mean([r[key] for r in group]) for key in ("yaw_error", "pitch_error", "roll_error", "nmke")},
                "idsim_source": _finite_mean([r["idsim_source"] for r in group]),
                "sharpness_face": metrics.median_sharpness(np.array([r["sharpness_face"] for r in group])),
                "scene_psnr": scene["mean_finite"], "scene_psnr_infinite": scene["infinite"],
                "scene_psnr_of_mean_mse": scene["of_mean_mse"],
                "scene_flicker": _finite_mean(flicker), "no_face": sum(r["no_face"] for r in group),
            })
    return rows
