"""The person's own eyes, from every frame they give: an eye bank (issue 63).

A synthesised eye is a blend of K shots whose eyes disagree, stretched to a state none of them shows: on an
expressive driver its irises streak and its lids smudge grey. The source's own frames show this person's real
eyes, open, glancing and shut. So every frame of the source (every frame of a video, every photo) is indexed,
and each output frame takes its eyes from one real frame of the person, moved into place:

* ``EyeEntry`` / ``build_eye_bank``: per source frame, both eyes cut into the eye's own frame (``eye_affine``: the
  corner line levelled, ``CANON_WIDTH`` pixels corner to corner, ``PATCH`` pixels around the eyes' centre) with
  what was read there: each eye's aperture (``landmarks.shape.measures.eye_apertures``), its gaze
  (``landmarks.parts.eyes.iris.gaze_offsets``, NaN where no iris was found) and the head's yaw and pitch.
* ``EyeBankTrack``: per output frame, the entry nearest the target's state (``state_cost``), one entry for both
  eyes (their gaze and light belong together; never a blend of several entries' eyes), kept until another is
  clearly nearer and cross-faded in when it changes (``landmarks.parts.hysteresis``), so the eyes do not pop. An
  entry whose lid opening reaches the target's within ``STRETCH`` is shown where there is one; an eye opened or shut
  further than every entry shows takes the nearest extreme, its stretch bounded, and where it is shut further, the
  lids are drawn down over it afterwards (``EyeChoice.shut``; both eyes together unless the target winks, ``WINK``).
* ``paste_bank_eyes``: each chosen eye mapped onto the target's corners, its lid opening stretched toward the
  target's by at most ``STRETCH`` (its lids alone, ``LID_BAND``: not the crease, the brow or the cheek), its iris
  moved toward the target's gaze no further than this person's own eyes were seen looking (``GAZE_SPAN``), lit as
  the skin around it (``landmarks.parts.lay_in.match_light``) and laid in under the feathered ellipse of
  ``landmarks.parts.eyes.driver_lids`` (lids, crease and lash line, not the brow).

How far an output eye lies from the person's real ones is ``landmarks.parts.eyes.eye_realism``.

numpy + OpenCV only (the inference core's rule): both runtimes share it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable

import cv2
import numpy as np

from landmarks.parts.bank_rows import BankRows, usable_face
from landmarks.parts.hysteresis import EntryTrack
from landmarks.parts.eyes.driver_lids import FEATHER, RING
from landmarks.parts.lay_in import ellipse_mask
from landmarks.parts.eyes.iris import gaze_offsets
from landmarks.shape.measures import EYES, eye_apertures, eye_axes
from landmarks.shape.measures import finite_points
from landmarks.parts.lay_in import match_light
from landmarks.motion.head_pose import estimate_head_pose
from landmarks.shape.measures import inter_ocular_distance

CANON_WIDTH = 32.0
"""An eye's width (corner to corner) in the bank's patches, in pixels."""
PATCH = (72, 52)
"""A bank patch's (width, height) in pixels, centred between the eye's corners: the ellipse laid in
(``driver_lids.REGION``) and the skin ring whose light is matched, at ``CANON_WIDTH``."""
SCALES = {"aperture": 0.04, "gaze": 0.06, "yaw": 8.0, "pitch": 8.0}
"""How far apart two states are (``state_cost``): each term's difference over its scale, squared, summed. An
aperture in eye widths (open eyes read 0.25-0.35, shut 0.05-0.12), a gaze in eye widths, a pose in degrees."""
STRETCH = 1.3
"""An entry's lid opening is stretched onto the target's by at most this factor (or its inverse). On the FSTH sample
(``lsr eval --banks shots none``, K = 8, the bank the 8 shots) the nearest entry stretched at most this far, laid
over the drawn lids, left the output's eyes open where the driver's shut (judged eye correlation 0.40 -> 0.20): so
where the target shuts further, the lids are drawn over the entry's eye (``EyeChoice.shut``)."""
NEAREST = 1.1
"""An eye that no entry shows within ``STRETCH`` (opened or shut beyond every entry, or between two far apart) takes
the entries whose stretch lies within this factor of the least one's."""
GAZE_SPAN = (2.0, 98.0)
"""The iris of a bank eye is moved toward the target's gaze only within the gazes the person's own eyes show: each
eye's gaze clipped to these percentiles of the bank's (``gaze_span``), never past them (an iris moved where this
person was never seen looking stretches the white on one side). On the validation people (``lsr bench eyes``,
each clip driven by the next, the "all" bank) the output eyes' realism distance went 0.87 -> 0.64 and 6.29 -> 5.00
times the real frames' for the two GRID people, whose eyes barely glance, the gaze correlation moving 0.02 -> 0.03
and 0.40 -> 0.38; with the K shots as the bank 1.55 -> 0.64 and 6.06 -> 4.46, gaze 0.45 / 0.37 / 0.29 ->
0.42 / 0.34 / 0.24. The percentiles, not the extremes, so that one misread iris does not widen the span."""
LID_BAND = (0.75, 0.25)
"""Where a bank eye's lid opening is stretched (``lid_stretch``): wholly within this share of the entry's own
aperture of the corner line (its lids and what lies between them), fading to nothing over the next this many eye
widths, so that the crease, the brow and the cheek stay where the real eye has them. The whole patch stretched put
the output eyes of the validation people (``lsr bench eyes``, the "all" bank) at 0.93 / 0.63 / 5.06 / 1.46 times the
real frames' realism distance, this at 0.76 / 0.58 / 3.94 / 1.42, the judged eye correlation 0.11 / 0.71 / 0.44 /
0.61 against 0.03 / 0.69 / 0.43 / 0.61 (the first pair's agreement is -0.04); 0.6 of the aperture moved the lids
less (0.71 -> 0.62 on real033, the eye gain 1.50 -> 1.19)."""
WINK = 0.5
"""The two eyes are shut together (``shut_beyond_entry``) unless the target's lid openings, each over its entry's,
differ by more than this: a wink. The face mesh reads the two lids of one blink apart (a lowered or turned head,
lids that never meet): in the validation drivers' blinks (an eye under 0.6 of its median opening) the two eyes'
openings over their medians differed by up to 0.5, while one eye shut wholly and the other at rest reads about 0.6
apart. Decided eye by eye, one blink was drawn with one eye shut and the other open."""
REGION = (1.0, 0.6)
"""The ellipse laid in over each eye: semi-axes along and across the corner line, in eye widths, centred between
the corners: the lids, the crease, the lash line and the skin around them, so that no synthesised lid line shows at
its edge (``landmarks.parts.eyes.driver_lids.REGION``, which lays in only shut lids, is (0.7, 0.45)). On a validation pair
(real046 driven by real015, ``/tmp``-free: ``lsr bench eyes``) the output eyes' realism distance was 0.074 with
that region and 0.041 with this one."""


