"""PyTorch datasets of K-shot episodes over the on-disk format (``lsr.data.format``).

An *episode* (thesis §4.3, the few-shot setting taken over from FSTH) is K source frames of one
identity plus one target frame of the same identity; the model sees the shots and the target's
landmarks and must produce the target. ``EpisodeDataset`` serves training episodes;
``CrossIdentityDataset`` serves evaluation pairs whose driver comes from another identity (no ground
truth exists for those).

Conventions (shape contracts of every item):

* ``shots`` (K, 3, S, S), ``target`` (3, S, S): float32 RGB in [-1, 1].
* ``shot_landmark_images`` (K, 3, S, S), ``target_landmark_image`` (3, S, S): float32 in [-1, 1]
  (black background = -1): ``landmarks.shape.raster.draw_landmarks`` at S, drawn on the fly after
  augmentation, normalised like the frames so the networks see one input range.
* ``target_segmentation`` (S, S) int64 class ids of ``SEG_CLASSES``; ``SEGMENTATION_IGNORE_INDEX``
  (-1) everywhere when the clip has no maps (use ``cross_entropy(..., ignore_index=-1)``).
* ``shot_landmarks`` (K, 68, 2), ``target_landmarks`` (68, 2): float32 x, y pixels at S.
* ``identity``: int64 index into ``dataset.identities``; ``index``: the episode index.
* with ``warp_references = N > 0`` (the warp-guided generator): ``references`` (N, 3, S, S) in [-1, 1], the
  N shots nearest to the target TPS-warped onto its landmarks (``landmarks.warp.tps.warp_references``, after
  augmentation), and ``reference_masks`` (N, 1, S, S) in {0, 1}, where each warp sampled inside its shot.

Sampling: frames with NaN landmarks are never chosen. ``shots_from="identity"`` (default) draws the
shots from any video of the target's identity (appearance across videos, as at test time);
``"video"`` draws them from the target's video only; ``"video_apart"`` from the half of the target's clip that
does not hold the target (the evaluation protocol's inputs and hold-outs are separate stretches of one video, so
its shots are never the target's neighbours in time). The target is never one of its own shots;
when fewer than K other frames exist the shots are drawn with replacement.

Expression episodes (``expression_episodes = p > 0``): a fraction p of episodes takes a target whose mouth is open
wider than most of its pool's (the top ``OPEN_MOUTH_QUANTILE``) and shots whose mouths are closed (the pool's lower
half by mouth opening, ``landmarks.shape.expression.mouth_opening``). No shot then shows the target's mouth: the network
must draw the mouth's interior itself, which is what another person's driving asks of it (a yawn, an "O").

Determinism: episode ``i`` of a dataset with seed ``s`` (and epoch ``e``, see ``set_epoch``) is drawn
from ``numpy.random.default_rng([s, e, i])`` and a torch generator seeded from it, so it does not
depend on DataLoader workers or on the order items are requested.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from lsr.data.augment import AugmentConfig, augment_frames
from lsr.data.format import ClipReader, list_clips
from lsr.core import MAX_K
from lsr.errors import ConfigError, DatasetError

SEGMENTATION_IGNORE_INDEX = -1
SHOTS_FROM = ("identity", "video", "video_apart")
OPEN_MOUTH_QUANTILE = 0.75
"""Expression episodes' targets: frames whose mouth opening is above this quantile of their pool's."""


@dataclasses.dataclass(frozen=True)
class FrameRef:
    clip: int  # index into the dataset's clip readers
    frame: int


class _FrameIndex:
    """Clips of a split grouped by identity, with the frames that have landmarks."""

    def __init__(self, root: str | os.PathLike[str], split: str | None, size: int | None) -> None:
        self.root = Path(root)
        self.clips = [ClipReader(path) for path in list_clips(self.root, split)]
        if not self.clips:
            raise DatasetError(f"split {split!r} of {self.root} has no clips; prepare or generate data first")
        sizes = {clip.size for clip in self.clips}
        if size is None and len(sizes) > 1:
            raise DatasetError(f"clips of {self.root} have several sizes {sorted(sizes)}; pass size= to resize them alike")
        self.size = int(size if size is not None else sizes.pop())
        if self.size < 16:
            raise ConfigError(f"size must be >= 16, got {self.size}")
        self.frames_by_identity: dict[str, list[FrameRef]] = {}
        self.frames_by_video: dict[tuple[str, str], list[FrameRef]] = {}
        for clip_index, clip in enumerate(self.clips):
            valid = np.flatnonzero(np.isfinite(clip.landmarks).all(axis=(1, 2)))  # NaN rows never chosen
            refs = [FrameRef(clip_index, int(f)) for f in valid]
            self.frames_by_identity.setdefault(clip.identity, []).extend(refs)
            self.frames_by_video.setdefault((clip.identity, clip.video), []).extend(refs)
        self.identities = sorted(name for name, refs in self.frames_by_identity.items() if refs)

    def load(self, ref: FrameRef, with_segmentation: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(S, S, 3) uint8 frame, (68, 2) float32 landmarks and (S, S) int64 class map (or None) at ``self.size``."""
        clip = self.clips[ref.clip]
        frame = clip.frame(ref.frame)
        landmarks = clip.landmarks[ref.frame].astype(np.float32)
        segmentation = None
        if with_segmentation:
            if clip.has_segmentation:
                segmentation = clip.segmentation(ref.frame).astype(np.int64)
            else:
                segmentation = np.full((clip.size, clip.size), SEGMENTATION_IGNORE_INDEX, np.int64)
        if clip.size != self.size:
            scale = self.size / clip.size
            interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
            frame = cv2.resize(frame, (self.size, self.size), interpolation=interpolation)
            landmarks = (landmarks + 0.5) * scale - 0.5  # pixel centres at integers
            if segmentation is not None:
                segmentation = cv2.resize(segmentation.astype(np.int16), (self.size, self.size),
                                          interpolation=cv2.INTER_NEAREST).astype(np.int64)
        return frame, landmarks, segmentation


