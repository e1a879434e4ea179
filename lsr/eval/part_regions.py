"""The face's moving parts in ``lsr eval``: scored in their own regions, beyond the shots, and judged by a detector
that did not drive them.

The landmarks that drive a re-enactment (the mesh detector's, by default) also place the output's lids and lips, so
that detector reads a lip stretched to the target's shape as an open mouth, whatever is drawn inside it. Here:

Self re-enactment, per hold-out frame (``self_part_scores``):
  * ``psnr_mouth`` / ``ssim_mouth`` / ``sharpness_mouth``: inside the mouth region, the hull of the ground truth's
    outer lips dilated by ``MOUTH_DILATION`` x its inter-ocular distance; ``*_eyes`` the same inside both eyes'
    regions (each eye's hull dilated by ``EYE_DILATION``, lids and lashes included). PSNR of the MSE over the
    region, SSIM the mean of the whole-frame map over it, sharpness the Laplacian variance inside it over the
    ground truth's (``metrics``' conventions);
  * ``psnr_inside`` / ``psnr_lips``: the mouth region split where the error lies: inside the ground truth's inner
    lips (cavity, teeth, tongue; NaN where its mouth is closed, below ``OPEN_MOUTH``) and on its lips (the
    outer-lip polygon less that);
  * ``beyond_*``: the hold-out lies beyond the K shots (``landmarks.parts.coverage.beyond_shots``: mouth wider, eyes
    more closed, head turned or tilted further, iris further aside than in every shot; the ground truth's
    landmarks and its image's gaze against the shots').

Cross-identity, per composited frame (``CrossJudge``): dlib's 68 points (HOG detector and shape predictor, the
``judge``) on the composited frame and on the driver's frame, so neither side is read by the detector that drove
the motion:
  * ``judge_driver_mouth`` / ``judge_output_mouth`` (and ``_eye``): openings (``landmarks.shape.expression``), whose
    correlation and pooled gain are summarised as ``lsr.eval.cross`` does;
  * ``judge_driver_gaze`` / ``judge_output_gaze``: the iris's horizontal offset in eye widths, found in the
    pixels inside the judge's eye polygons (``landmarks.parts.appearance.gaze``); ``driver_gaze``: the driver's as the
    iris net reads it (``lsr.core.finish.sequence_gazes``, both eyes' mean), the gaze warped and drawn eyes follow;
  * ``iris_contrast``: the output's (``landmarks.parts.appearance.iris_contrast``) over the mean of the source shots'
    (a doubled iris halves it);
  * ``output_cavity`` / ``driver_cavity`` and ``output_teeth`` / ``driver_teeth``: the inside of the mouth
    (``landmarks.parts.appearance.mouth_interior``) where the judge sees the driver's mouth open.
Where dlib's detector finds no face, its shape predictor is given the box of the primary detector's landmarks
(counted as ``judge_boxed``).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from landmarks.parts.appearance import OPEN_MOUTH, gaze, gazes, iris_contrast, mouth_interior, polygon_mask
from landmarks.shape.expression import BLINKING, eye_opening, mouth_opening
from lsr.eval import metrics
from lsr.eval.cross import _finite_mean

MOUTH_DILATION = 0.15  # mouth region: outer-lip hull dilated by this x the inter-ocular distance
EYE_DILATION = 0.12  # eye regions: each eye's hull dilated by this x the inter-ocular distance
REGIONS = ("mouth", "eyes")
SPLIT = ("inside", "lips")
"""The mouth region's parts scored apart (PSNR only: SSIM and sharpness are noisy over a few hundred pixels)."""
BEYOND = ("mouth", "eyes", "yaw", "gaze", "any")