@dataclasses.dataclass(frozen=True)
class EyeBank:
    """A person's eyes, indexed (module docstring). N entries, each both eyes of one source frame."""

    patches: np.ndarray
    """(N, 2, PATCH[1], PATCH[0], 3) uint8 RGB: each entry's eyes (image left first) in the eye's own frame."""
    apertures: np.ndarray
    """(N, 2) float64: each eye's lid gap over its width (``landmarks.shape.measures.eye_apertures``)."""
    gazes: np.ndarray
    """(N, 2, 2) float64: each eye's gaze (``landmarks.parts.eyes.iris.gaze_offsets``), NaN where not found."""
    poses: np.ndarray
    """(N, 2) float64: the head's yaw and pitch in degrees."""

    def __post_init__(self) -> None:
        n = len(self.patches)
        if self.patches.shape[1:] != (2, PATCH[1], PATCH[0], 3) or self.patches.dtype != np.uint8:
            raise ValueError(f"patches must be (N, 2, {PATCH[1]}, {PATCH[0]}, 3) uint8, got {self.patches.shape}")
        if self.apertures.shape != (n, 2) or self.gazes.shape != (n, 2, 2) or self.poses.shape != (n, 2):
            raise ValueError("an eye bank's apertures, gazes and poses must hold one row per patch")

    def __len__(self) -> int:
        return len(self.patches)

    @property
    def least_aperture(self) -> np.ndarray:
        """(2,) each eye's least aperture in the bank: how far shut this person's frames show it."""
        return np.nanmin(self.apertures, axis=0)