def _to_unit(frames: np.ndarray) -> torch.Tensor:
    """(N, S, S, 3) uint8 -> (N, 3, S, S) float32 in [0, 1]."""
    return torch.from_numpy(frames).permute(0, 3, 1, 2).to(torch.float32).div_(255.0)


def landmark_images(landmarks: torch.Tensor, size: int) -> torch.Tensor:
    """(N, 68, 2) float pixels -> (N, 3, S, S) float32 in [-1, 1] (``draw_landmarks``; black = -1)."""
    from landmarks.shape.raster import draw_landmarks

    drawn = np.stack([draw_landmarks(points.numpy(), size) for points in landmarks])  # (N, S, S, 3) uint8
    return _to_unit(drawn) * 2.0 - 1.0


def _rngs(seed: int, epoch: int, index: int) -> tuple[np.random.Generator, torch.Generator]:
    rng = np.random.default_rng([seed, epoch, index])
    generator = torch.Generator().manual_seed(int(rng.integers(0, 2**62)))
    return rng, generator


def _check_shots(shots: int) -> None:
    if not 1 <= shots <= MAX_K:
        raise ConfigError(f"shots (K) must be in 1..{MAX_K}, got {shots}")


def _draw_shots(rng: np.random.Generator, pool: list[FrameRef], shots: int) -> list[FrameRef]:
    picks = rng.choice(len(pool), size=shots, replace=len(pool) < shots)
    return [pool[int(p)] for p in picks]


