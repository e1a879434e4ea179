"""Where the training people's lids sit when their eyes close: the survey behind ``landmarks.parts.eyes.lids.LID_CLOSED``
and ``CLOSED_SHARE``, for the mesh net's own eye contours and for the refined ones (``landmarks.detect.mediapipe_mesh``, step 3b).

    lsr face-models lids ../shared/data/real_talking_heads [--frames-per-clip 64]

Per training person (the validation people left out, as ``lsr face-models fit`` does), on frames spread evenly
through each clip: the mean lid gap of both eyes (``landmarks.parts.eyes.lids.lid_gaps``) of the largest face, once from the
mesh net alone and once with its eyes refined, on the same frames and regions. Printed: the 1st / 5th percentile
over all frames, the people who blink (smallest gap under 0.75 of their median), their smallest gaps' median and
their closed / open ratio (smallest over median).
"""

from __future__ import annotations

import collections
from pathlib import Path
from typing import Any

import numpy as np

from landmarks.parts.eyes.lids import lid_gaps

BLINKING = 0.75  # a person whose smallest gap is under this share of their median gap closed their eyes


def survey(data: Path, frames_per_clip: int = 64) -> dict[str, dict[str, list[float]]]:
    """{person: {"mesh": gaps, "refined": gaps}} over the training clips under ``data`` (real*/**/*.mp4);
    InputFileError when there are none."""
    from tqdm import tqdm

    from landmarks.exceptions import InputFileError
    from landmarks.detect import mediapipe_mesh as face_mesh
    from landmarks.shape.mesh68 import VALIDATION_PEOPLE
    from landmarks.detect.mediapipe_tracker import MeshDetector
    from landmarks.io.video import iter_frames, probe_video

    detector = MeshDetector()
    gaps: dict[str, dict[str, list[float]]] = collections.defaultdict(lambda: {"mesh": [], "refined": []})
    videos = sorted(path for path in data.glob("real*/**/*.mp4")
                    if path.relative_to(data).parts[0] not in VALIDATION_PEOPLE)
    if not videos:
        raise InputFileError(f"no real*/**/*.mp4 clips under {data}; give the real_talking_heads folder")
    for video in tqdm(videos, desc="lid gaps", unit="clip"):
        person = video.relative_to(data).parts[0]
        count = probe_video(video).frames
        picks = set(np.linspace(0, max(count - 1, 0), min(frames_per_clip, count)).round().astype(int).tolist())
        for index, frame in enumerate(iter_frames(video)):
            if index in picks and (found := detector.meshes(frame)):
                result = found[0][1]  # its mesh: the region's, eyes refined; the mesh net's own on the same region
                raw = face_mesh.predict_mesh(frame, result.region, eyes=False).mesh
                gaps[person]["mesh"].append(float(lid_gaps(raw).mean()))
                gaps[person]["refined"].append(float(lid_gaps(result.mesh).mean()))
            if index >= max(picks):
                break
    return dict(gaps)


def summary(gaps: dict[str, dict[str, list[float]]], kind: str) -> str:
    people = [np.asarray(person[kind]) for person in gaps.values() if person[kind]]
    smallest, median = np.array([g.min() for g in people]), np.array([np.median(g) for g in people])
    every = np.concatenate(people)
    blink = smallest < BLINKING * median
    ratio = smallest[blink] / median[blink]
    return (f"{kind:8s} {len(people)} people: all frames 1st / 5th percentile {np.percentile(every, 1):.3f} / "
            f"{np.percentile(every, 5):.3f}; {int(blink.sum())} blink: smallest gap median "
            f"{np.median(smallest[blink]):.3f}, closed / open median {np.median(ratio):.2f} "
            f"(quartiles {np.percentile(ratio, 25):.2f}-{np.percentile(ratio, 75):.2f})")


def run_survey(cfg: Any) -> dict[str, dict[str, list[float]]]:
    """Entry point of ``lsr face-models lids`` (``lsr.config.FaceModelsLidsConfig``): survey, print both summaries."""
    gaps = survey(Path(cfg.data), cfg.frames_per_clip)
    for kind in ("mesh", "refined"):
        print(summary(gaps, kind))
    return gaps
