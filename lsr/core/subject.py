"""An encoded subject: its K shots, their averaged latents, and what is read off its shots once (lids at rest,
irises, the anchor's gaze) for every frame it is driven in. ``lsr.core.engine.ReenactorBase.encode_subject`` makes
it; the frame loop, the live session and the web export read it. Torch-free."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from landmarks.parts.eyes.drawn_lids import shot_lid_gaps
from landmarks.parts.bank_rows import BankRows
from landmarks.parts.eyes.eye_bank import EyeBank, build_eye_bank, eye_bank_of, eye_row
from landmarks.parts.mouth.mouth_bank import MouthBank, build_mouth_bank, mouth_bank_of, mouth_row
from landmarks.parts.eyes.iris import gaze_offsets, iris_donor
from lsr.core.finish import found_irises, shot_irises
from lsr.core.inputs import SubjectShots


@dataclasses.dataclass
class Subject:
    """An encoded subject: its K shots and averaged latents (thesis eq. 4.3: z = 1/K sum_i E(I_i))."""

    shots: SubjectShots
    layout_latent: np.ndarray
    """(1, D) float32."""
    style_latent: np.ndarray
    """(1, D) float32."""
    source: str | None
    """Resolved source path when the source was one file or folder (decides the default mode)."""
    banks: dict[str, tuple[EyeBank | None, MouthBank | None]] = dataclasses.field(default_factory=dict, repr=False)
    """Its part banks, by ``lsr.core.finish.BANKS`` scope, built on first use (``part_banks``)."""
    video_track: tuple[object, list[np.ndarray | None]] | None = dataclasses.field(default=None, repr=False)
    """A video source's (the detector its tracker ran with, each frame's 68 points or None) as the "all" banks' pass
    tracked them: the scene's stream (``lsr.core.scene.SourceScene``) takes them for the same detector instead of
    tracking the same frames again."""

    def part_banks(self, scope: str, detector=None) -> tuple[EyeBank | None, MouthBank | None]:
        """Its eyes and mouths, indexed (``landmarks.parts``): scope "shots", its K shots; "all", every frame of a
        video source (tracked with ``detector``'s tracker; the shots for other sources). None where none shows a
        face."""
        if scope not in ("all", "shots"):
            raise ValueError(f"a part bank's scope must be 'all' or 'shots', got {scope!r}")
        if scope not in self.banks:
            if scope == "all" and self.shots.video is not None:
                track: list[np.ndarray | None] = []
                self.banks[scope] = video_part_banks(self.shots.video, detector, track=track)
                self.video_track = (detector, track)
            else:
                shots = self.shots
                self.banks[scope] = (build_eye_bank(zip(shots.frames, shots.landmarks, self.found_irises[0])),
                                     build_mouth_bank(zip(shots.frames, shots.landmarks)))
        return self.banks[scope]

    @functools.cached_property
    def lid_gaps(self) -> np.ndarray:
        """(2,) its lids at rest, the median lid gaps of its shots (``landmarks.parts.eyes.drawn_lids.shot_lid_gaps``)."""
        return shot_lid_gaps(self.shots.landmarks)

    @functools.cached_property
    def found_irises(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Its shots' irises (K, 2, 4) and their eyes' median open apertures (``lsr.core.finish.found_irises``): the
        iris net runs on its shots once, on first use."""
        return found_irises(self.shots.frames, self.shots.landmarks)

    @functools.cached_property
    def shot_irises(self) -> np.ndarray:
        """(K, 2, 2) each shot's iris centres in its crop pixels (``lsr.core.finish.shot_irises``), for ``eyes``
        "warped"."""
        return shot_irises(self.shots.frames, self.shots.landmarks, self.found_irises)

    @functools.cached_property
    def anchor_gaze(self) -> np.ndarray:
        """(2, 2) the anchor shot's gaze (``landmarks.parts.eyes.iris.gaze_offsets``, NaN where not found): where relative
        motion starts the gaze from."""
        anchor = self.shots.anchor
        return gaze_offsets(self.found_irises[0][anchor], self.shots.landmarks[anchor])

    @functools.cached_property
    def irises(self) -> tuple:
        """(the irises drawn into its frames, ``landmarks.parts.eyes.iris.iris_donor``, or None; ``anchor_gaze``), found on
        first use."""
        return iris_donor(self.shots.frames, self.shots.landmarks, self.found_irises[0]), self.anchor_gaze

    @property
    def reference_landmarks(self) -> np.ndarray:
        """(68, 2) crop landmarks of the anchor shot (the most neutral): the face relative motion is applied to."""
        return self.shots.landmarks[self.shots.anchor]

    @property
    def reference_mesh(self) -> np.ndarray | None:
        """(468, 3) crop mesh of the anchor shot, or None when the shots have no meshes."""
        meshes = self.shots.meshes
        if meshes is None or not np.isfinite(meshes[self.shots.anchor]).all():
            return None
        return meshes[self.shots.anchor]


def video_part_banks(video, detector=None, max_entries: int = 600, track: list | None = None
                     ) -> tuple[EyeBank | None, MouthBank | None]:
    """The eye and mouth banks of every frame of a video (``landmarks.parts``), in one pass, each frame cut into both
    banks' rows as it is decoded (memory bounded by ``landmarks.parts.bank_rows.BankRows``): tracked with
    ``detector``'s tracker (``landmarks.detect.registry.make_tracker``), whose iris net's irises come with its faces (the
    mesh tracker); other trackers' irises are found per frame (``landmarks.parts.eyes.iris.find_irises``). track: a
    list that gets each frame's points as tracked (None where no face was found)."""
    import contextlib

    from landmarks.detect.registry import make_tracker
    from landmarks.parts.eyes.iris import find_irises
    from landmarks.io.video import iter_frames
    from lsr.core.overlap import prefetch

    tracker = make_tracker(detector)
    eyes, mouths = BankRows(max_entries), BankRows(max_entries)
    with contextlib.closing(prefetch(iter_frames(video))) as frames:  # decoded on a thread beside the tracking
        for frame in frames:
            points = tracker.update(frame)
            if track is not None:
                track.append(None if points is None else np.array(points))  # as tracked, its own dtype
            if points is None or not np.isfinite(points).all():
                continue
            points = np.asarray(points, np.float64)
            irises = getattr(tracker, "irises", None)
            row = eye_row(frame, points, irises if irises is not None else find_irises(frame, points))
            eyes.add(row)
            mouths.add(mouth_row(frame, points, None if row is None else row[-1]))  # the head turn read once
    return eye_bank_of(eyes.spread()), mouth_bank_of(mouths.spread())