def eye_affine(corners: np.ndarray, size: tuple[int, int] = PATCH) -> np.ndarray:
    """The (2, 3) affine taking image pixels to an eye's own frame: the corners (2, 2) (image-left corner first) onto
    the patch's centre line, ``CANON_WIDTH`` apart, around the centre of a patch of ``size`` (width, height)."""
    corners = np.asarray(corners, np.float64)
    along = corners[1] - corners[0]
    width = float(np.hypot(*along))
    if not width > 0:
        raise ValueError("an eye's corners must be apart")
    unit = along / width
    across = np.array([-unit[1], unit[0]])  # down in the image for a level eye
    scale = CANON_WIDTH / width
    linear = np.stack([unit * scale, across * scale])  # (2, 2): image offsets -> patch offsets
    centre = corners.mean(axis=0)
    shift = np.array([size[0] / 2.0, size[1] / 2.0]) - linear @ centre
    return np.hstack([linear, shift[:, None]])


def eye_corners(landmarks: np.ndarray) -> np.ndarray:
    """(2, 2, 2): each eye's two corners (image left first, ``landmarks.shape.measures.EYES``) of (68, 2) points."""
    return np.stack([np.asarray(landmarks, np.float64)[[first, last]] for first, last, _ in EYES])


def cut_eyes(frame: np.ndarray, landmarks: np.ndarray, size: tuple[int, int] = PATCH) -> np.ndarray:
    """Both eyes of ``frame`` (H, W, 3) uint8 with 68 points ``landmarks`` in its pixels, each in its own frame
    (``eye_affine``) -> (2, size[1], size[0], 3) uint8 (bilinear, the frame's edge replicated)."""
    return np.stack([cv2.warpAffine(frame, eye_affine(corners, size), size, flags=cv2.INTER_AREA
                                    if _width(corners) > 2 * CANON_WIDTH else cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE) for corners in eye_corners(landmarks)])


def _width(corners: np.ndarray) -> float:
    return float(np.hypot(*(corners[1] - corners[0])))


def head_turn(landmarks: np.ndarray) -> np.ndarray:
    """(2,) yaw and pitch in degrees of finite (68, 2) points, read in the face's own crop (``POSE_CROP``), so that a
    full frame's face and a crop's read alike."""
    from landmarks.align import crop_transform, transform_landmarks

    points = np.asarray(landmarks, np.float64)
    crop = transform_landmarks(points, crop_transform(points, POSE_CROP))
    return np.asarray(estimate_head_pose(crop, (POSE_CROP, POSE_CROP))[:2], np.float64)


POSE_CROP = 256


