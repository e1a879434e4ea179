"""The person's own mouth, from every frame they give: a mouth bank (issue 63).

The synthesis' mouth is a blend of K shots stretched to the target's lips; beyond the shots it opens too little,
and inside it the driver's teeth and cavity are laid in (``landmarks.parts.mouth.interior``), lit as this person but
another person's teeth. The source's own frames show this person's lips, teeth and cavity in many states. So every
frame of the source is indexed, and each output frame takes its mouth from one real frame of the person:

* ``build_mouth_bank``: per source frame, the mouth cut in its own frame (``mouth_affine``: the corners levelled,
  ``CANON_WIDTH`` pixels apart, ``PATCH`` pixels around their midpoint), with its 20 lip points there and the
  head's yaw and pitch;
* ``MouthBankTrack``: per output frame, the entry whose lips, in the mouth's own frame, lie nearest the target's
  (``shape_cost``: the opening weighs most) and whose head turns alike, kept and cross-faded by
  ``landmarks.parts.hysteresis``. A target whose opening no entry shows (``TOLERANCE``) takes none: the driver's
  interior laid in before stands;
* ``paste_bank_mouth``: the entry's lips mapped onto the target's by a thin-plate spline through their 20 points
  (``landmarks.warp.tps``; the inner lips, and the opening between them, land on the target's), lit as the skin around it (``match_light``) and laid in under the
  mouth's feathered region (``landmarks.parts.mouth.nearest_mouth.mouth_weight``: the outer lips grown a little).

numpy + OpenCV only (the inference core's rule): both runtimes share it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import cv2
import numpy as np

from landmarks.parts.eyes.eye_bank import head_turn
from landmarks.parts.bank_rows import BankRows, usable_face
from landmarks.parts.hysteresis import EntryTrack
from landmarks.parts.eyes.driver_lids import similarity
from landmarks.shape.expression import mouth_opening
from landmarks.parts.mouth.interior import LIPS, lip_affine
from landmarks.shape.measures import finite_points
from landmarks.parts.lay_in import match_light
from landmarks.parts.mouth.nearest_mouth import mouth_weight
from landmarks.shape.measures import inter_ocular_distance

CANON_WIDTH = 48.0
"""The mouth's width (corner to corner) in the bank's patches, in pixels."""
PATCH = (96, 96)
"""A bank patch's (width, height) in pixels, centred between the mouth's corners: a yawn's lips and the skin
around them."""
CORNERS = (48, 54)
"""The mouth's corners of the 68 points (image left first)."""
INNER = slice(12, 20)
"""The inner lips among the 20 lip points."""
SCALES = {"opening": 0.01, "lips": 3.0, "inner": 1.5, "yaw": 10.0, "pitch": 10.0}
"""How far apart two states are (``shape_cost``): the mouth opening (``landmarks.shape.expression.mouth_opening``, inter-ocular
distances: what the eye reads first), the outer lips' and the inner lips' RMS distance in the mouth's own frame
(pixels at ``CANON_WIDTH``: an "O" or a smile), and the head's turn in degrees, each over its scale, squared,
summed."""
TOLERANCE = (0.015, 0.25)
"""An entry whose opening differs from the target's by more than the first, and by more than the second share of the
target's, is never shown: its lips stretched to the target's would show a shut mouth wide open, or the reverse.
Where no entry is near enough, the bank gives none and the steps before stand (the driver's interior)."""
SMOOTHING = 0.01
"""The lip spline's regularisation (``landmarks.warp.tps.fit_tps``; unit-spread coordinates): a shut mouth's inner lips
meet, and the spline bends smoothly rather than through them exactly."""
MIN_WIDTH = 8.0
"""A frame whose mouth is narrower than this many pixels is not banked."""


@dataclasses.dataclass(frozen=True)
class MouthBank:
    """A person's mouths, indexed (module docstring). N entries."""

    patches: np.ndarray
    """(N, PATCH[1], PATCH[0], 3) uint8 RGB: each entry's mouth in the mouth's own frame."""
    lips: np.ndarray
    """(N, 20, 2) float64: each entry's lip points (48-67) in its patch's pixels."""
    openings: np.ndarray
    """(N,) float64: each entry's mouth opening (``landmarks.shape.expression.mouth_opening``)."""
    poses: np.ndarray
    """(N, 2) float64: the head's yaw and pitch in degrees (``eye_bank.head_turn``)."""

    def __post_init__(self) -> None:
        n = len(self.patches)
        if self.patches.shape[1:] != (PATCH[1], PATCH[0], 3) or self.patches.dtype != np.uint8:
            raise ValueError(f"patches must be (N, {PATCH[1]}, {PATCH[0]}, 3) uint8, got {self.patches.shape}")
        if self.lips.shape != (n, 20, 2) or self.openings.shape != (n,) or self.poses.shape != (n, 2):
            raise ValueError("a mouth bank's lips, openings and poses must hold one row per patch")

    def __len__(self) -> int:
        return len(self.patches)


