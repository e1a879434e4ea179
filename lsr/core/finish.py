"""The parts' steps after the frame synthesis (issues 23 and 40), torch-free: the nearest warped shot's mouth, the
mouth drawn by a part generator over it, and the eyes drawn with one iris where the driver looks.

``finish_eyes`` applies a reenactor's ``eyes`` choice (``EYES``): the subject's irises (``lsr.core.subject.Subject``:
the shot with the most open eyes, and the anchor shot's gaze, which relative motion starts from) drawn into the
synthesis at the target's gaze (``DriverGaze``, ``sequence_gazes``; ``landmarks.parts.eyes.iris``). "warped" acts before the
synthesis instead: the engine gives the references' warps each shot's iris (``shot_irises``) and the target's gaze.

``finish_mouth`` applies a reenactor's ``mouth`` choice (``MOUTHS``). ``draw_mouth`` cuts the mouth's window out of the synthesised crop (``landmarks.parts.part_window``), gives it and the
target's lip masks to the backend's part generator (``models_def.part_generator``: the torch module or its ONNX
graph) and pastes the drawn window back under a feathered mask around the lips. The window is level with the
eyes and at the generator's own resolution whatever the crop's size.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from landmarks.parts.eyes.drawn_lids import draw_lids
from landmarks.parts.eyes.driver_lids import paste_eyes
from landmarks.parts.eyes.eye_bank import paste_bank_eyes
from landmarks.parts.mouth.interior import paste_interior
from landmarks.parts.mouth.mouth_bank import paste_bank_mouth
from landmarks.parts.eyes.iris import CLOSED, IrisDonor, draw_irises, find_irises, gaze_offsets, iris_donor, retarget_gaze
from lsr.core.images import from_network, to_network
from landmarks.parts.part_window import (MOUTH, PartWindow, extract, lip_masks, paste, paste_weight, to_window,
                                   window_eye_distance, window_transform)

PartRunner = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""(window (1, 3, P, P) float32 in [-1, 1], masks (1, 2, P, P) float32 in [0, 1]) -> (1, 3, P, P) in [-1, 1]."""
EYES = ("drawn", "warped", "blend")
"""A model's eyes: one iris per eye, the subject's own, drawn where the driver looks ("drawn", ``finish_eyes``,
``landmarks.parts.eyes.iris``; frame drivers only: a landmark driver has no irises); the shots' own irises carried by their
warps to where the driver looks, or where a landmark driver gives no gaze, to where the nearest shot's lands
("warped", ``shot_irises``, ``landmarks.parts.eyes.iris_shift``); or the network's blend of its shots as warped ("blend")."""
MOUTH_INTERIORS = ("driver", "shots")
"""Inside an open mouth: the driver frame's cavity, teeth and tongue inside the target's inner lips ("driver",
``landmarks.parts.mouth.interior``; where the driver is a video or a camera) or what ``MOUTHS``' choice gives ("shots")."""
LIDS = ("drawn", "driver", "shots")
"""Where the target shuts its eyes: the subject's own upper lids drawn down over the synthesis' eyes ("drawn",
``landmarks.parts.eyes.drawn_lids``), the driver frame's shut lids laid in ("driver", ``landmarks.parts.eyes.driver_lids``; where the
driver is a video or a camera, drawn where none were cut), or the warped shots' lids lowered alone ("shots",
``landmarks.parts.eyes.lids``)."""
BANKS = ("all", "shots", "none")
"""Where the subject's own eyes and mouth come from (``landmarks.parts``: per frame one real exemplar of the person,
moved into place over the synthesis): every frame the source gives, a video's every frame ("all"), the K shots alone
("shots", the evaluation protocol's inputs), or none: the synthesis' ("none")."""
BANK_PARTS = ("eyes", "both", "mouth")
"""Which parts come from the banks (``BANKS``): the eyes by default. The mouth bank is indexed by the driving
detector's inner lips, which read a mouth showing its teeth as nearly shut (MODEL_CARD.md), so it lays teeth into
shut mouths and a slit into open ones; it is measured beside the eyes (``lsr bench eyes``), not shipped on."""
MOUTHS = ("drawn", "nearest", "blend")
"""A warp-guided model's mouth: the nearest warped shot's where the target opens it wider than the shots, then
redrawn by the mouth generator ("drawn"); without the redrawing ("nearest"); the network's blend alone ("blend")."""