def eye_state(landmarks: np.ndarray, irises: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a face's eyes show: 68 points (its pixels) and its irises ((2, 4) ``landmarks.parts.eyes.iris.find_irises`` rows,
    or None) -> (apertures (2,), gazes (2, 2), yaw and pitch (2,))."""
    points = np.asarray(landmarks, np.float64)
    gazes = np.full((2, 2), np.nan) if irises is None else gaze_offsets(np.asarray(irises, np.float64), points)
    return eye_apertures(points), gazes, head_turn(points)


def eye_row(frame: np.ndarray, points: np.ndarray | None, irises: np.ndarray | None) -> tuple | None:
    """One frame's entry of an eye bank: (patches, apertures, gazes, head turn), or None where it has no face or an
    eye is under 4 pixels wide (``build_eye_bank``)."""
    face = usable_face(frame, points)
    if face is None or min(_width(c) for c in eye_corners(face[1])) < 4.0:
        return None
    return (cut_eyes(*face), *eye_state(face[1], irises))


def eye_bank_of(rows: list[tuple]) -> EyeBank | None:
    """``eye_row``s -> ``EyeBank`` (None for no rows)."""
    if not rows:
        return None
    patches, apertures, gazes, poses = (np.stack(column) for column in zip(*rows))
    return EyeBank(patches, apertures, gazes, poses)


def build_eye_bank(faces: Iterable[tuple[np.ndarray, np.ndarray | None, np.ndarray | None]], max_entries: int = 600
                   ) -> EyeBank | None:
    """The eye bank of a person's frames, read one at a time: (frame (H, W, 3) uint8 RGB, its 68 points (frame
    pixels; None or NaN: no face, skipped), its irises ((2, 4) ``landmarks.parts.eyes.iris.find_irises`` rows, or None)) ->
    ``EyeBank``, or None when no frame has a face whose eyes are at least 4 pixels wide. At most ``max_entries``
    entries, evenly spread over the frames."""
    rows = BankRows(max_entries)
    for frame, points, irises in faces:
        rows.add(eye_row(frame, points, irises))
    return eye_bank_of(rows.spread())


def gaze_span(bank: EyeBank) -> np.ndarray:
    """(2, 2) each eye's (least, most) gaze along its corner line that the bank's entries show (``GAZE_SPAN``'s
    percentiles; NaN where no entry's iris of that eye was read)."""
    along = bank.gazes[:, :, 0]
    span = np.full((2, 2), np.nan)
    for eye in range(2):
        known = along[np.isfinite(along[:, eye]), eye]
        if known.size:
            span[eye] = np.percentile(known, GAZE_SPAN)
    return span


def state_cost(bank: EyeBank, apertures: np.ndarray, gazes: np.ndarray | None, pose: np.ndarray) -> np.ndarray:
    """(N,) how far each entry's state lies from the target's: apertures (2,), gazes (2, 2) or None (not asked),
    yaw and pitch (2,) (``SCALES``). A gaze term counts only where both gazes are known; an entry's unknown
    aperture or pose costs as much as a far one."""
    cost = (((bank.apertures - apertures) / SCALES["aperture"]) ** 2).sum(axis=1)
    pose_terms = ((bank.poses - pose) / np.array([SCALES["yaw"], SCALES["pitch"]])) ** 2
    cost = cost + np.where(np.isfinite(pose_terms), pose_terms, 0.0).sum(axis=1)
    if gazes is not None:
        gaze_terms = ((bank.gazes - gazes) / SCALES["gaze"]) ** 2  # (N, 2, 2)
        cost = cost + np.where(np.isfinite(gaze_terms), gaze_terms, 0.0).sum(axis=(1, 2))
    return np.where(np.isfinite(cost), cost, np.inf)


@dataclasses.dataclass(frozen=True)
class EyeChoice:
    """An output frame's eyes from the bank: the entry, and the entry it fades from (with that one's weight)."""

    entry: int
    previous: int | None = None
    previous_weight: float = 0.0
    eyes: tuple[bool, bool] = (True, True)
    """Which eyes (image left first) take the bank's: False where the bank has no reading of it, or where no one entry
    shows both eyes' openings and the other eye's is shown."""
    apertures: tuple[float, float] = (math.nan, math.nan)
    """The apertures asked of each eye (``EyeBankTrack.asked``), which its lid opening is stretched toward."""
    gazes: tuple[float, float] = (math.nan, math.nan)
    """Where each iris is moved, along the corner line in eye widths (the target's gaze within the bank's
    ``gaze_span``; NaN: left where it is)."""
    shut: tuple[bool, bool] = (False, False)
    """Which eyes the target shuts further than the entry's lids stretch (``STRETCH``; both together unless a wink,
    ``shut_beyond_entry``): the bank has no eye that shut, so the lids are drawn down over the entry's
    (``lsr.core.finish.finish_parts``)."""
    bank: EyeBank | None = dataclasses.field(default=None, compare=False, repr=False)
    """The bank it was chosen from (``EyeBankTrack``): what ``paste_bank_eyes`` lays in when given no other."""


class EyeBankTrack:
    """One driven sequence's choice of bank entries, frame by frame (hysteresis and cross-fade; module docstring).

    reference: the subject's face at rest ((68, 2), the anchor shot's), where the target's lids were retargeted
    from a driver (relative motion): its small lid motions were multiplied for the warps (``landmarks.parts.eyes.lids``'
    ``lid_share``), and a real eye follows the driver's own (``driver_share``). None: the target's lids as they
    are."""

    def __init__(self, bank: EyeBank, reference: np.ndarray | None = None) -> None:
        self.bank = bank
        self.reference = None if reference is None else finite_points(reference)
        self.entries = EntryTrack()
        self.gaze_span = gaze_span(bank)

    @property
    def switches(self) -> int:
        """How often the entry changed."""
        return self.entries.switches

    def reset(self) -> None:
        """A gap in the face (no target): the next frame chooses afresh."""
        self.entries.reset()

    def asked(self, points: np.ndarray) -> np.ndarray:
        """(2,) the apertures the target's eyes ask of a real eye: its own, or with a ``reference``, the driver's
        lid motion undone of ``lid_share``'s gain (gaps from the reference's closed gap, in proportion)."""
        from landmarks.parts.eyes.lids import closed_gaps, driver_share, lid_gaps

        apertures = eye_apertures(points)
        if self.reference is None:
            return apertures
        rest, gaps = lid_gaps(self.reference), lid_gaps(points)
        shut = closed_gaps(rest)
        with np.errstate(divide="ignore", invalid="ignore"):
            share = (gaps - shut) / np.where(rest > shut, rest - shut, np.nan)
            goal = shut + (rest - shut) * driver_share(np.maximum(share, 0.0))
            undone = apertures * goal / gaps
        return np.where(np.isfinite(undone) & (gaps > 0), undone, apertures)

    def __call__(self, landmarks: np.ndarray, gazes: np.ndarray | None = None) -> EyeChoice | None:
        """The target's 68 points (its pixels) and gaze ((2, 2) ``landmarks.parts.eyes.iris.gaze_offsets`` or None) -> this
        frame's ``EyeChoice``, or None where neither eye takes the bank's."""
        points = finite_points(landmarks)
        if points is None:
            self.reset()
            return None
        apertures = self.asked(points)
        with np.errstate(divide="ignore", invalid="ignore"):
            far = np.abs(np.log(apertures[None, :] / self.bank.apertures))  # (N, 2): how far each entry's lids stretch
        far = np.where(np.isfinite(far), far, np.inf)
        # an entry within STRETCH where there is one; for an eye opened or shut beyond every entry, or between two
        # far apart, the nearest (stretched as far as it goes: ``_placed``)
        reach = np.maximum(math.log(STRETCH), far.min(axis=0) + math.log(NEAREST)) + 1e-9
        shows = np.isfinite(far) & (far <= reach)
        eyes = shows.any(axis=0)
        if not eyes.any():
            self.reset()
            return None
        usable = shows[:, eyes].all(axis=1)
        if not usable.any():  # no one entry shows both eyes' openings: the eye that more entries show
            eyes = np.arange(2) == int(np.argmax(shows.sum(axis=0)))
            usable = shows[:, eyes].all(axis=1)
        cost = np.where(usable, state_cost(self.bank, apertures, gazes, head_turn(points)), np.inf)
        entry, previous, weight = self.entries(cost)
        shut = shut_beyond_entry(apertures, self.bank.apertures[entry], eyes)
        along = (np.full(2, np.nan) if gazes is None else np.asarray(gazes, np.float64)[:, 0])
        known = np.isfinite(self.gaze_span).all(axis=1)
        along = np.where(known, np.clip(along, self.gaze_span[:, 0], self.gaze_span[:, 1]), along)  # GAZE_SPAN
        return EyeChoice(entry, previous, weight, eyes=tuple(bool(e) for e in eyes),  # type: ignore[arg-type]
                         apertures=tuple(float(a) for a in apertures),  # type: ignore[arg-type]
                         gazes=tuple(float(g) for g in along), shut=tuple(bool(e) for e in shut),  # type: ignore
                         bank=self.bank)


def shut_beyond_entry(apertures: np.ndarray, own: np.ndarray, eyes: np.ndarray) -> np.ndarray:
    """(2,) bool: which of the ``eyes`` (2,) bool taking the bank's the target shuts further than their entry's lids
    stretch (``STRETCH``), from the apertures asked (2,) over the entry's ``own`` (2,). Both eyes go by the more shut
    of the two unless they differ by more than ``WINK``: one blink is never drawn as a wink."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.where(eyes, np.asarray(apertures, np.float64) / np.asarray(own, np.float64), np.nan)
    if np.isfinite(ratios).all() and abs(ratios[0] - ratios[1]) <= WINK:
        ratios = np.full(2, ratios.min())
    return np.asarray(eyes, bool) & (ratios < 1.0 / STRETCH)


def paste_bank_eyes(image: np.ndarray, landmarks: np.ndarray, bank: EyeBank | None, choice: EyeChoice | None
                    ) -> np.ndarray:
    """``image`` (S, S, 3) uint8, the synthesis for the target's 68 points ``landmarks`` (its pixels), with the
    chosen bank eyes laid over its own (module docstring): a new array, or ``image`` itself when there is no
    choice or the target's points are not finite. bank: None, the one the choice was made from."""
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    points = finite_points(landmarks)
    bank = bank if bank is not None or choice is None else choice.bank
    if bank is None or choice is None or points is None:
        return image
    ring = max(1, round(RING * float(inter_ocular_distance(points))))
    apertures = np.where(np.isfinite(choice.apertures), choice.apertures, eye_apertures(points))
    height, width = image.shape[:2]
    result = image.copy()
    for eye, corners in enumerate(eye_corners(points)):
        centre, along, eye_width = eye_axes(points, eye)
        if not choice.eyes[eye] or eye_width < 2.0:
            continue
        axes = (REGION[0] * eye_width, REGION[1] * eye_width)
        sigma = max(0.5, FEATHER * eye_width)
        margin = axes[0] + ring + 3 * sigma + 1
        x0, y0 = np.maximum(np.floor(centre - margin), 0).astype(int)
        x1, y1 = np.minimum(np.ceil(centre + margin) + 1, (width, height)).astype(int)
        if x1 - x0 < 2 or y1 - y0 < 2:
            continue
        box = (y1 - y0, x1 - x0)
        local = points - (x0, y0)
        warped = _placed(bank, choice.entry, eye, local, apertures[eye], choice.gazes[eye], box)
        if choice.previous is not None and choice.previous_weight > 0:
            fading = _placed(bank, choice.previous, eye, local, apertures[eye], choice.gazes[eye], box)
            warped = choice.previous_weight * fading + (1.0 - choice.previous_weight) * warped
        region = result[y0:y1, x0:x1].astype(np.float32)
        inside = ellipse_mask(centre - (x0, y0), axes, along, box)
        warped = match_light(warped, region, inside > 0.5, ring, cast=1.0, fade=None)
        weight = cv2.GaussianBlur(inside, (0, 0), sigma)[..., None]
        result[y0:y1, x0:x1] = np.clip(np.rint(weight * warped + (1.0 - weight) * region), 0, 255).astype(np.uint8)
    return result


def lid_stretch(map_y: np.ndarray, stretch: float, aperture: float) -> np.ndarray:
    """A backward map's rows in an eye's own frame (``eye_affine``: the corner line at the patch's middle row) with
    the eye's lid opening stretched by ``stretch`` within ``LID_BAND`` of the corner line (``aperture``: the eye's
    own, in eye widths), fading to the unstretched map beyond it (a smoothstep; monotonic for stretches within
    ``STRETCH`` of apertures under 0.6) -> a new float32 map, or ``map_y`` itself for no stretch."""
    if stretch == 1.0 or not np.isfinite(aperture):
        return map_y
    middle = PATCH[1] / 2.0
    offset = map_y - np.float32(middle)
    inner = LID_BAND[0] * aperture * CANON_WIDTH
    fade = np.clip((np.abs(offset) - inner) / (LID_BAND[1] * CANON_WIDTH), 0.0, 1.0)
    kept = 1.0 - (1.0 - 1.0 / stretch) * (1.0 - fade * fade * (3.0 - 2.0 * fade))
    return (middle + offset * kept).astype(np.float32)


def _placed(bank: EyeBank, entry: int, eye: int, points: np.ndarray, aperture: float, gaze: float,
            box: tuple[int, int]) -> np.ndarray:
    """Entry ``entry``'s eye ``eye`` mapped onto the target's 68 ``points`` (box pixels): by its corners, its lid
    opening stretched toward ``aperture`` within ``STRETCH`` (``lid_stretch``), its iris moved along the eye from
    where the entry looked to ``gaze`` (``landmarks.parts.eyes.iris_shift.shift_iris``; NaN: left) -> (box[0],
    box[1], 3) float32."""
    from landmarks.parts.eyes.iris_shift import shift_iris

    own = bank.apertures[entry, eye]
    stretch = float(np.clip(aperture / own, 1.0 / STRETCH, STRETCH)) if own > 0 and np.isfinite(aperture) else 1.0
    matrix = eye_affine(eye_corners(points)[eye], PATCH)  # box pixels -> patch pixels
    ys, xs = np.mgrid[0:box[0], 0:box[1]].astype(np.float32)
    map_x = (matrix[0, 0] * xs + matrix[0, 1] * ys + matrix[0, 2]).astype(np.float32)
    map_y = lid_stretch((matrix[1, 0] * xs + matrix[1, 1] * ys + matrix[1, 2]).astype(np.float32), stretch, own)
    start = bank.gazes[entry, eye, 0]
    if np.isfinite(start) and np.isfinite(gaze):
        map_x, map_y = shift_iris(map_x, map_y, points, eye, float(start), float(gaze))
    return cv2.remap(bank.patches[entry, eye], map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE
                     ).astype(np.float32)