def _dilated_hull(points: np.ndarray, shape: tuple[int, int], radius: float) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(points).astype(np.int32)), 1)
    if radius <= 0:
        return mask.astype(bool)
    return cv2.distanceTransform(1 - mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= radius


def part_masks(landmarks: np.ndarray, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """The mouth and eye regions of one face (module docstring). landmarks: (68, 2); shape: (H, W) ->
    {"mouth": (H, W) bool, "eyes": (H, W) bool} (all False for non-finite landmarks)."""
    points = metrics.check_landmarks(landmarks)
    if points.shape != (68, 2):
        raise ValueError(f"part_masks needs one face's (68, 2) landmarks, got {points.shape}")
    if not np.isfinite(points).all():
        empty = np.zeros(shape, bool)
        return {"mouth": empty, "eyes": empty.copy()}
    distance = float(metrics.eye_distance(points))
    eyes = (_dilated_hull(points[36:42], shape, EYE_DILATION * distance)
            | _dilated_hull(points[42:48], shape, EYE_DILATION * distance))
    return {"mouth": _dilated_hull(points[48:60], shape, MOUTH_DILATION * distance), "eyes": eyes}


def mouth_split(landmarks: np.ndarray, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """The mouth's parts (module docstring): landmarks (68, 2); shape (H, W) -> {"inside": the inner-lip polygon,
    empty where the mouth is closed (below ``OPEN_MOUTH``); "lips": the outer-lip polygon less it} (H, W) bool,
    both empty for non-finite landmarks."""
    points = metrics.check_landmarks(landmarks)
    if points.shape != (68, 2):
        raise ValueError(f"mouth_split needs one face's (68, 2) landmarks, got {points.shape}")
    empty = np.zeros(shape, bool)
    if not np.isfinite(points).all():
        return {"inside": empty, "lips": empty.copy()}
    outer = polygon_mask(points[48:60], shape)
    inside = polygon_mask(points[60:68], shape) & outer if mouth_opening(points) >= OPEN_MOUTH else empty
    return {"inside": inside, "lips": outer & ~inside}


def self_part_scores(outputs: np.ndarray, targets: np.ndarray, target_landmarks: np.ndarray) -> list[dict[str, float]]:
    """PSNR, SSIM and sharpness inside the mouth and eye regions of each target (module docstring).
    outputs, targets: (T, S, S, 3) uint8; target_landmarks: (T, 68, 2) -> T dicts with keys psnr_/ssim_/sharpness_
    + mouth / eyes."""
    if not len(targets):
        return []
    masks = [part_masks(points, targets.shape[1:3]) for points in target_landmarks]
    scores: list[dict[str, float]] = [{} for _ in targets]
    for region in REGIONS:
        mask = np.stack([m[region] for m in masks])  # (T, S, S)
        errors = metrics.mse(outputs, targets, mask=mask)
        similarities = metrics.ssim(outputs, targets, mask=mask)
        sharpnesses = metrics.sharpness(outputs, targets, masks=mask)  # (T,) NaN where the truth is flat there
        for row in range(len(targets)):
            scores[row].update({f"psnr_{region}": float(metrics.psnr_from_mse(errors[row])),
                                f"ssim_{region}": float(similarities[row]),
                                f"sharpness_{region}": float(sharpnesses[row])})
    splits = [mouth_split(points, targets.shape[1:3]) for points in target_landmarks]
    for part in SPLIT:
        errors = metrics.mse(outputs, targets, mask=np.stack([s[part] for s in splits]))  # NaN where empty
        psnrs = np.where(np.isnan(errors), np.nan, metrics.psnr_from_mse(errors))  # psnr_from_mse gives inf for NaN
        for row in range(len(targets)):
            scores[row][f"psnr_{part}"] = float(psnrs[row])
    return scores


def beyond_flags(shots: Sequence[np.ndarray], shot_landmarks: np.ndarray, targets: np.ndarray,
                 target_landmarks: np.ndarray) -> list[dict[str, bool]]:
    """Which targets lie beyond the shots (``landmarks.parts.coverage.beyond_shots``, module docstring). shots: K x (S, S,
    3) uint8 and (K, 68, 2); targets: (T, S, S, 3) and (T, 68, 2) -> T dicts {beyond_mouth, beyond_eyes,
    beyond_yaw, beyond_gaze, beyond_any: bool}."""
    from landmarks.parts.coverage import beyond_shots, face_features

    size = targets.shape[1:3] if len(targets) else shots[0].shape[:2]
    shot_features = face_features(shot_landmarks, size, gazes(shots, shot_landmarks))
    target_features = face_features(target_landmarks, size, gazes(targets, target_landmarks))
    flags = beyond_shots(shot_features, target_features)
    columns = {"mouth": flags.mouth, "eyes": flags.eyes, "yaw": flags.yaw | flags.pitch, "gaze": flags.gaze,
               "any": flags.any}
    return [{f"beyond_{name}": bool(columns[name][row]) for name in BEYOND} for row in range(len(target_features))]


# ---- the judge ----------------------------------------------------------------------------------------------


class Judge:
    """dlib's 68 points (HOG detector, shape predictor), memoised by image content; the boxed fallback of the module
    docstring where its detector finds no face. ``boxed``: how many images needed it."""

    def __init__(self) -> None:
        from landmarks.detect.face_detector import DlibDetector

        self.detector = DlibDetector(kind="hog")
        self._found: dict[bytes, tuple[np.ndarray | None, bool]] = {}
        self.boxed = 0

    def landmarks(self, image: np.ndarray, fallback: np.ndarray | None = None) -> np.ndarray | None:
        """(68, 2) float64 dlib landmarks of the largest face, or those predicted in ``fallback``'s box ((68, 2):
        another detector's landmarks of the same image), or None."""
        from landmarks.detect.face_detector import predict_landmarks

        key = hashlib.blake2b(np.ascontiguousarray(image).tobytes(), digest_size=16).digest()
        if key not in self._found:
            faces = self.detector.detect(image)
            if faces:
                self._found[key] = (np.asarray(faces[0].landmarks, np.float64), False)
            elif fallback is not None and np.isfinite(fallback).all():
                points = np.asarray(fallback, np.float64)
                top = min(points[17:27, 1].min(), points[36:48, 1].min())
                box = np.array([points[:17, 0].min(), top, points[:17, 0].max(), points[:17, 1].max()], np.float32)
                self._found[key] = (predict_landmarks(np.ascontiguousarray(image), box).astype(np.float64), True)
            else:
                self._found[key] = (None, False)
            self.boxed += self._found[key][1]
        return self._found[key][0]


def _openings(points: np.ndarray | None) -> tuple[float, float]:
    if points is None:
        return math.nan, math.nan
    return float(mouth_opening(points)), float(eye_opening(points))


class CrossJudge:
    """The judge's reading of one cross-identity sequence's driver and shots, made once and shared by every
    method. driver_frames: (T, S', S', 3) uint8 with driver_landmarks (T, 68, 2) (the primary detector's: the
    fallback boxes); shots: K x (S, S, 3) with shot_landmarks (K, 68, 2); driver_gazes: the driver's
    ``lsr.core.finish.sequence_gazes`` (T, 2, 2), when already at hand."""

    def __init__(self, judge: Judge, driver_frames: np.ndarray, driver_landmarks: np.ndarray,
                 shots: Sequence[np.ndarray], shot_landmarks: np.ndarray, driver_gazes: np.ndarray | None = None
                 ) -> None:
        from lsr.core.finish import sequence_gazes

        self.judge = judge
        self.driver: list[dict[str, float]] = []
        if driver_gazes is None:
            driver_gazes = sequence_gazes(driver_frames, driver_landmarks)
        driving = driver_gazes[:, :, 0]  # (T, 2): the iris net's, as methods get it
        for frame, fallback, along in zip(driver_frames, driver_landmarks, driving):
            points = judge.landmarks(frame, fallback)
            mouth, eye = _openings(points)
            cavity, teeth = mouth_interior(frame, points) if points is not None else (math.nan, math.nan)
            self.driver.append({"judge_driver_mouth": mouth, "judge_driver_eye": eye,
                                "judge_driver_gaze": float(gaze(frame, points)[0]) if points is not None else math.nan,
                                "driver_gaze": float(np.mean(along[np.isfinite(along)])) if np.isfinite(along).any()
                                else math.nan, "driver_cavity": cavity, "driver_teeth": teeth})
        contrasts = []
        for shot, fallback in zip(shots, shot_landmarks):
            points = judge.landmarks(shot, fallback)
            contrasts.append(iris_contrast(shot, points) if points is not None else math.nan)
        finite = [c for c in contrasts if math.isfinite(c)]
        self.shot_contrast = float(np.mean(finite)) if finite else math.nan

    def records(self, composited: np.ndarray, primary: Sequence[np.ndarray | None]) -> list[dict[str, Any]]:
        """The judge's fields (module docstring) for each composited frame. composited: (T, S, S, 3) uint8;
        primary: T x (68, 2) or None, the primary detector's landmarks of those frames (the fallback boxes)."""
        rows = []
        for frame, fallback, driver in zip(composited, primary, self.driver):
            points = self.judge.landmarks(frame, fallback)
            mouth, eye = _openings(points)
            row = {**driver, "judge_no_face": points is None, "judge_output_mouth": mouth, "judge_output_eye": eye,
                   "judge_output_gaze": math.nan, "iris_contrast": math.nan,
                   "output_cavity": math.nan, "output_teeth": math.nan}
            if points is not None:
                row["judge_output_gaze"] = float(gaze(frame, points)[0])
                contrast = iris_contrast(frame, points)
                if self.shot_contrast > 0:
                    row["iris_contrast"] = contrast / self.shot_contrast
                if driver["judge_driver_mouth"] >= OPEN_MOUTH:  # the driver shows an inside: compare the output's
                    row["output_cavity"], row["output_teeth"] = _interior_at(frame, points)
            rows.append(row)
        return rows


def _interior_at(frame: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """The output's mouth interior where the driver's mouth is open; an output mouth the judge sees closed has
    none: its lips stand where the cavity should be (darkness 1, no teeth)."""
    cavity, teeth = mouth_interior(frame, points)
    return (1.0, 0.0) if math.isnan(cavity) else (cavity, teeth)


# ---- summaries ------------------------------------------------------------------------------------------------


def _region_scores(group: Sequence[dict[str, Any]]) -> dict[str, float]:
    scores: dict[str, float] = {}
    for region in REGIONS:
        scores[f"psnr_{region}"] = _finite_mean([r[f"psnr_{region}"] for r in group])
        scores[f"ssim_{region}"] = _finite_mean([r[f"ssim_{region}"] for r in group])
        scores[f"sharpness_{region}"] = metrics.median_sharpness(np.array([r[f"sharpness_{region}"] for r in group]))
    for part in SPLIT:  # NaN where no hold-out has it (a closed mouth has no inside)
        scores[f"psnr_{part}"] = _finite_mean([r.get(f"psnr_{part}", math.nan) for r in group])
    return scores


def summarise_self(records: Sequence[dict[str, Any]], methods: Sequence[str],
                   ks: Sequence[int]) -> list[dict[str, Any]]:
    """Per (method, K): the region scores over all hold-outs and over those beyond the shots (any feature); the
    mouth region also over the hold-outs whose mouth lies beyond, the eye region over those whose eyes or gaze do.
    -> rows {method, k, frames, beyond_frames, all: {...}, beyond: {...}, mouth_beyond: {...}, eyes_beyond: {...},
    counts: {mouth, eyes, yaw, gaze}}."""
    rows = []
    for name in methods:
        for k in ks:
            group = [r for r in records if r["method"] == name and r["k"] == k and "psnr_mouth" in r]
            if not group:
                continue
            beyond = [r for r in group if r["beyond_any"]]
            mouth = [r for r in group if r["beyond_mouth"]]
            eyes = [r for r in group if r["beyond_eyes"] or r["beyond_gaze"]]
            rows.append({"method": name, "k": k, "frames": len(group), "beyond_frames": len(beyond),
                         "all": _region_scores(group), "beyond": _region_scores(beyond) if beyond else {},
                         "mouth_beyond": _region_scores(mouth) if mouth else {},
                         "eyes_beyond": _region_scores(eyes) if eyes else {},
                         "counts": {part: sum(r[f"beyond_{part}"] for r in group) for part in BEYOND[:-1]}})
    return rows


def _by_sequence(group: Sequence[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Cross records grouped per driven sequence (identity, driver), in order."""
    sequences: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for record in group:
        sequences.setdefault((record["identity"], record["driver"]), []).append(record)
    return sequences


def gaze_pairs(sequences: dict[tuple[str, str], list[dict[str, Any]]], driver: str, output: str
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per sequence, (driver's, output's) gaze over the frames where the judge sees the driver's eyes open (NaN where
    it reads them under ``BLINKING`` of the sequence's median opening: a shut eye shows no iris to follow)."""
    pairs = []
    for members in sequences.values():
        eyes = np.array([r["judge_driver_eye"] for r in members], np.float64)
        opened = eyes >= BLINKING * np.nanmedian(eyes) if np.isfinite(eyes).any() else np.zeros(len(eyes), bool)
        pairs.append(tuple(np.where(opened, np.array([r[key] for r in members], np.float64), np.nan)
                           for key in (driver, output)))
    return pairs


def summarise_cross(records: Sequence[dict[str, Any]], methods: Sequence[str],
                    ks: Sequence[int]) -> list[dict[str, Any]]:
    """Per (method, K) over the cross records with the judge's fields: judge_mouth_corr / judge_eye_corr (mean
    per-sequence correlation), judge_mouth_gain / judge_eye_gain (pooled), gaze_corr (mean per-sequence correlation
    of output and driver gaze where the driver's eyes are open, ``gaze_pairs``), iris_contrast (median),
    output_cavity / driver_cavity and output_teeth / driver_teeth (means over the frames where the driver's mouth is
    open), open_frames, judge_no_face; read_mouth_gain
    / read_eye_gain: the judge's openings of the outputs on the driving detector's of the same outputs, pooled per
    sequence (how alike the two detectors read what was drawn; the agreement row's are the drivers' own frames)."""
    from lsr.eval.cross import opening_correlation, pooled_gain

    rows = []
    for name in methods:
        for k in ks:
            group = [r for r in records if r["method"] == name and r["k"] == k and "judge_no_face" in r]
            if not group:
                continue
            sequences = _by_sequence(group)
            pairs: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"mouth": [], "eye": []}
            for members in sequences.values():
                for part in pairs:
                    pairs[part].append((np.array([r[f"judge_driver_{part}"] for r in members], np.float64),
                                        np.array([r[f"judge_output_{part}"] for r in members], np.float64)))
            opened = [r for r in group if math.isfinite(r["output_cavity"])]
            contrasts = np.array([r["iris_contrast"] for r in group], np.float64)
            rows.append({
                "method": name, "k": k, "frames": len(group), "sequences": len(sequences),
                "judge_mouth_corr": _finite_mean([opening_correlation(*p) for p in pairs["mouth"]]),
                "judge_mouth_gain": pooled_gain(pairs["mouth"]),
                "judge_eye_corr": _finite_mean([opening_correlation(*p) for p in pairs["eye"]]),
                "judge_eye_gain": pooled_gain(pairs["eye"]),
                "gaze_corr": _finite_mean([opening_correlation(*p) for p in gaze_pairs(
                    sequences, "judge_driver_gaze", "judge_output_gaze")]),
                "iris_contrast": float(np.median(contrasts[np.isfinite(contrasts)])) if np.isfinite(contrasts).any()
                else math.nan,
                "open_frames": len(opened),
                **{key: _finite_mean([r[key] for r in opened])
                   for key in ("output_cavity", "driver_cavity", "output_teeth", "driver_teeth")},
                "judge_no_face": sum(r["judge_no_face"] for r in group),
                **{f"read_{part}_gain": pooled_gain([(np.array([r[f"output_{part}"] for r in members], np.float64),
                                                     np.array([r[f"judge_output_{part}"] for r in members], np.float64))
                                                    for members in sequences.values()]) for part in ("mouth", "eye")},
            })
    return rows + agreement_rows(records, methods, ks)


AGREEMENT = "the drivers: driving detector vs judge"
"""The row of ``summarise_cross`` that compares the two detectors on the drivers' own frames."""


def agreement_rows(records: Sequence[dict[str, Any]], methods: Sequence[str], ks: Sequence[int]
                   ) -> list[dict[str, Any]]:
    """Per K, how far the judge and the detector that drove the motion agree on the drivers' own frames: the
    per-sequence correlation (mean) and pooled gain of the judge's mouth and eye openings on the driving detector's,
    and the correlation of the judge's gaze with the iris net's (where the driver's eyes are open, ``gaze_pairs``).
    A method drives its output to the driving detector's reading, so its judged correlation can reach this only
    where the two detectors agree (the rows' ceiling). Read from the first method's records (the drivers are the
    same for every method). ``by_driver``: each driver's own pooled mouth and eye gains and how far the driving
    detector reads them move ({driver: {"mouth_gain", "eye_gain", "mouth_range", "eye_range"}}, openings in eye
    distances), since the pooled row hides a driver the two detectors read apart when another moves more; a driver
    that barely moves has a gain of noise."""
    from lsr.eval.cross import opening_correlation, pooled_gain

    rows = []
    for k in ks:
        group: list[dict[str, Any]] = []
        for name in methods:
            group = group or [r for r in records if r["method"] == name and r["k"] == k and "judge_no_face" in r]
        if not group:
            continue
        sequences = _by_sequence(group)
        pairs = {part: [(np.array([r[f"driver_{part}"] for r in members], np.float64),
                         np.array([r[f"judge_driver_{part}"] for r in members], np.float64))
                        for members in sequences.values()] for part in ("mouth", "eye")}
        pairs["gaze"] = gaze_pairs(sequences, "driver_gaze", "judge_driver_gaze")
        drivers = sorted({driver for _, driver in sequences})
        by_driver = {}
        for driver in drivers:
            own = {part: [pair for (_, each), pair in zip(sequences, pairs[part]) if each == driver]
                   for part in ("mouth", "eye")}
            by_driver[driver] = {f"{part}_gain": pooled_gain(own[part]) for part in own}
            for part in own:
                read = np.concatenate([driving for driving, _ in own[part]])
                read = read[np.isfinite(read)]
                by_driver[driver][f"{part}_range"] = float(np.ptp(read)) if len(read) else math.nan
        rows.append({"method": AGREEMENT, "k": k, "frames": len(group), "sequences": len(sequences),
                     "judge_mouth_corr": _finite_mean([opening_correlation(*p) for p in pairs["mouth"]]),
                     "judge_mouth_gain": pooled_gain(pairs["mouth"]),
                     "judge_eye_corr": _finite_mean([opening_correlation(*p) for p in pairs["eye"]]),
                     "judge_eye_gain": pooled_gain(pairs["eye"]),
                     "gaze_corr": _finite_mean([opening_correlation(*p) for p in pairs["gaze"]]),
                     **dict.fromkeys(("iris_contrast", "output_cavity", "driver_cavity", "output_teeth",
                                      "driver_teeth"), math.nan),
                     "read_mouth_gain": pooled_gain(pairs["mouth"]), "read_eye_gain": pooled_gain(pairs["eye"]),
                     "open_frames": 0, "judge_no_face": sum(r["judge_no_face"] for r in group),
                     "by_driver": by_driver})
    return rows


CONVENTION = (
    f"mouth region = the ground truth's outer-lip hull dilated by {MOUTH_DILATION:g} x its inter-ocular distance, "
    f"eye regions = each eye's hull dilated by {EYE_DILATION:g} x it (both eyes); PSNR / SSIM / sharpness as for the "
    "face region. Beyond the shots (landmarks.parts.coverage.beyond_shots): the hold-out's mouth opens wider, its eyes "
    "close further, its head turns or tilts further or its iris looks further aside (landmarks.parts.appearance.gaze) "
    "than in every one of the K shots, by more than the margins of landmarks.parts.coverage.MARGINS; 'beyond' rows = "
    "any of these, the mouth column there over the frames whose mouth is beyond, the eye columns over those whose "
    "eyes or gaze are. Judged: dlib's 68 points (HOG detector and shape predictor; where it finds no face, its "
    "shape predictor in the box of the primary detector's points, counted) on the composited frame and on the "
    "driver's frame, so that neither is read by the detector that drove the motion; mouth / eye corr and gain as "
    "in the cross-identity table; gaze corr = per-sequence correlation of the output's and the driver's iris "
    "offset (landmarks.parts.appearance.gaze, the dark-weighted centroid inside the judge's eye polygon, in eye widths) "
    f"over the frames where the judge sees the driver's eyes open (at >= {BLINKING:g} of the sequence's median "
    "opening: a shut eye has no iris to follow); "
    "iris contrast = the output eyes' (bright - dark) / bright over the source shots' (median over frames; a "
    f"doubled iris halves it); cavity = median grey inside the inner lips over the face's, teeth = share of "
    f"teeth-like pixels there, on the frames where the judge sees the driver's mouth open (>= {OPEN_MOUTH:g} "
    "inter-ocular distances; an output mouth it sees closed counts as cavity 1, teeth 0). "
    f"'{AGREEMENT}': the judge's openings of the drivers' own frames against the driving detector's, correlated "
    "and pooled as above, and its iris offset against the iris net's gaze (what warped and drawn eyes are given, "
    "landmarks.parts.eyes.iris.gaze_offsets, both eyes' mean; on the same open-eyed frames): a method's output follows the "
    "driving detector's reading, so "
    "its judged correlation reaches this only where the two detectors agree. 'read alike': the judge's openings "
    "of the outputs on the driving detector's of the same outputs, pooled per sequence as the gain (the agreement "
    "row: of the drivers' own frames); below the drivers' figure, the two detectors read the drawn mouth or eyes "
    "apart where they read real ones alike, so what is lost lies in the drawing, not in following the driver"
)


def markdown(self_rows: Sequence[dict[str, Any]], cross_rows: Sequence[dict[str, Any]], fmt: Any) -> list[str]:
    """The two tables of the moving parts (lines of markdown); fmt: the report's number formatter."""
    lines: list[str] = []
    if self_rows:
        lines += ["", "## Moving parts, self re-enactment: all hold-outs and those beyond the shots", "",
                  "| method | K | frames | mouth PSNR ↑ | mouth SSIM ↑ | mouth sharpness →1 | inside the lips PSNR ↑ "
                  "| lips PSNR ↑ | eyes PSNR ↑ | eyes SSIM ↑ | eyes sharpness →1 |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in self_rows:
            counts = row["counts"]
            for label, mouth, eyes, frames in (
                    ("all", row["all"], row["all"], str(row["frames"])),
                    ("beyond", row["mouth_beyond"], row["eyes_beyond"],
                     f"{row['beyond_frames']} (mouth {counts['mouth']}, eyes {counts['eyes']}, pose {counts['yaw']}, "
                     f"gaze {counts['gaze']})")):
                cells = [fmt(mouth.get("psnr_mouth"), 2), fmt(mouth.get("ssim_mouth")),
                         fmt(mouth.get("sharpness_mouth"), 2), fmt(mouth.get("psnr_inside"), 2),
                         fmt(mouth.get("psnr_lips"), 2), fmt(eyes.get("psnr_eyes"), 2),
                         fmt(eyes.get("ssim_eyes")), fmt(eyes.get("sharpness_eyes"), 2)]
                lines.append(f"| {row['method']} | {row['k']} | {label}: {frames} | " + " | ".join(cells) + " |")
        lines += ["", "The mouth region split where its error lies: *inside the lips* is the ground truth's inner-lip "
                  f"polygon where its mouth is open (>= {OPEN_MOUTH:g} eye distances: cavity, teeth, tongue), *lips* "
                  "its outer-lip polygon less that."]
    if cross_rows:
        lines += ["", "## Moving parts, cross-identity: judged by dlib's 68 points (not the driving detector)", "",
                  "| method | K | frames | mouth corr ↑ | mouth gain →1 | eye corr ↑ | eye gain →1 | "
                  "gaze corr ↑ | iris contrast →1 | cavity out (driver) | teeth out (driver) | read alike: mouth, "
                  "eyes →1 | open frames | judge no face |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in cross_rows:
            if row["method"] == AGREEMENT:
                lines.append(f"| {AGREEMENT} | {row['k']} | {row['frames']} | {fmt(row['judge_mouth_corr'], 2)} | "
                             f"{fmt(row['judge_mouth_gain'], 2)} | {fmt(row['judge_eye_corr'], 2)} | "
                             f"{fmt(row['judge_eye_gain'], 2)} | {fmt(row['gaze_corr'], 2)} | – | – | – | "
                             f"{fmt(row['read_mouth_gain'], 2)}, {fmt(row['read_eye_gain'], 2)} | – | "
                             f"{row['judge_no_face']} |")
                continue
            lines.append(
                f"| {row['method']} | {row['k']} | {row['frames']} | {fmt(row['judge_mouth_corr'], 2)} | "
                f"{fmt(row['judge_mouth_gain'], 2)} | {fmt(row['judge_eye_corr'], 2)} | "
                f"{fmt(row['judge_eye_gain'], 2)} | "
                f"{fmt(row['gaze_corr'], 2)} | {fmt(row['iris_contrast'], 2)} | "
                f"{fmt(row['output_cavity'], 2)} ({fmt(row['driver_cavity'], 2)}) | "
                f"{fmt(row['output_teeth'], 2)} ({fmt(row['driver_teeth'], 2)}) | "
                f"{fmt(row['read_mouth_gain'], 2)}, {fmt(row['read_eye_gain'], 2)} | {row['open_frames']} | "
                f"{row['judge_no_face']} |")
        said: dict[str, list[int]] = {}  # the drivers' frames are the same at every K: one line per reading
        for row in cross_rows:
            if row["method"] == AGREEMENT and len(row.get("by_driver", {})) > 1:
                each = ", ".join(f"{driver} {fmt(gains['mouth_gain'], 2)} / {fmt(gains['eye_gain'], 2)} (moving "
                                 f"{fmt(gains['mouth_range'], 2)} / {fmt(gains['eye_range'], 2)})"
                                 for driver, gains in row["by_driver"].items())
                said.setdefault(each, []).append(row["k"])
        for each, ks in said.items():
            lines += ["", f"The drivers one by one, K = {', '.join(map(str, ks))} (the judge's pooled mouth / eye gain "
                      "on the driving detector's, per driver, and how far the driving detector reads that driver's "
                      f"mouth and eyes move, in eye distances: a driver that barely moves has a gain of noise): {each}."]
    return lines


def driver_mouth_inputs(sequences: Sequence[Any]) -> list[dict[str, list]]:
    """What a method that takes the driver's mouth interior is given cross-identity
    (``protocol.DRIVER_FRAME_INPUTS``): one ``{"driver_mouths": T x DriverMouth or None}`` per ``cross.CrossSequence``, cut from the driving frames at
    the driver's own points (``landmarks.parts.mouth.interior.cut_driver_mouth``, as ``lsr reenact`` cuts them)."""
    from landmarks.parts.mouth.interior import cut_driver_mouth

    return [{"driver_mouths": [cut_driver_mouth(frame, points) for frame, points in
                               zip(sequence.driver_frames, sequence.driver_landmarks)]} for sequence in sequences]


def driver_eye_inputs(sequences: Sequence[Any]) -> list[dict[str, list]]:
    """What a method that takes the driver's shut eyes is given cross-identity (``protocol.DRIVER_FRAME_INPUTS``): one
    ``{"driver_eyes": T x DriverEyes or None}`` per ``cross.CrossSequence``, cut from the driving frames at the
    driver's own points against its lids at rest as ``lsr reenact`` keeps them (``landmarks.parts.eyes.driver_lids``,
    ``landmarks.parts.eyes.lids.running_reference_gaps``)."""
    from landmarks.parts.eyes.driver_lids import cut_driver_eyes
    from landmarks.parts.eyes.lids import running_reference_gaps

    return [{"driver_eyes": [cut_driver_eyes(frame, points, gaps) for frame, points, gaps in
                             zip(sequence.driver_frames, sequence.driver_landmarks,
                                 running_reference_gaps(sequence.driver_landmarks))]} for sequence in sequences]


def driver_gazes(sequences: Sequence[Any]) -> list[np.ndarray]:
    """Each ``cross.CrossSequence``'s driver's gaze by the iris net (``lsr.core.finish.sequence_gazes``, (T, 2, 2)):
    made once, for what warped or drawn eyes follow (``gaze_inputs``) and what the judge checks (``CrossJudge``)."""
    from lsr.core.finish import sequence_gazes

    return [sequence_gazes(sequence.driver_frames, sequence.driver_landmarks) for sequence in sequences]


def gaze_inputs(targets: np.ndarray, target_landmarks: np.ndarray, sequences: Sequence[Any],
                driver_gazes: Sequence[np.ndarray] | None = None
                ) -> tuple[dict[str, np.ndarray], list[dict[str, np.ndarray]]]:
    """What a method with warped or drawn eyes is given (``protocol.takes_gazes``): self re-enactment, the hold-outs'
    own gaze ``{"target_gazes": (T, 2, 2)}``; cross-identity, one such dict per ``cross.CrossSequence``: the
    driver's gaze as ``lsr reenact`` gives it to the source (``lsr.core.finish.DriverGaze``), the anchor shot's moved
    by the driver's since its first frame whose irises were found. driver_gazes: each sequence's driver's
    ``sequence_gazes``, when already at hand."""
    from landmarks.parts.eyes.iris import retarget_gaze
    from lsr.core.finish import sequence_gazes

    crossed = []
    for position, sequence in enumerate(sequences):
        driver = sequence_gazes(sequence.driver_frames, sequence.driver_landmarks) if driver_gazes is None else \
            driver_gazes[position]
        anchor = sequence_gazes(sequence.anchor_shot[None], sequence.anchor_landmarks[None])[0]
        found = np.flatnonzero(np.isfinite(driver).all(axis=(1, 2)))
        crossed.append({"target_gazes": driver if not len(found) else retarget_gaze(driver, driver[found[0]], anchor)})
    return {"target_gazes": sequence_gazes(targets, target_landmarks)}, crossed