class Choice:
    """A reenactor setting that is one of ``choices`` (``default`` until set): setting anything else is a ValueError
    that names the setting. Used as a class attribute (``ReenactorBase.eyes``, ``mouth_interior``, ``lids``)."""

    def __init__(self, choices: tuple[str, ...], default: str, doc: str) -> None:
        self.choices, self.default, self.__doc__ = choices, default, doc
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, instance: object, owner: type | None = None):
        return self if instance is None else instance.__dict__.get(self.name, self.default)

    def __set__(self, instance: object, value: str) -> None:
        if value not in self.choices:
            raise ValueError(f"{self.name} must be one of {self.choices}, got {value!r}")
        instance.__dict__[self.name] = value


def set_parts(reenactor: object, **choices: object) -> None:
    """Set the part settings that are given (not None) on ``reenactor``: ``mouth``, ``eyes``, ``mouth_interior``,
    ``lids``, ``expression_gain``, ``bank``, ``bank_parts``. The one place lsr eval and lsr bench vary them; an
    unknown setting is a ValueError naming it (a ``Choice`` checks each value)."""
    for name, value in choices.items():
        if not hasattr(type(reenactor), name):
            raise ValueError(f"a reenactor has no part setting {name!r}")
        if value is not None:
            setattr(reenactor, name, value)


def draws_mouth(backend: object) -> bool:
    """Whether ``backend`` has a mouth generator (``SynthesisBackend.draw_mouth``, ``mouth_generator_size`` > 0)."""
    return getattr(backend, "mouth_generator_size", 0) > 0


def finish_mouth(image: np.ndarray, mouth: str, inputs: dict[str, np.ndarray], crop_landmarks: np.ndarray,
                 shot_landmarks: np.ndarray, warp_references: int, backend) -> np.ndarray:
    """The synthesis ``image`` (C, C, 3) uint8 with its mouth as ``mouth`` says: "nearest" and "drawn" take the
    nearest warped shot's (``inputs``' first reference) as far as ``landmarks.parts.mouth.nearest_mouth.mouth_strength`` says;
    "drawn" then redraws it with ``backend.draw_mouth``; "blend" leaves it. crop_landmarks: (68, 2) target pixels;
    shot_landmarks: (K, 68, 2) the subject's shots'."""
    if mouth in ("nearest", "drawn") and "references" in inputs:
        from landmarks.parts.mouth.nearest_mouth import keep_nearest_mouth, mouth_strength

        strength = mouth_strength(crop_landmarks, shot_landmarks, warp_references)
        if strength > 0:  # most frames: the shots show this mouth, so the reference is not even converted
            image = keep_nearest_mouth(image, from_network(inputs["references"][0, 0]),
                                       inputs["reference_masks"][0, 0, 0], crop_landmarks, strength)
    if mouth == "drawn":
        image = draw_mouth(image, crop_landmarks, backend.draw_mouth)
    return image