class EpisodeDataset(Dataset):
    """K-shot training episodes (see the module docstring for the item contract).

    root: dataset root with manifest.json; split: manifest split name or None for all;
    shots: K in 1..32; size: output side S (default: the clips' size); episodes: dataset length
    (default: number of usable target frames); seed: base seed; augment: None or ``AugmentConfig``.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str | None = "train",
        shots: int = 8,
        size: int | None = None,
        episodes: int | None = None,
        seed: int = 0,
        shots_from: Literal["identity", "video", "video_apart"] = "identity",
        augment: AugmentConfig | None = None,
        with_segmentation: bool = True,
        warp_references: int = 0,
        expression_episodes: float = 0.0,
    ) -> None:
        _check_shots(shots)
        if not 0.0 <= expression_episodes <= 1.0:
            raise ConfigError(f"expression_episodes must be in [0, 1], got {expression_episodes}")
        if warp_references < 0:
            raise ConfigError(f"warp_references must be >= 0, got {warp_references}")
        self.warp_references = warp_references
        if shots_from not in SHOTS_FROM:
            raise ConfigError(f"shots_from must be one of {', '.join(SHOTS_FROM)}, got {shots_from!r}")
        if augment is not None:
            augment.validate()
        self.index = _FrameIndex(root, split, size)
        self.shots, self.seed, self.epoch = shots, seed, 0
        self.shots_from, self.augment, self.with_segmentation = shots_from, augment, with_segmentation
        # A target needs at least one other usable frame in its pool.
        if shots_from == "identity":
            pools = {name: refs for name, refs in self.index.frames_by_identity.items() if len(refs) >= 2}
        else:
            pools = {key: refs for key, refs in self.index.frames_by_video.items() if len(refs) >= 2}
        self.targets = [ref for refs in pools.values() for ref in refs]
        if not self.targets:
            raise DatasetError(f"{root} (split {split!r}) has no {shots_from} with two or more frames with landmarks; "
                               "prepare more frames per clip")
        self._pools = pools
        self.identities = sorted({self.index.clips[ref.clip].identity for ref in self.targets})
        self._identity_id = {name: i for i, name in enumerate(self.identities)}
        self.episodes = len(self.targets) if episodes is None else int(episodes)
        if self.episodes < 1:
            raise ConfigError(f"episodes must be >= 1, got {episodes}")
        self.expression_episodes = float(expression_episodes)
        self._open_targets: list[FrameRef] = []
        self._closed: dict[str | tuple[str, str], set[FrameRef]] = {}
        if self.expression_episodes > 0:
            self._index_mouths()

    def _index_mouths(self) -> None:
        """Per pool: the frames with the widest mouths (expression targets) and the closed half (their shots)."""
        from landmarks.shape.expression import mouth_opening

        for key, refs in self._pools.items():
            opening = mouth_opening(np.stack([self.index.clips[r.clip].landmarks[r.frame] for r in refs]))
            if len(refs) < 4 or not np.isfinite(opening).all() or np.ptp(opening) <= 0:
                continue
            wide, median = np.quantile(opening, OPEN_MOUTH_QUANTILE), np.median(opening)
            self._open_targets.extend(r for r, o in zip(refs, opening) if o > wide)
            self._closed[key] = {r for r, o in zip(refs, opening) if o <= median}
        if not self._open_targets:
            raise DatasetError("expression episodes need clips whose mouths open and close (4 or more frames each); "
                               "none has")

    @property
    def size(self) -> int:
        return self.index.size

    def set_epoch(self, epoch: int) -> None:
        """Draw a different (still deterministic) set of episodes for each epoch."""
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.episodes

    def _pool_key(self, ref: FrameRef) -> str | tuple[str, str]:
        clip = self.index.clips[ref.clip]
        return clip.identity if self.shots_from == "identity" else (clip.identity, clip.video)

    def _shot_pool(self, target_ref: FrameRef) -> list[FrameRef]:
        """The frames the target's shots are drawn from (never the target itself)."""
        pool = [ref for ref in self._pools[self._pool_key(target_ref)] if ref != target_ref]
        if self.shots_from == "video_apart":
            same_clip = sorted(ref.frame for ref in pool if ref.clip == target_ref.clip) + [target_ref.frame]
            middle = (min(same_clip) + max(same_clip)) / 2.0
            apart = [ref for ref in pool if ref.clip != target_ref.clip or (ref.frame < middle) != (target_ref.frame < middle)]
            pool = apart or pool  # a clip with its frames on one side only: the whole video
        return pool

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if not 0 <= index < self.episodes:
            raise IndexError(f"episode {index} out of range ({self.episodes})")
        rng, generator = _rngs(self.seed, self.epoch, index)
        if self.expression_episodes > 0 and rng.random() < self.expression_episodes:
            target_ref = self._open_targets[int(rng.integers(len(self._open_targets)))]
            pool = self._shot_pool(target_ref)
            closed = self._closed[self._pool_key(target_ref)]
            pool = [ref for ref in pool if ref in closed] or pool
        else:
            target_ref = self.targets[int(rng.integers(len(self.targets)))]
            pool = self._shot_pool(target_ref)
        refs = _draw_shots(rng, pool, self.shots) + [target_ref]
        loaded = [self.index.load(ref, with_segmentation=False) for ref in refs[:-1]]
        loaded.append(self.index.load(target_ref, with_segmentation=self.with_segmentation))
        images = _to_unit(np.stack([frame for frame, _, _ in loaded]))  # (K+1, 3, S, S) in [0, 1]
        points = torch.from_numpy(np.stack([lm for _, lm, _ in loaded]))  # (K+1, 68, 2)
        segmentation = torch.from_numpy(loaded[-1][2]) if self.with_segmentation else None  # (S, S)
        if self.augment is not None:
            stacked_seg = None
            if segmentation is not None:  # only the target's map matters; shots get ignore maps
                stacked_seg = torch.full((len(refs), self.size, self.size), SEGMENTATION_IGNORE_INDEX, dtype=torch.int64)
                stacked_seg[-1] = segmentation
            images, points, stacked_seg = augment_frames(images, points, stacked_seg, generator, self.augment)
            segmentation = None if stacked_seg is None else stacked_seg[-1]
        drawn = landmark_images(points, self.size)
        images = images * 2.0 - 1.0
        item = {
            "shots": images[:-1].contiguous(),
            "shot_landmark_images": drawn[:-1].contiguous(),
            "shot_landmarks": points[:-1].to(torch.float32).contiguous(),
            "target": images[-1].contiguous(),
            "target_landmark_image": drawn[-1].contiguous(),
            "target_landmarks": points[-1].to(torch.float32).contiguous(),
            "identity": torch.tensor(self._identity_id[self.index.clips[target_ref.clip].identity], dtype=torch.int64),
            "index": torch.tensor(index, dtype=torch.int64),
        }
        if segmentation is not None:
            item["target_segmentation"] = segmentation.contiguous()
        if self.warp_references:
            item.update(reference_tensors(images[:-1], points[:-1], points[-1], self.warp_references))
        return item


