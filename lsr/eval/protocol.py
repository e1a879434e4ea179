"""The evaluation protocol of the thesis (§4.4, taken over from FSTH [112]) and its runner.

Per test identity there are input frames (32 in the FSTH sample) and hold-out frames (32). K
shots are drawn uniformly without replacement from the input frames that have landmarks,
seeded by (seed, K, identity), and the method (including any subject fine-tuning) sees only
them. Metrics are computed on the hold-out frames, driven by their ground-truth landmarks.

Data sources (``load_identities``):
  * the LSR release / FSTH layout ``{train,test}/<id>/<video>/combined/NNNNN_rgb.png``:
    ``train`` = inputs, ``test`` = hold-outs; landmarks detected with ``landmarks.detect.face_detector`` and
    cached as ``<cache_dir>/landmarks_<split>_<id>.npz``; with a mesh detector (one with ``meshes``,
    ``landmarks.detect.mediapipe_tracker.MeshDetector``) the 468-point meshes of the same detections too (the 68 points are
    ``mesh_to_68`` of them);
  * an ``lsr.data.format`` dataset (manifest + clips): for each identity of the split, its
    clips' frames in clip-name order, first ``inputs`` frames = inputs, next ``holdouts`` =
    hold-outs (with fewer than inputs + holdouts frames, the first half is used as inputs);
    landmarks from ``landmarks.npy``; the hold-outs' segmentation maps too, when every clip has them; meshes
    (none are stored) from a mesh detector's run on the frames (``attach_meshes``, cached like the landmarks).

A method is anything with ``reenact`` (``Method``); one that ``uses_meshes`` is given them where there are some;
one that ``needs_meshes`` runs only on identities with
meshes (otherwise it is skipped and the skip counted). The runner also evaluates, per method:
  * PSNR / SSIM on the whole frame and inside the ground truth's face region (``lsr.eval.metrics.face_mask``);
  * NMKE / ID-SIM of the output, where output landmarks come from the same detector; hold-outs
    whose ground truth has no face cannot be driven and are skipped (counted); outputs with no
    detected face are counted (``no_face``), their NMKE is missing and their ID-SIM embedding
    is aligned with the ground-truth landmarks instead (the output is meant to be in that pose);
  * mouth / eye correlation: the output's detected openings against the ground truth's, per identity, the
    cross-identity measure where the answer is known (``lsr.eval.report.summarise``);
  * pose-variance buckets (thesis §4.5.1): the raw-landmark NMKE between the nearest source shot
    and the target (= the single shot at K = 1), split into low / medium / high;
  * cross-identity re-enactment (§4.4.3): identity i driven by identity i+1's hold-out landmarks as
    ``lsr reenact`` drives it (retargeted onto the anchor shot, composited into it); expression, pose, NMKE,
    identity, face sharpness and scene metrics of the composited frames (``lsr.eval.cross``).
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from landmarks.parts.coverage import spread
from landmarks.shape.expression import eye_opening, mouth_opening
from landmarks.detect.registry import detect_faces, gives_meshes  # noqa: F401 - protocol.detect_faces
from lsr.errors import ConfigError, DatasetError
from lsr.eval.analysis import FaceAnalysis
from lsr.eval import cross, idsim
from lsr.eval import part_regions as parts
from lsr.eval.baselines import check_method_inputs, nearest_shot_indices
from lsr.eval.metrics import face_mask, mse, nmke, psnr_from_mse, sharpness, ssim

BUCKETS = ("low", "medium", "high")
SHOT_CHOICES = ("random", "spread", "cover")  # run_protocol's shot_choice


@runtime_checkable
class Method(Protocol):
    """A re-enactment method under evaluation. Optionally also has
    ``finetune(shots, shot_landmarks) -> Method``: a subject-specific method fitted on the shots only.
    A method with ``needs_target_segmentation = True`` (thesis Table 4.2's ``oracle_seg`` upper bound)
    is also passed ``target_segmentations=`` (T, S, S) uint8 ground truth of the targets, or None
    when the data has none (the method then raises ConfigError). A method with ``needs_meshes = True`` (the
    ``mesh`` baselines) is also passed ``shot_meshes=`` (K, 468, 3) and ``target_meshes=`` (T, 468, 3) float32
    face meshes (NaN rows: none found); on identities without meshes it is skipped."""

    name: str

    def reenact(self, shots: list[np.ndarray], shot_landmarks: np.ndarray, target_landmarks: np.ndarray) -> np.ndarray:
        """shots: K x (S, S, 3) uint8; shot_landmarks: (K, 68, 2); target_landmarks: (T, 68, 2)
        -> (T, S, S, 3) uint8."""
        ...


@dataclasses.dataclass
class EvalIdentity:
    """One test identity. frames: (N, S, S, 3) uint8; landmarks: (N, 68, 2) float32, NaN rows = no face;
    holdout_segmentations: (N_holdout, S, S) uint8 class ids (lsr.data.classes) or None when unknown;
    input_meshes / holdout_meshes: (N, 468, 3) float32 face meshes of the same frames (NaN rows = none found), or
    None when the detector gives no meshes."""

    name: str
    input_frames: np.ndarray
    input_landmarks: np.ndarray
    holdout_frames: np.ndarray
    holdout_landmarks: np.ndarray
    holdout_segmentations: np.ndarray | None = None
    input_meshes: np.ndarray | None = None
    holdout_meshes: np.ndarray | None = None

    @property
    def has_meshes(self) -> bool:
        return self.input_meshes is not None and self.holdout_meshes is not None


# ---- data -----------------------------------------------------------------------------------------


def takes_meshes(method: Any) -> bool:
    """The method is passed meshes when there are some: it ``needs_meshes`` (skipped without) or ``uses_meshes``
    (a warp-guided model's mesh references; TPS references without)."""
    return bool(getattr(method, "needs_meshes", False) or getattr(method, "uses_meshes", False))


def takes_gazes(method: Any) -> bool:
    """The method is passed ``target_gazes=`` (T, 2, 2), where each target looks (``landmarks.parts.eyes.iris.gaze_offsets``
    of the hold-out or, cross-identity, the driver's relative gaze): it ``uses_gazes`` (warped or drawn eyes)."""
    return bool(getattr(method, "uses_gazes", False))


DRIVER_FRAME_INPUTS = {"uses_driver_mouths": parts.driver_mouth_inputs, "uses_driver_eyes": parts.driver_eye_inputs}
"""What a method is passed cross-identity from the driving frames, by the attribute that asks for it: ``driver_mouths=``,
the open mouths (``landmarks.parts.mouth.interior.DriverMouth``: the driver's mouth interior), and ``driver_eyes=``, the
shut eyes (``landmarks.parts.eyes.driver_lids.DriverEyes``: the driver's shut lids); each cut once per driver."""


def detect_landmarks(frames: Sequence[np.ndarray], detector: Any) -> np.ndarray:
    """Largest face's 68 landmarks per frame. frames: N x (H, W, 3) uint8 -> (N, 68, 2) float32, NaN = no face."""
    return detect_faces(frames, detector)[0]


def _cached_faces(names: np.ndarray, frames: Sequence[np.ndarray], detector: Any,
                  cache: Path | None) -> tuple[np.ndarray, np.ndarray | None]:
    """``detect_faces``, stored in ``cache`` (an .npz keyed by the frames' names and the detector's settings)."""
    with_meshes = gives_meshes(detector)
    settings = f"{detector.settings}/retry"
    if with_meshes:  # the 68 points are mapped from the meshes: a refitted mapping invalidates them
        from landmarks.shape.mesh68 import MAPPING_FILE

        settings += "/mesh68:" + hashlib.blake2b(MAPPING_FILE.read_bytes(), digest_size=8).hexdigest()
    if cache is not None and cache.is_file():
        with np.load(cache, allow_pickle=False) as stored:
            if (str(stored["settings"]) == settings and np.array_equal(stored["files"], names)
                    and (not with_meshes or "meshes" in stored.files)):
                return stored["landmarks"], (stored["meshes"] if with_meshes else None)
    landmarks, meshes = detect_faces(frames, detector)
    if cache is not None:
        from landmarks.io.image_files import atomic_output

        extra = {} if meshes is None else {"meshes": meshes}
        with atomic_output(cache) as temp, open(temp, "wb") as handle:
            np.savez(handle, files=names, settings=np.array(settings), landmarks=landmarks, **extra)
    return landmarks, meshes


def _cached_landmarks(files: list[str], frames: list[np.ndarray], detector: Any,
                      cache: Path | None) -> tuple[np.ndarray, np.ndarray | None]:
    names = np.array([os.path.basename(os.path.dirname(os.path.dirname(f))) + "/" + os.path.basename(f) for f in files])
    return _cached_faces(names, frames, detector, cache)


def load_fsth_sample(root: Path, detector: Any, cache_dir: Path | None = None, progress: bool = True) -> list[EvalIdentity]:
    """Identities of the LSR release / FSTH layout (see the module docstring), sorted by name."""
    from tqdm import tqdm

    from landmarks.io.image_files import read_image

    root = Path(root)
    names = sorted(p.name for p in (root / "train").iterdir() if p.is_dir() and (root / "test" / p.name).is_dir())
    if not names:
        raise DatasetError(f"{root}: no identity has both train/<id> and test/<id>; expected {{train,test}}/<id>/<video>/combined/*_rgb.png")
    identities = []
    for name in tqdm(names, desc="lsr eval: frames + landmarks", disable=not progress):
        parts = {}
        for split in ("train", "test"):
            files = sorted(glob.glob(str(root / split / name / "*" / "combined" / "*_rgb.png")))
            if not files:
                raise DatasetError(f"{root / split / name}: no <video>/combined/*_rgb.png frames")
            frames = [read_image(f) for f in files]
            if len({f.shape for f in frames}) != 1 or frames[0].shape[0] != frames[0].shape[1]:
                raise DatasetError(f"{root / split / name}: frames must all be square and of one size")
            cache = None if cache_dir is None else Path(cache_dir) / f"landmarks_{split}_{name}.npz"
            parts[split] = (np.stack(frames), *_cached_landmarks(files, frames, detector, cache))
        (inputs, input_landmarks, input_meshes), (holdouts, holdout_landmarks, holdout_meshes) = parts["train"], parts["test"]
        identities.append(EvalIdentity(name, inputs, input_landmarks, holdouts, holdout_landmarks,
                                       input_meshes=input_meshes, holdout_meshes=holdout_meshes))
    return identities


def load_lsr_split(root: Path, split: str = "test", inputs: int = 32, holdouts: int = 32) -> list[EvalIdentity]:
    """Identities of an ``lsr.data.format`` dataset split (see the module docstring)."""
    from lsr.data.format import identity_clips, read_clip, read_manifest

    manifest = read_manifest(root)
    if split not in manifest["splits"] or not manifest["splits"][split]:
        raise DatasetError(f"{root}: split {split!r} is missing or empty (splits: {sorted(manifest['splits'])})")
    identities = []
    for name in manifest["splits"][split]:
        frames, landmarks, segmentations = [], [], []
        for clip in identity_clips(root, name):
            data = read_clip(clip, with_segmentation=True)
            frames.append(data["frames"])
            landmarks.append(data["landmarks"])
            segmentations.append(data["segmentation"])
        all_frames, all_landmarks = np.concatenate(frames), np.concatenate(landmarks)
        # ground truth for the oracle_seg upper bound (thesis Table 4.2), only if every clip has it
        all_segmentations = None if any(s is None for s in segmentations) else np.concatenate(segmentations)
        total = len(all_frames)
        if total < 2:
            raise DatasetError(f"{root / name}: {total} frame(s); evaluation needs >= 2 (inputs and hold-outs)")
        num_inputs = inputs if total >= inputs + holdouts else total // 2
        end = min(total, num_inputs + holdouts)
        holdout_segmentations = None if all_segmentations is None else all_segmentations[num_inputs:end]
        identities.append(EvalIdentity(name, all_frames[:num_inputs], all_landmarks[:num_inputs],
                                       all_frames[num_inputs:end], all_landmarks[num_inputs:end], holdout_segmentations))
    return identities


def attach_meshes(identities: Sequence[EvalIdentity], detector: Any, cache_dir: Path | None = None,
                  progress: bool = True) -> None:
    """Give identities without meshes (an lsr dataset stores none) the meshes of a mesh detector's run on their
    frames, cached as ``<cache_dir>/meshes_<id>_<input|holdout>.npz`` (keyed by the frames' content). Their
    landmarks stay the stored ones. A detector without meshes (dlib's) attaches nothing."""
    from tqdm import tqdm

    if not gives_meshes(detector):
        return
    for identity in tqdm([i for i in identities if not i.has_meshes], desc="lsr eval: meshes", disable=not progress):
        found = {}
        for role, frames in (("input", identity.input_frames), ("holdout", identity.holdout_frames)):
            names = np.array([f"{role}/{hashlib.blake2b(frame.tobytes(), digest_size=8).hexdigest()}" for frame in frames])
            cache = None if cache_dir is None else Path(cache_dir) / f"meshes_{identity.name}_{role}.npz"
            found[role] = _cached_faces(names, list(frames), detector, cache)[1]
        identity.input_meshes, identity.holdout_meshes = found["input"], found["holdout"]


def detect_layout(root: Path) -> str:
    """'lsr' (manifest.json) or 'fsth' ({train,test}/ folders); DatasetError otherwise."""
    root = Path(root)
    if (root / "manifest.json").is_file():
        return "lsr"
    if (root / "train").is_dir() and (root / "test").is_dir():
        return "fsth"
    raise DatasetError(f"{root} is neither an lsr dataset (manifest.json) nor an LSR-release folder ({{train,test}}/<id>/...)")


# ---- sampling and buckets -------------------------------------------------------------------------


def _stable_hash(text: str) -> int:
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "little")


def sample_shots(candidates: np.ndarray, k: int, seed: int, identity: str) -> np.ndarray:
    """K distinct input-frame indices drawn uniformly from ``candidates`` (sorted), seeded by
    (seed, K, identity). candidates: (N,) int indices into the *input* frames only."""
    candidates = np.asarray(candidates)
    if k < 1 or k > len(candidates):
        raise ConfigError(f"identity {identity}: K = {k} but only {len(candidates)} input frames with a face; lower --k")
    rng = np.random.default_rng(np.random.SeedSequence([seed, k, _stable_hash(identity)]))
    return np.sort(rng.choice(candidates, size=k, replace=False))


def bucket_thresholds(pose_distances: np.ndarray) -> tuple[float, float]:
    """Tercile thresholds of the finite pose distances (thesis §4.5.1 clusters into three groups)."""
    finite = np.asarray(pose_distances, np.float64)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return (float("nan"), float("nan"))
    low, high = np.quantile(finite, [1 / 3, 2 / 3])
    return float(low), float(high)


def assign_buckets(pose_distances: np.ndarray, thresholds: tuple[float, float]) -> list[str]:
    """'low' (< t0), 'medium' (t0 <= d < t1), 'high' (>= t1), 'unknown' for NaN."""
    low, high = thresholds
    labels = []
    for distance in np.asarray(pose_distances, np.float64):
        if not np.isfinite(distance):
            labels.append("unknown")
        else:
            labels.append("low" if distance < low else "medium" if distance < high else "high")
    return labels


# ---- runner ---------------------------------------------------------------------------------------


@dataclasses.dataclass
class EvalRun:
    """Everything a report needs. records: one dict per (method, K, identity, hold-out frame) with
    keys method, k, identity, frame, mse, psnr, ssim, psnr_face, ssim_face, sharpness, sharpness_face, idsim, nmke,
    no_face, pose_distance, bucket, truth_mouth / truth_eye (the ground truth's landmarks' openings) and output_mouth /
    output_eye (the output's detected ones, NaN: no face). cross_records: one per cross-identity frame, keys of
    ``lsr.eval.cross.evaluate_method`` (method, k, identity, driver, frame, anchor, no_face, idsim_source, nmke,
    yaw/pitch/roll_error, driver_mouth, driver_eye, output_mouth, output_eye, sharpness_face, scene_mse, scene_psnr,
    scene_flicker)."""

    records: list[dict[str, Any]]
    cross_records: list[dict[str, Any]]
    thresholds: dict[int, tuple[float, float]]
    counts: dict[str, Any]
    settings: dict[str, Any]


def _warp_counts(method: Any) -> dict[str, int]:
    return dict(getattr(method, "warp_counts", {}))


def _add_warp_counts(counts: dict[str, Any], name: str, k: int, kind: str, before: dict[str, int], after: dict[str, int]) -> None:
    """counts["warp_methods"][name][f"K={k} {kind}"][warp method] += frames (methods with ``warp_counts`` only)."""
    if not after:
        return
    table = counts.setdefault("warp_methods", {}).setdefault(name, {}).setdefault(f"K={k} {kind}", {})
    for method, value in after.items():
        table[method] = table.get(method, 0) + value - before.get(method, 0)


def _rows_or_none(array: np.ndarray | None, rows: np.ndarray) -> np.ndarray | None:
    return None if array is None else array[rows]


def _check_outputs(outputs: np.ndarray, count: int, size: tuple[int, ...], name: str) -> None:
    if not isinstance(outputs, np.ndarray) or outputs.dtype != np.uint8 or outputs.shape != (count, *size):
        raise ConfigError(f"method {name} returned {getattr(outputs, 'shape', type(outputs))} "
                          f"{getattr(outputs, 'dtype', '')}; expected ({count}, {', '.join(map(str, size))}) uint8")


def run_protocol(
    methods: Sequence[Method],
    identities: Sequence[EvalIdentity],
    ks: Sequence[int],
    analysis: FaceAnalysis,
    *,
    seed: int = 0,
    max_holdouts: int = 0,
    fixed_thresholds: tuple[float, float] | None = None,
    cross_identity: bool = True,
    finetune: bool = True,
    on_outputs: Callable[[str, int, EvalIdentity, np.ndarray, np.ndarray], None] | None = None,
    on_cross_outputs: Callable[[str, cross.CrossSequence, np.ndarray], None] | None = None,
    frame_metrics: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] | None = None,
    progress: bool = True,
    retarget: str = "2d",
    cross_drivers: int = 1,
    shot_choice: str = "random",
    judge: bool = True,
) -> EvalRun:
    """Evaluate ``methods`` on ``identities`` for each K (see the module docstring).

    max_holdouts: use only the first N driveable hold-out frames per identity (0 = all).
    fixed_thresholds: bucket thresholds on the pose distance; None = terciles per K.
    on_outputs(method_name, k, identity, outputs, targets) is called per (method, K, identity)
    (e.g. to save example images); on_cross_outputs(method_name, sequence, composited) per cross-identity
    drive (composited: (T, S, S, 3) uint8, the frames the cross metrics see). frame_metrics:
    {key: metric(outputs, targets) -> (T,)}, each value
    stored per frame in the records under its key (e.g. LPIPS). A method with ``finetune`` is also evaluated fine-tuned,
    as "<name>+ft", when ``finetune`` is true. retarget: how the cross-identity driver is moved onto the anchor
    (``landmarks.motion.retarget_mesh.retarget_face``'s mode; "3d" needs the identities' meshes, "2d" elsewhere).
    cross_drivers: each identity is driven by the next this many identities (i+1, i+2, ...; at most all others).
    shot_choice: "random" (the protocol's: ``sample_shots``), "spread" (evenly over the inputs in time) or "cover" (as
    ``lsr reenact`` chooses them from many:
    ``lsr.core.inputs.choose_shots``: spread, with the person's extreme moments swapped in). judge: also read the
    moving parts with dlib's 68 points, a detector that did not drive them (``lsr.eval.part_regions``; needs dlib).
    """
    from tqdm import tqdm

    if not methods or not identities or not ks:
        raise ConfigError("evaluation needs at least one method, one identity and one K")
    if cross_drivers < 1:
        raise ConfigError(f"cross_drivers must be >= 1, got {cross_drivers}")
    if shot_choice not in SHOT_CHOICES:
        raise ConfigError(f"shot_choice must be one of {', '.join(SHOT_CHOICES)}, got {shot_choice!r}")
    judged_by = parts.Judge() if judge else None
    records: list[dict[str, Any]] = []
    cross_records: list[dict[str, Any]] = []
    counts: dict[str, Any] = {"holdouts_without_face": {}, "inputs_without_face": {}}
    for identity in identities:
        analysis.seed(identity.input_frames, identity.input_landmarks)
        analysis.seed(identity.holdout_frames, identity.holdout_landmarks)
        counts["inputs_without_face"][identity.name] = int(np.sum(~np.isfinite(identity.input_landmarks).all(axis=(1, 2))))
        counts["holdouts_without_face"][identity.name] = int(np.sum(~np.isfinite(identity.holdout_landmarks).all(axis=(1, 2))))
    same_person_inputs = {identity.name: analysis.same_person(identity.input_frames, identity.input_landmarks)
                          for identity in identities}
    for identity in identities:  # same_person counts frames without a face as not the person's: not another's
        found = int(np.isfinite(identity.input_landmarks).all(axis=(1, 2)).sum())
        others = found - int(same_person_inputs[identity.name].sum())
        if others:
            counts.setdefault("inputs_of_another_person", {})[identity.name] = others
    variants: list[tuple[str, Method, bool]] = []
    for method in methods:
        variants.append((method.name, method, False))
        if finetune and callable(getattr(method, "finetune", None)):
            variants.append((f"{method.name}+ft", method, True))
    bar = tqdm(total=len(variants) * len(ks) * len(identities), desc="lsr eval", disable=not progress)
    for k in ks:
        for position, identity in enumerate(identities):
            # input frames with a face, of the person (another person's are left out, as lsr reenact does)
            candidates = np.flatnonzero(same_person_inputs[identity.name])
            if k > len(candidates):  # fewer input frames with a face than K: use them all, and say so
                counts.setdefault("k_capped", {})[f"K={k} {identity.name}"] = int(len(candidates))
            if shot_choice == "cover":  # input frames only, as lsr reenact would choose them
                from lsr.core.inputs import choose_shots

                shot_indices = candidates[choose_shots([identity.input_frames[i] for i in candidates],
                                                       [identity.input_landmarks[i] for i in candidates],
                                                       min(k, len(candidates)))]
            elif shot_choice == "spread":  # evenly over the inputs in time
                shot_indices = candidates[spread(len(candidates), min(k, len(candidates)))]
            else:
                shot_indices = sample_shots(candidates, min(k, len(candidates)), seed, identity.name)
            shots = [identity.input_frames[i] for i in shot_indices]
            shot_landmarks = identity.input_landmarks[shot_indices].astype(np.float64)
            driveable = np.flatnonzero(np.isfinite(identity.holdout_landmarks).all(axis=(1, 2)))
            if max_holdouts:
                driveable = driveable[:max_holdouts]
            targets = identity.holdout_frames[driveable]
            target_landmarks = identity.holdout_landmarks[driveable].astype(np.float64)
            _, pose_distances = nearest_shot_indices(shot_landmarks, target_landmarks)
            target_embeddings = [analysis.embedding(t, p) for t, p in zip(targets, target_landmarks)]
            source_embedding = idsim.mean_embedding(np.stack([analysis.embedding(s, p) for s, p in zip(shots, shot_landmarks)]))
            face_masks = np.stack([face_mask(p, targets.shape[1:3]) for p in target_landmarks]) if len(targets) else None
            beyond = parts.beyond_flags(shots, shot_landmarks, targets, target_landmarks)  # (T,) dicts
            shifts = range(1, min(cross_drivers, len(identities) - 1) + 1) if cross_identity else range(0)
            drivers = [identities[(position + shift) % len(identities)] for shift in shifts]
            target_segmentations = _rows_or_none(identity.holdout_segmentations, driveable)
            sequences = []  # (sequence, the driver's segmentations): retargeted onto the anchor shot once per driver
            for driver in drivers:  # every method gets the same targets
                driver_rows = np.flatnonzero(np.isfinite(driver.holdout_landmarks).all(axis=(1, 2)))[: len(driveable)]
                if len(driver_rows):
                    meshes = identity.has_meshes and driver.has_meshes
                    sequences.append((cross.prepare_sequence(
                        k, identity.name, driver.name, driver_rows, shots, shot_landmarks,
                        driver.holdout_frames[driver_rows], driver.holdout_landmarks[driver_rows], source_embedding,
                        shot_meshes=identity.input_meshes[shot_indices] if meshes else None,  # type: ignore[index]
                        driver_meshes=driver.holdout_meshes[driver_rows] if meshes else None,  # type: ignore[index]
                        retarget=retarget), _rows_or_none(driver.holdout_segmentations, driver_rows)))
            gazing = any(takes_gazes(method) for method in methods)
            # the drivers' gaze by the iris net, once: what warped or drawn eyes follow, and what the judge checks
            driver_gazes = parts.driver_gazes([s for s, _ in sequences]) if gazing or judged_by is not None else None
            judges = [None if judged_by is None else parts.CrossJudge(
                judged_by, sequence.driver_frames, sequence.driver_landmarks, shots, shot_landmarks, driving)
                for (sequence, _), driving in zip(sequences, driver_gazes or [None] * len(sequences))]
            # the driver and shots read once, for every method; what warped or drawn eyes get, self and cross
            gaze_inputs, cross_gazes = parts.gaze_inputs(targets, target_landmarks, [s for s, _ in sequences],
                                                         driver_gazes) if gazing else ({}, [{} for _ in sequences])
            from_drivers = {attribute: cut([s for s, _ in sequences]) for attribute, cut in DRIVER_FRAME_INPUTS.items()
                            if any(getattr(method, attribute, False) for method in methods)}  # mouths, shut eyes
            mesh_inputs: dict[str, np.ndarray] | None = None  # what mesh methods get, self and cross
            cross_meshes: list[dict[str, np.ndarray]] = [{} for _ in sequences]  # per driver, made once
            if any(takes_meshes(method) for method in methods) and identity.has_meshes:
                mesh_inputs = {"shot_meshes": identity.input_meshes[shot_indices],  # type: ignore[index]
                               "target_meshes": identity.holdout_meshes[driveable]}  # type: ignore[index]
                # NaN where the driver has no meshes: the mesh methods fall back per frame
                cross_meshes = [{"shot_meshes": mesh_inputs["shot_meshes"], "target_meshes": (
                    np.full((len(sequence.targets), 468, 3), np.nan, np.float32) if sequence.target_meshes is None
                    else sequence.target_meshes.astype(np.float32))} for sequence, _ in sequences]
            for name, method, use_finetune in variants:
                check_method_inputs(shots, shot_landmarks, target_landmarks)
                if getattr(method, "needs_meshes", False) and mesh_inputs is None:
                    counts.setdefault("skipped_without_meshes", {}).setdefault(name, []).append(f"K={k} {identity.name}")
                    bar.update(1)
                    continue
                model = method.finetune(shots, shot_landmarks) if use_finetune else method  # type: ignore[attr-defined]
                before = _warp_counts(model)
                oracle = getattr(model, "needs_target_segmentation", False)  # baselines never see the ground truth
                extra_inputs = {"target_segmentations": target_segmentations} if oracle else {}
                if takes_meshes(model):
                    extra_inputs.update(mesh_inputs or {})
                if takes_gazes(model):
                    extra_inputs.update(gaze_inputs)
                outputs = model.reenact(shots, shot_landmarks, target_landmarks, **extra_inputs)
                _add_warp_counts(counts, name, k, "self", before, _warp_counts(model))
                _check_outputs(outputs, len(targets), targets.shape[1:], name)
                errors = mse(outputs, targets)
                similarities = ssim(outputs, targets) if len(targets) else np.zeros(0)
                face_errors = mse(outputs, targets, mask=face_masks) if len(targets) else np.zeros(0)
                face_similarities = ssim(outputs, targets, mask=face_masks) if len(targets) else np.zeros(0)
                sharpnesses = sharpness(outputs, targets)  # (T,) Laplacian-variance ratio, NaN for a flat ground truth
                face_sharpnesses = sharpness(outputs, targets, masks=face_masks) if len(targets) else np.zeros(0)
                extra = {key: metric(outputs, targets) for key, metric in (frame_metrics or {}).items()}
                truth_mouth, truth_eye = mouth_opening(target_landmarks), eye_opening(target_landmarks)  # (T,) each
                part_scores = parts.self_part_scores(outputs, targets, target_landmarks)
                for row, output in enumerate(outputs):
                    found = analysis.landmarks(output)
                    align = found if found is not None else target_landmarks[row]
                    records.append({
                        "method": name, "k": int(k), "identity": identity.name, "frame": int(driveable[row]),
                        "mse": float(errors[row]), "psnr": float(psnr_from_mse(errors[row])),
                        "ssim": float(similarities[row]), "psnr_face": float(psnr_from_mse(face_errors[row])),
                        "ssim_face": float(face_similarities[row]), "sharpness": float(sharpnesses[row]),
                        "sharpness_face": float(face_sharpnesses[row]),
                        "idsim": idsim.cosine_similarity(analysis.embedding(output, align), target_embeddings[row]),
                        "nmke": float(nmke(found, target_landmarks[row])) if found is not None else float("nan"),
                        "no_face": found is None, "pose_distance": float(pose_distances[row]),
                        "truth_mouth": float(truth_mouth[row]), "truth_eye": float(truth_eye[row]),
                        "output_mouth": float(mouth_opening(found)) if found is not None else float("nan"),
                        "output_eye": float(eye_opening(found)) if found is not None else float("nan"),
                        **{key: float(values[row]) for key, values in extra.items()},
                        **part_scores[row], **beyond[row],
                    })
                for position, ((sequence, driver_segmentations), meshes_of, gazes_of, sequence_judge) in enumerate(zip(
                        sequences, cross_meshes, cross_gazes, judges)):
                    before = _warp_counts(model)
                    # the oracle sees the driving frames' segmentation, i.e. the driver's own (not retargeted) layout
                    extra_inputs = {"target_segmentations": driver_segmentations} if oracle else {}
                    if takes_meshes(model):
                        extra_inputs.update(meshes_of)
                    extra_inputs.update(gazes_of if takes_gazes(model) else {})
                    for attribute, per_sequence in from_drivers.items():
                        extra_inputs.update(per_sequence[position] if getattr(model, attribute, False) else {})
                    crossed = model.reenact(shots, shot_landmarks, sequence.targets, **extra_inputs)
                    _add_warp_counts(counts, name, k, "cross", before, _warp_counts(model))
                    _check_outputs(crossed, len(sequence.targets), targets.shape[1:], name)
                    composited = cross.composite(sequence, crossed)
                    measured = cross.evaluate_method(sequence, name, composited, analysis)
                    if sequence_judge is not None:
                        readings = sequence_judge.records(composited, [analysis.landmarks(f) for f in composited])
                        measured = [{**record, **extra} for record, extra in zip(measured, readings)]
                    cross_records.extend(measured)
                    if on_cross_outputs is not None:
                        on_cross_outputs(name, sequence, composited)
                if on_outputs is not None:
                    on_outputs(name, int(k), identity, outputs, targets)
                bar.update(1)
    bar.close()
    thresholds: dict[int, tuple[float, float]] = {}
    for k in ks:
        at_k = [r for r in records if r["k"] == k]
        thresholds[int(k)] = fixed_thresholds or bucket_thresholds(np.array([r["pose_distance"] for r in at_k]))
        labels = assign_buckets(np.array([r["pose_distance"] for r in at_k]), thresholds[int(k)])
        for record, label in zip(at_k, labels):
            record["bucket"] = label
    settings = {"ks": [int(k) for k in ks], "seed": seed, "max_holdouts": max_holdouts, "cross_identity": cross_identity,
                "cross_drivers": int(cross_drivers), "shot_choice": shot_choice,
                "identities": [i.name for i in identities], "methods": [v[0] for v in variants],
                "bucket_thresholds": "fixed" if fixed_thresholds else "terciles per K"}
    if judged_by is not None:
        counts["judge_boxed"] = judged_by.boxed
    return EvalRun(records, cross_records, thresholds, counts, settings)