def mouth_inputs(image: np.ndarray, crop_landmarks: np.ndarray, part: PartWindow = MOUTH
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The part generator's inputs for ``image`` (C, C, 3) uint8 and the target's landmarks (68, 2) in its pixels:
    (window (1, 3, P, P) float32 in [-1, 1], masks (1, 2, P, P) float32, window landmarks (68, 2), transform
    (2, 3) crop -> window), or None when the landmarks are not finite."""
    transform = window_transform(crop_landmarks, part)
    if transform is None:
        return None
    window = extract(image, transform, part.size)
    points = to_window(crop_landmarks, transform)
    return to_network(window)[None], lip_masks(points, part.size)[None], points, transform


def draw_mouth(image: np.ndarray, crop_landmarks: np.ndarray, run: PartRunner, part: PartWindow = MOUTH) -> np.ndarray:
    """``image`` (C, C, 3) uint8 with its mouth redrawn by ``run`` for the target's landmarks (68, 2) in crop
    pixels; a new array (``image`` itself when the landmarks are not finite)."""
    found = mouth_inputs(image, crop_landmarks, part)
    if found is None:
        return image
    window, masks, points, transform = found
    drawn = from_network(run(window, masks)[0])
    return paste(image, drawn, paste_weight(points, part.size, window_eye_distance(part)), transform)


def found_irises(frames, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Each frame's irises and its eyes' apertures when open: N x (H, W, 3) uint8, (N, 68, 2) -> (irises (N, 2, 4)
    ``landmarks.parts.eyes.iris.find_irises``, the median aperture of each eye over the frames (2,), None where none was
    found)."""
    irises = np.stack([find_irises(frame, points) for frame, points in zip(frames, landmarks)]) if len(frames) else \
        np.zeros((0, 2, 4))
    return irises, np.nanmedian(irises[..., 3], axis=0) if np.isfinite(irises[..., 3]).any() else None


def shot_irises(frames: np.ndarray, landmarks: np.ndarray, found: tuple | None = None) -> np.ndarray:
    """A subject's shots (K, C, C, 3) uint8 with their landmarks (K, 68, 2) -> (K, 2, 2) float64 each shot's iris
    centres (``landmarks.parts.eyes.iris.find_irises``), NaN where not found or where the eye is closing against its median
    aperture over the shots (``landmarks.parts.eyes.iris.CLOSED``): the irises ``landmarks.parts.eyes.iris_shift`` carries. found:
    ``found_irises`` of the same shots, when already at hand."""
    irises, opened = found_irises(frames, landmarks) if found is None else found
    centres = irises[..., :2].copy()
    if opened is not None:
        centres[~(irises[..., 3] >= CLOSED * opened)] = np.nan
    return centres


def sequence_gazes(frames, landmarks: np.ndarray) -> np.ndarray:
    """A whole sequence's gazes: N x (H, W, 3) uint8, (N, 68, 2) -> (N, 2, 2) ``landmarks.parts.eyes.iris.gaze_offsets``,
    NaN where an iris is not found or the eye is closing against its median aperture over the sequence."""
    irises, opened = found_irises(frames, landmarks)
    return np.stack([gaze_offsets(i, p, opened) for i, p in zip(irises, landmarks)]) if len(frames) else np.zeros((0, 2, 2))


class DriverGaze:
    """A driver's gaze, frame by frame, as the target's: ``source`` None, its own (absolute); else ``source`` (2, 2)
    (the subject's anchor gaze) moved by the driver's since its first frame whose irises were found
    (``landmarks.parts.eyes.iris.retarget_gaze``), as relative motion moves the 68 points. An eye is closing (no gaze) against
    the median of its last ``HISTORY`` apertures."""

    HISTORY = 150

    def __init__(self, source: np.ndarray | None) -> None:
        self.source = source
        self.reference: np.ndarray | None = None
        self.apertures: list[np.ndarray] = []

    def __call__(self, frame: np.ndarray, points: np.ndarray, irises: np.ndarray | None = None) -> np.ndarray:
        """frame (H, W, 3) uint8 and its 68 points (the tracker's, frame pixels) -> the target's gaze (2, 2).
        irises: the tracker's own (the mesh tracker runs the iris net on the same eyes: ``tracker.irises``), else
        found here (``landmarks.parts.eyes.iris.find_irises``, about 4 ms)."""
        if irises is None or not np.isfinite(irises).all():
            irises = find_irises(frame, points)
        if np.isfinite(irises[:, 3]).all():
            self.apertures = (self.apertures + [irises[:, 3]])[-self.HISTORY:]
        gaze = gaze_offsets(irises, points, np.median(self.apertures, axis=0) if self.apertures else None)
        if self.source is None:
            return gaze
        if self.reference is None and np.isfinite(gaze).all():
            self.reference = gaze
        return gaze if self.reference is None else retarget_gaze(gaze, self.reference, self.source)


def finish_eyes(image: np.ndarray, eyes: str, crop_landmarks: np.ndarray, gaze: np.ndarray | None,
                donor: IrisDonor | None) -> np.ndarray:
    """The synthesis ``image`` (C, C, 3) uint8 with its eyes as ``eyes`` says: "drawn" lays ``donor``'s irises at
    ``gaze`` (2, 2) into the lids of ``crop_landmarks`` (68, 2) (``landmarks.parts.eyes.iris.draw_irises``); "blend", or no
    gaze or donor, leaves it."""
    if eyes != "drawn" or gaze is None or donor is None:
        return image
    return draw_irises(image, crop_landmarks, gaze, donor)


def finish_lids(image: np.ndarray, lids: str, crop_landmarks: np.ndarray, lid_gaps: np.ndarray, driver_eyes,
                which: tuple[bool, bool] = (True, True)) -> np.ndarray:
    """The shut lids as ``lids`` (``LIDS``) says: the driver's laid in where it has ``driver_eyes`` and ``lids`` is
    "driver" (both eyes), else the subject's drawn down (``lid_gaps``: its lids at rest) over the eyes ``which``;
    "shots" leaves ``image``."""
    if driver_eyes is not None and lids == "driver":
        return paste_eyes(image, crop_landmarks, driver_eyes)
    if lids != "shots":
        return draw_lids(image, crop_landmarks, lid_gaps, which)
    return image


def finish_parts(image: np.ndarray, settings, inputs: dict[str, np.ndarray], crop_landmarks: np.ndarray, subject,
                 gaze: np.ndarray | None, driver_mouth, driver_eyes, eye_choice, mouth_choice) -> np.ndarray:
    """The parts' steps after the frame synthesis, in order, on the (C, C, 3) uint8 ``image`` of target landmarks
    ``crop_landmarks`` (68, 2) crop pixels; ``settings``: the reenactor (its ``mouth``, ``mouth_interior``, ``lids``,
    ``eyes``, ``warp_references`` and ``backend``). The mouth as ``mouth`` says (the nearest warped shot's, redrawn
    by the mouth generator for "drawn"); with a ``driver_mouth``, the interior as ``mouth_interior`` says; the shut
    lids as ``lids`` says (the driver's with ``driver_eyes``, else drawn); with a ``gaze``, drawn irises for ``eyes``
    "drawn"; then the subject's own mouth and eyes from its part banks over all that, each choice carrying the bank
    it was made from (``landmarks.parts``), and the lids again over a bank eye the target shuts further than its
    entry shows (``EyeChoice.shut``)."""
    if settings.mouth != "blend":
        image = finish_mouth(image, settings.mouth, inputs, crop_landmarks, subject.shots.landmarks,
                             settings.warp_references, settings.backend)
    if driver_mouth is not None and settings.mouth_interior == "driver":
        image = paste_interior(image, crop_landmarks, driver_mouth)
    image = finish_lids(image, settings.lids, crop_landmarks, subject.lid_gaps, driver_eyes)
    if gaze is not None and settings.eyes == "drawn":
        image = finish_eyes(image, settings.eyes, crop_landmarks, gaze, subject.irises[0])
    image = paste_bank_mouth(image, crop_landmarks, None, mouth_choice)
    image = paste_bank_eyes(image, crop_landmarks, None, eye_choice)
    if eye_choice is not None and any(eye_choice.shut):  # shut further than the bank shows: lids over its eye
        image = finish_lids(image, settings.lids, crop_landmarks, subject.lid_gaps, driver_eyes, eye_choice.shut)
    return image