def reference_tensors(shots: torch.Tensor, shot_landmarks: torch.Tensor, target_landmarks: torch.Tensor,
                      count: int) -> dict[str, torch.Tensor]:
    """The ``count`` nearest shots warped onto the target (``landmarks.warp.tps.warp_references``) as network inputs.

    shots: (K, 3, S, S) in [-1, 1]; shot_landmarks: (K, 68, 2); target_landmarks: (68, 2)
    -> {"references": (count, 3, S, S) in [-1, 1], "reference_masks": (count, 1, S, S) in {0, 1}}.
    """
    from landmarks.warp.tps import warp_references

    frames = ((shots.permute(0, 2, 3, 1) + 1.0) * 127.5).round().clamp(0, 255).to(torch.uint8).numpy()  # (K, S, S, 3)
    warped, masks, _ = warp_references(frames, shot_landmarks.numpy(), target_landmarks.numpy(), count)
    return {
        "references": _to_unit(warped) * 2.0 - 1.0,
        "reference_masks": torch.from_numpy(masks)[:, None].contiguous(),
    }


class CrossIdentityDataset(Dataset):
    """Evaluation pairs: K shots of a source identity, a driver frame of a *different* identity.

    Items: ``shots``, ``shot_landmark_images``, ``shot_landmarks`` (as in ``EpisodeDataset``),
    ``driver`` (3, S, S) in [-1, 1] (for display; not a ground truth), ``driver_landmark_image``
    (3, S, S) in [-1, 1], ``driver_landmarks`` (68, 2), ``source_identity`` and ``driver_identity``
    (int64 indices into ``identities``), ``index``. No augmentation. Needs two or more identities.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str | None = "test",
        shots: int = 8,
        size: int | None = None,
        pairs: int | None = None,
        seed: int = 0,
    ) -> None:
        _check_shots(shots)
        self.index = _FrameIndex(root, split, size)
        self.identities = self.index.identities
        if len(self.identities) < 2:
            raise DatasetError(f"{root} (split {split!r}) has {len(self.identities)} identity with landmarks; "
                               "cross-identity pairs need two or more")
        self.shots, self.seed = shots, seed
        self.pairs = sum(len(self.index.frames_by_identity[n]) for n in self.identities) if pairs is None else int(pairs)
        if self.pairs < 1:
            raise ConfigError(f"pairs must be >= 1, got {pairs}")

    @property
    def size(self) -> int:
        return self.index.size

    def __len__(self) -> int:
        return self.pairs

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if not 0 <= index < self.pairs:
            raise IndexError(f"pair {index} out of range ({self.pairs})")
        rng, _ = _rngs(self.seed, 0, index)
        source = int(rng.integers(len(self.identities)))
        driver = (source + 1 + int(rng.integers(len(self.identities) - 1))) % len(self.identities)
        source_pool = self.index.frames_by_identity[self.identities[source]]
        driver_pool = self.index.frames_by_identity[self.identities[driver]]
        refs = _draw_shots(rng, source_pool, self.shots) + [driver_pool[int(rng.integers(len(driver_pool)))]]
        loaded = [self.index.load(ref, with_segmentation=False) for ref in refs]
        images = _to_unit(np.stack([frame for frame, _, _ in loaded])) * 2.0 - 1.0
        points = torch.from_numpy(np.stack([lm for _, lm, _ in loaded]))
        drawn = landmark_images(points, self.size)
        return {
            "shots": images[:-1].contiguous(),
            "shot_landmark_images": drawn[:-1].contiguous(),
            "shot_landmarks": points[:-1].contiguous(),
            "driver": images[-1].contiguous(),
            "driver_landmark_image": drawn[-1].contiguous(),
            "driver_landmarks": points[-1].contiguous(),
            "source_identity": torch.tensor(source, dtype=torch.int64),
            "driver_identity": torch.tensor(driver, dtype=torch.int64),
            "index": torch.tensor(index, dtype=torch.int64),
        }