def mouth_affine(landmarks: np.ndarray) -> np.ndarray:
    """The (2, 3) similarity taking image pixels to the mouth's own frame: the corners (``CORNERS``) of (68, 2)
    points level, ``CANON_WIDTH`` apart, around the centre of a ``PATCH`` (``landmarks.parts.eyes.driver_lids.similarity``)."""
    corners = np.asarray(landmarks, np.float64)[list(CORNERS)]
    if not np.hypot(*(corners[1] - corners[0])) > 0:
        raise ValueError("the mouth's corners must be apart")
    centre = np.array([PATCH[0] / 2.0, PATCH[1] / 2.0])
    return similarity(corners, centre + [[-CANON_WIDTH / 2.0, 0.0], [CANON_WIDTH / 2.0, 0.0]])


def own_lips(landmarks: np.ndarray) -> np.ndarray:
    """(20, 2) the lip points of (68, 2) points in the mouth's own frame (``mouth_affine``)."""
    points = np.asarray(landmarks, np.float64)
    matrix = mouth_affine(points)
    return points[LIPS] @ matrix[:, :2].T + matrix[:, 2]


def mouth_row(frame: np.ndarray, points: np.ndarray | None, turn: np.ndarray | None = None) -> tuple | None:
    """One frame's entry of a mouth bank: (patch, own lips, opening, head turn), or None where it has no face or its
    mouth is narrower than ``MIN_WIDTH`` (``build_mouth_bank``). turn: the face's ``head_turn`` when the caller has
    it already (the eye bank's row of the same frame)."""
    face = usable_face(frame, points)
    if face is None or np.hypot(*(face[1][CORNERS[1]] - face[1][CORNERS[0]])) < MIN_WIDTH:
        return None
    frame, points = face
    patch = cv2.warpAffine(frame, mouth_affine(points), PATCH, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return patch, own_lips(points), float(mouth_opening(points)), head_turn(points) if turn is None else turn


def mouth_bank_of(rows: list[tuple]) -> MouthBank | None:
    """``mouth_row``s -> ``MouthBank`` (None for no rows)."""
    if not rows:
        return None
    patches, lips, openings, poses = zip(*rows)
    return MouthBank(np.stack(patches), np.stack(lips), np.asarray(openings, np.float64), np.stack(poses))


def build_mouth_bank(faces: Iterable[tuple[np.ndarray, np.ndarray | None]], max_entries: int = 600
                     ) -> MouthBank | None:
    """The mouth bank of a person's frames, read one at a time: (frame (H, W, 3) uint8 RGB, its 68 points (frame
    pixels; None or NaN: no face, skipped)) -> ``MouthBank``, or None when no frame has a mouth at least
    ``MIN_WIDTH`` pixels wide. At most ``max_entries`` entries, evenly spread over the frames."""
    rows = BankRows(max_entries)
    for frame, points in faces:
        rows.add(mouth_row(frame, points))
    return mouth_bank_of(rows.spread())


def shape_cost(bank: MouthBank, lips: np.ndarray, opening: float, pose: np.ndarray) -> np.ndarray:
    """(N,) how far each entry's mouth lies from the target's: its lips (20, 2) in the mouth's own frame, its
    opening and its yaw and pitch (2,) (``SCALES``; an unknown pose counts nothing); inf for an entry whose opening
    lies beyond ``TOLERANCE``."""
    outer = np.sqrt(((bank.lips[:, :12] - lips[:12]) ** 2).sum(-1).mean(-1)) / SCALES["lips"]
    inner = np.sqrt(((bank.lips[:, INNER] - lips[INNER]) ** 2).sum(-1).mean(-1)) / SCALES["inner"]
    apart = np.abs(bank.openings - opening)
    turn = ((bank.poses - pose) / np.array([SCALES["yaw"], SCALES["pitch"]])) ** 2
    cost = (apart / SCALES["opening"]) ** 2 + outer ** 2 + inner ** 2 + np.where(np.isfinite(turn), turn, 0.0).sum(1)
    near = (apart <= TOLERANCE[0]) | (apart <= TOLERANCE[1] * abs(opening))
    return np.where(np.isfinite(cost) & near, cost, np.inf)


@dataclasses.dataclass(frozen=True)
class MouthChoice:
    """An output frame's mouth from the bank: the entry, and the entry it fades from (with that one's weight)."""

    entry: int
    previous: int | None = None
    previous_weight: float = 0.0
    bank: MouthBank | None = dataclasses.field(default=None, compare=False, repr=False)
    """The bank it was chosen from (``MouthBankTrack``): what ``paste_bank_mouth`` lays in when given no other."""


class MouthBankTrack:
    """One driven sequence's choice of bank mouths, frame by frame (module docstring)."""

    def __init__(self, bank: MouthBank) -> None:
        self.bank = bank
        self.entries = EntryTrack()

    @property
    def switches(self) -> int:
        return self.entries.switches

    def reset(self) -> None:
        self.entries.reset()

    def __call__(self, landmarks: np.ndarray) -> MouthChoice | None:
        """The target's 68 points (its pixels) -> this frame's ``MouthChoice``, or None where no entry opens as it does
        (``TOLERANCE``) or its points are not finite."""
        points = finite_points(landmarks)
        if points is None or np.hypot(*(points[CORNERS[1]] - points[CORNERS[0]])) < 1.0:
            self.reset()
            return None
        cost = shape_cost(self.bank, own_lips(points), float(mouth_opening(points)), head_turn(points))
        if not np.isfinite(cost).any():
            self.reset()
            return None
        entry, previous, weight = self.entries(cost)
        if not np.isfinite(cost[previous if previous is not None else entry]):
            previous, weight = None, 0.0  # never fade from a mouth that opens otherwise
        return MouthChoice(entry, previous, weight, bank=self.bank)


def paste_bank_mouth(image: np.ndarray, landmarks: np.ndarray, bank: MouthBank | None, choice: MouthChoice | None
                     ) -> np.ndarray:
    """``image`` (S, S, 3) uint8, the synthesis for the target's 68 points ``landmarks`` (its pixels), with the
    chosen bank mouth laid over its own (module docstring): a new array, or ``image`` itself when there is no
    choice, the target's points are not finite or its mouth region lies outside the image. bank: None, the one the
    choice was made from."""
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    points = finite_points(landmarks)
    bank = bank if bank is not None or choice is None else choice.bank
    if bank is None or choice is None or points is None:
        return image
    region = mouth_weight(points, image.shape[:2])
    if region is None:
        return image
    weight, (x0, y0, x1, y1) = region
    local = points[LIPS] - (x0, y0)
    box = (y1 - y0, x1 - x0)
    warped = _placed(bank, choice.entry, local, box)
    if choice.previous is not None and choice.previous_weight > 0:
        warped = choice.previous_weight * _placed(bank, choice.previous, local, box) + (
            1.0 - choice.previous_weight) * warped
    result = image.copy()
    under = result[y0:y1, x0:x1].astype(np.float32)
    lips = weight > 0.5
    ring = max(1, round(0.06 * float(inter_ocular_distance(points))))
    warped = match_light(warped, under, lips, ring, cast=1.0, fade=None)
    result[y0:y1, x0:x1] = np.clip(np.rint(weight[..., None] * warped + (1.0 - weight[..., None]) * under), 0,
                                   255).astype(np.uint8)
    return result


def _placed(bank: MouthBank, entry: int, lips: np.ndarray, box: tuple[int, int]) -> np.ndarray:
    """Entry ``entry``'s mouth mapped onto the target's lips (20, 2) (box pixels): each of the box's pixels reads the
    patch where the thin-plate spline through the 20 lip pairs puts it (``SMOOTHING``), so that the inner lips, and
    the opening between them, land on the target's; the affine fit of the lips where the spline is degenerate ->
    (box[0], box[1], 3) float32."""
    from landmarks.warp.tps import DegenerateTpsError, fit_tps

    try:
        spline = fit_tps(lips, bank.lips[entry], regularization=SMOOTHING)  # box pixels -> patch pixels
    except DegenerateTpsError:
        return cv2.warpAffine(bank.patches[entry], lip_affine(lips, bank.lips[entry]), (box[1], box[0]),
                              flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
                              ).astype(np.float32)
    ys, xs = np.mgrid[0:box[0], 0:box[1]]
    where = spline.dense(np.stack([xs.ravel(), ys.ravel()], axis=1)).astype(np.float32).reshape(box[0], box[1], 2)
    return cv2.remap(bank.patches[entry], where[..., 0], where[..., 1], cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
