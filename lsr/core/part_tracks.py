"""A driven sequence's choice of the subject's own parts from its banks (issue 63; ``landmarks.parts``): one track
per banked part, fed the frames' targets in order by the frame loop (``lsr.core.engine``) or the live session
(``lsr.core.live_session``), so that hysteresis holds. Torch-free."""

from __future__ import annotations

import dataclasses

import numpy as np

from landmarks.parts.eyes.eye_bank import EyeBankTrack, EyeChoice
from landmarks.parts.mouth.mouth_bank import MouthBankTrack, MouthChoice
from lsr.core.subject import Subject


@dataclasses.dataclass
class PartTracks:
    """A driven sequence's choice of bank parts: the eyes' and the mouth's, either None."""

    eyes: EyeBankTrack | None
    mouth: MouthBankTrack | None

    def __call__(self, landmarks: np.ndarray, gaze: np.ndarray | None) -> tuple[EyeChoice | None, MouthChoice | None]:
        return (None if self.eyes is None else self.eyes(landmarks, gaze),
                None if self.mouth is None else self.mouth(landmarks))

    def reset(self) -> None:
        for track in (self.eyes, self.mouth):
            if track is not None:
                track.reset()


def part_tracks(subject: Subject, bank: str, parts: str, detector, relative: bool) -> PartTracks | None:
    """A new sequence's tracks over ``subject``'s banks of scope ``bank`` (``lsr.core.finish.BANKS``; "none": None) for
    ``parts`` (``lsr.core.finish.BANK_PARTS``), built on first use with ``detector`` (``Subject.part_banks``).
    relative: the targets' lids were retargeted from a driver's onto the subject's anchor."""
    if bank == "none":
        return None
    eye_bank, mouth_bank = subject.part_banks(bank, detector)
    eyes = (EyeBankTrack(eye_bank, subject.reference_landmarks if relative else None)
            if eye_bank is not None and parts in ("eyes", "both") else None)
    mouth = MouthBankTrack(mouth_bank) if mouth_bank is not None and parts in ("mouth", "both") else None
    return PartTracks(eyes, mouth)
