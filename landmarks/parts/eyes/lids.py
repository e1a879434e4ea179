"""Eyes that close as the driver's do: retargeted in proportion, and warped to the aperture (issue 23: blinks).

The lids never quite meet: on a closed eye they sit on the lid's fold, still about ``LID_CLOSED`` inter-ocular
distances apart (``lid_gaps``). Two things follow.

**Warping** (``close_lids``, called by ``landmarks.warp.piecewise_affine.warp_references_mesh``). A warp that moves a shot's
lids onto a closing target's scales the whole gap between them, the visible aperture included, by the ratio of the
two gaps, so a fully closed target leaves the shot's eye half open. Warping one hold-out frame of each of the 4
validation people onto the others' meshes, the detector read 0.29-0.50 of the target's change of eye opening
where the eyes blink. So the target's upper lids are lowered first, so that the warp shows the target's
*aperture* (gap minus the closed gap c, ``closed_gaps``) rather than its gap: the shot's aperture G_s - c is
scaled onto G_t - c, which puts the target's upper lid at a gap of (G_t - c) G_s / (G_s - c). It only ever
closes: where the target's eye is as open as the shot's or wider, nothing moves. The upper lid moves, as it does
in a blink; the lower lid and everything else stay. The references share the target's face layout, so the lids
are lowered once per target, for the median gap of the shots being warped.

**Retargeting** (``lids_as_driver``, called by ``landmarks.motion.retarget_points.retarget_driving`` on the 68 points and by
``landmarks.motion.retarget_mesh.retarget_face`` on the meshes). The rest of the face takes the driver's change since
its reference frame, added; for the lids that shuts a narrow-eyed source's eye at the driver's squint and leaves
a wide-eyed one half open at the driver's blink. So each eye's aperture is the
source's own times the driver's over the driver reference's: a blink shuts any eye, and the source keeps its
eye shape.

**The driver's reference lids** (``LidReference``). The rest of the face moves relative to the driver's first
face, but its lids would make a poor reference: a first face that blinks or stares sets the level every later
eye is read against. On the FSTH sample, id00061's first face blinks (lid gap 0.051 against a median of 0.116),
so 81% of id00017's targets sat at the ``MAX_APERTURE`` cap; on the validation people, real046's first face
stares (0.165 against 0.119), which left the sources' eyes at two thirds of their aperture throughout. So the
reference lid gaps are the median of the driver's faces: a file's first ``LOOK_AHEAD`` faces are read before any
is driven (``lsr reenact`` tracks them first), and every face driven since joins them (the last
``REST_FRAMES``); a live camera has only the faces so far. ``lsr eval`` computes the same for each whole
driver (``running_reference_gaps``), so it measures what ``lsr reenact`` does. On the 12 validation sequences
(32 frames each, so the median of the whole driver; ``lsr eval --data VAL --k 8 --methods tps --weights
lsr/weights/default --cross-drivers 3``), cross-identity eye correlation 0.60 -> 0.67 and eye gain (the mean of
per-sequence slopes) 0.50 -> 0.69 (the tps baseline, driven by the same targets: 0.72 -> 0.85), mouth unchanged. Looking ahead 25 faces gave 0.64
(tps 0.81); none, as a camera does, 0.60 (0.79): a median of a few faces moves while the driver is read.

**Small lid motions** (``lid_share``). A warped lid reads at about half its motion: over the 12 cross-identity
sequences of the 4 validation people (``lsr eval --data VAL --k 8 32 --methods tps --weights lsr/weights/default
--cross-drivers 3``), the output's eye opening, as the detector reads it, moved 0.45 times as far as the driver's
(eye gain, K = 8), and where a driver's eyes barely move (a lid-gap spread of 0.002 inter-ocular distances, a tenth
of a pixel) the shots' own differences drown that motion: eye correlation 0.62 at K = 8, 0.54 at K = 32, with two
sequences near 0. So a driver's small lid motion moves the source's lids ``SMALL_LID_GAIN`` times as far, fading to
the driver's own change from a few ``SMALL_LID_SPAN`` (a share of the aperture) on, so that a blink still shuts the
eye and a wide stare is still capped: eye correlation 0.62 -> 0.74 and eye gain 0.45 -> 0.82 at K = 8, 0.54 -> 0.68
and 0.47 -> 0.78 at K = 32 (the tps baseline, driven by the same targets: 0.60 -> 0.77, 0.50 -> 0.69); mouth
correlation and gain unchanged (0.89 / 0.93 -> 0.89 / 0.94 at K = 8); self re-enactment is not retargeted. Chosen on
a first version of that run (10 sequences): a span of 0.2 gave 0.72 at K = 8 against 0.74; a plain gain of 3 0.75,
but it shut a wide-eyed source's eye at a squint, which a squeezing warp draws as a torn eye; 2 gave 0.70. The gain
centres on the driver's reference face: one that squints widens the source's eyes by at most 0.3 of their aperture.
The run without the gain: the same command under ``python -c "import sys, landmarks.parts.eyes.lids as e; e.SMALL_LID_GAIN =
1.0; from lsr.cli import main; sys.argv[0] = 'lsr'; main()" eval ...``.

The same geometry serves the mesh (``MESH_LIDS``, MediaPipe's eye contours) and the 68 points (``POINTS_68_LIDS``).
The constants are the default mesh detector's (its 68 points are mapped from the mesh, eye contours refined);
dlib's 68 points (``--detector hog``) shut at a wider gap (about 0.06 where the mesh net alone read shut, over 23
training people who blink), so a dlib driver's blink leaves the source's eyes part open: for an open gap of 0.12,
(0.06 - 0.036) / (0.12 - 0.036), about 0.3 of their aperture.

``LID_CLOSED`` = 0.04 and ``CLOSED_SHARE`` = 0.3 come from the 56 training people, their lids as the default
detector reads them, eye contours refined by the iris net (``landmarks.detect.mediapipe_mesh``, step 3b; ``lsr face-models lids
../shared/data/real_talking_heads``, 64 frames per clip): the 45 people who blink (their
smallest gap under 0.75 of their median) close to a smallest gap of 0.038 (median over them; 1st percentile of all
frames 0.027), and narrow eyes close at a smaller gap: closed / open has a median of 0.32 (quartiles 0.22-0.51). So a
face's closed gap is ``closed_gaps`` = min(0.04, ``CLOSED_SHARE`` 0.3 x its open gap). The mesh net's own lids never
meet: read without the iris net, the same frames give 0.075 and 0.61 (38 people blink; 1st percentile 0.061), which
were the constants' values (0.07, 0.6) before the refinement; the measurements below were made with them.
Measured on the 4 validation people (``lsr eval --data VAL --k 8 32``, warp-guided default), cross-identity eye
correlation:

* the warp: 0.63 -> 0.67 at K = 8, 0.51 -> 0.58 at K = 32; face PSNR in self re-enactment -0.001 / -0.003 dB,
  mouth unchanged. Also tried there: 0.09 (0.67, -0.008 dB); lowering each shot's own target (no shared
  layout): the same; opening wider too, up to 1.5 times, where the target's eye is wider than the shot's: 0.69
  but -0.008 dB;
* the retargeting on top: 0.67 -> 0.72 at K = 8, 0.58 -> 0.63 at K = 32 (mouth correlation 0.83 -> 0.82 and
  0.88 -> 0.88; self re-enactment is not retargeted).

numpy only.
"""

from __future__ import annotations

import collections
import dataclasses

import numpy as np

LID_CLOSED = 0.04
"""The lid gap of a closed eye, in inter-ocular distances (``lid_gaps``), at most (``closed_gaps``)."""
CLOSED_SHARE = 0.3
"""A closed eye's gap is at most this share of the same eye's open gap (``closed_gaps``)."""
MAX_APERTURE = 1.5  # a driver's eye opened wider than its reference's widens the source's at most this much
MIN_APERTURE = 0.02  # a driver reference with its eyes (nearly) shut: its aperture counts as this
SMALL_LID_GAIN = 3.0
"""How much further a driver's small lid motions move the source's lids (``lid_share``; module docstring)."""
SMALL_LID_SPAN = 0.35
"""The size of a lid motion, as a share of the driver's aperture, beyond which the gain fades out (``lid_share``)."""
REST_FRAMES = 250
"""How many of the driver's latest faces its lids at rest (its reference lid gaps) are the median of (``LidReference``): 10 s at 25
fps, so a long stream's reference follows its open eyes and stays cheap."""
LOOK_AHEAD = 50
"""How many of a driver file's first faces count towards its reference lids before the first is driven (2 s at
25 fps, a blink or two; ``LidReference.look_ahead``): a live camera has none."""


@dataclasses.dataclass(frozen=True)
class Lids:
    """Where a face's lids are: per eye (outer corner, inner corner, upper lid corner to corner, lower lid corner to
    corner), and which upper-lid points measure the gap (those near the corners have about none)."""

    eyes: tuple[tuple[int, int, tuple[int, ...], tuple[int, ...]], ...]
    middle: slice


MESH_LIDS = Lids(((33, 133, (246, 161, 160, 159, 158, 157, 173), (7, 163, 144, 145, 153, 154, 155)),
                  (263, 362, (466, 388, 387, 386, 385, 384, 398), (249, 390, 373, 374, 380, 381, 382))), slice(2, 5))
"""The 468-point face mesh's lids (MediaPipe's eye contours)."""
POINTS_68_LIDS = Lids(((36, 39, (37, 38), (41, 40)), (42, 45, (43, 44), (47, 46))), slice(0, 2))
"""The 68 points' lids (iBUG, 0-based)."""


def lids_of(face: np.ndarray) -> Lids:
    """The lids of a (468, >=2) mesh or (68, 2) landmarks."""
    count = np.shape(face)[0] if np.ndim(face) == 2 else -1
    if count == 468:
        return MESH_LIDS
    if count == 68:
        return POINTS_68_LIDS
    raise ValueError(f"a face must be a (468, 2 or 3) mesh or (68, 2) landmarks, got {np.shape(face)}")


def _eye_frame(points: np.ndarray, outer: int, inner: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(origin, along, across): the corners' midpoint and unit vectors along and across the corner line (NaN when
    the corners coincide: a turned head's far eye can collapse)."""
    origin = (points[outer] + points[inner]) / 2
    line = points[inner] - points[outer]
    length = float(np.linalg.norm(line))
    along = line / length if length > 1e-9 else np.full(2, np.nan)
    return origin, along, np.array([-along[1], along[0]])


def _lid_heights(points: np.ndarray, eye: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(across, upper heights, lower lid heights at the upper points): heights across the corner line, pixels."""
    outer, inner, upper, lower = eye
    origin, along, across = _eye_frame(points, outer, inner)
    upper_points, lower_points = points[list(upper)] - origin, points[list(lower)] - origin
    if not np.isfinite(along).all():
        return across, np.full(len(upper), np.nan), np.full(len(upper), np.nan)
    order = np.argsort(lower_points @ along)
    lower_at = np.interp(upper_points @ along, (lower_points @ along)[order], (lower_points @ across)[order])
    return across, upper_points @ across, lower_at


def _inter_ocular(points: np.ndarray, lids: Lids) -> float:
    (right_outer, right_inner, *_), (left_outer, left_inner, *_) = lids.eyes
    right, left = points[right_outer] + points[right_inner], points[left_outer] + points[left_inner]
    return float(np.linalg.norm(right - left) / 2)


def _measure(points: np.ndarray, lids: Lids) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Per eye (across, upper minus lower lid heights at the upper points in pixels, gap in inter-ocular distances):
    what ``lid_gaps`` reads and ``set_lid_gaps`` moves, made once. points: (N, 2) finite."""
    scale = _inter_ocular(points, lids)
    measured = []
    for eye in lids.eyes:
        across, upper, lower_at = _lid_heights(points, eye)
        gap = float(np.abs(lower_at - upper)[lids.middle].mean() / scale) if scale > 0 else float("nan")
        measured.append((across, lower_at - upper, gap))
    return measured


def lid_gaps(face: np.ndarray) -> np.ndarray:
    """Each eye's lid gap: the mean distance of the upper lid's middle points from the lower lid, across the
    corner line, over the inter-ocular distance (the corners' midpoints). (468, >=2) mesh or (68, 2) landmarks ->
    (2,) float64 (NaN when the face is not finite)."""
    lids = lids_of(face)
    points = np.asarray(face, np.float64)[:, :2]
    if not np.isfinite(points).all():
        return np.full(2, np.nan)
    return np.array([gap for _, _, gap in _measure(points, lids)])


def set_lid_gaps(face: np.ndarray, gaps: np.ndarray) -> np.ndarray:
    """The face with each upper lid moved across its eye's corner line so that ``lid_gaps`` reads ``gaps``: every
    upper-lid point keeps its share of the gap, as a blink moves it; the lower lid and the rest stay.
    (468, 2 or 3) mesh or (68, 2) landmarks, frame pixels; gaps (2,) -> the same shape, float64 (a copy; an eye
    whose gap or goal is not finite or not positive stays)."""
    lids = lids_of(face)
    moved = np.array(face, np.float64)
    points = moved[:, :2]  # a view: the lids move in place
    if not np.isfinite(points).all():
        return moved
    for eye, (across, opening, gap), goal in zip(lids.eyes, _measure(points, lids), np.asarray(gaps, np.float64)):
        if not (gap > 0 and goal >= 0 and np.isfinite(gap * goal)):
            continue
        points[list(eye[2])] += (opening * (1.0 - goal / gap))[:, None] * across[None, :]
    return moved


def closed_gaps(open_gaps: np.ndarray, closed: float = LID_CLOSED) -> np.ndarray:
    """The lid gaps of a face's eyes closed, from their gaps open: ``closed``, or ``CLOSED_SHARE`` of the open gap
    for narrow eyes (module docstring). (...) -> (...) float64."""
    return np.minimum(closed, CLOSED_SHARE * np.asarray(open_gaps, np.float64))


def close_lids(target_mesh: np.ndarray, shot_gaps: np.ndarray, closed: float = LID_CLOSED) -> np.ndarray:
    """The target mesh with each upper lid lowered so that a warp of a shot with these lid gaps shows the target's
    aperture (module docstring). target_mesh: (468, 2 or 3) frame pixels; shot_gaps: (2,) ``lid_gaps`` of the
    shots -> (468, 2 or 3) float64 (a copy; the target's own vertices where nothing closes or ``closed`` is 0)."""
    target_gaps, shot_gaps = lid_gaps(target_mesh), np.asarray(shot_gaps, np.float64)
    shut = closed_gaps(shot_gaps, closed)
    closing = (target_gaps < shot_gaps) & (shot_gaps > shut) & (target_gaps > 0) & (shut > 0)  # NaN: False
    lowered = np.maximum(target_gaps - shut, 0.0) * shot_gaps / np.where(closing, shot_gaps - shut, 1.0)
    return set_lid_gaps(target_mesh, np.where(closing, lowered, target_gaps))


def lid_share(share: np.ndarray, gain: float | None = None, span: float | None = None) -> np.ndarray:
    """The share of the source's aperture its lids take for a driver at ``share`` of its reference's: a change d =
    share - 1 becomes d + (gain - 1) d exp(-(d / span)^2), then clipped to [0, ``MAX_APERTURE``]. Small lid motions
    move ``gain`` times as far, since a warped lid reads at about half its motion (module docstring); from a few
    ``span`` on (a blink, a wide stare) the change is the driver's. Monotonic for gain < 3.24. None: the module's
    ``SMALL_LID_GAIN`` / ``SMALL_LID_SPAN`` (read at the call). (...) -> (...) float64."""
    gain = SMALL_LID_GAIN if gain is None else gain
    span = SMALL_LID_SPAN if span is None else span
    change = np.asarray(share, np.float64) - 1.0
    if span > 0:
        change = change + (gain - 1.0) * change * np.exp(-np.square(change / span))
    return np.clip(1.0 + change, 0.0, MAX_APERTURE)


def driver_share(share: np.ndarray, gain: float | None = None, span: float | None = None) -> np.ndarray:
    """The inverse of ``lid_share``: the driver's share of its reference's aperture that ``lid_share`` maps onto
    ``share`` (the smallest, where ``lid_share`` clips). A part shown as it is, not warped (``landmarks.parts.eyes.eye_bank``),
    follows the driver's own lid motion, not its small motions multiplied. (...) -> (...) float64."""
    grid = np.linspace(0.0, 2.0 * MAX_APERTURE, 1201)
    mapped = np.maximum.accumulate(lid_share(grid, gain, span))
    first = np.concatenate([[True], np.diff(mapped) > 0])  # xp must increase: a clipped run keeps its first point
    return np.interp(np.asarray(share, np.float64), mapped[first], grid[first])


def lids_as_driver(faces: np.ndarray, drivers: np.ndarray, reference_gaps: np.ndarray, source: np.ndarray,
                   closed: float = LID_CLOSED) -> np.ndarray:
    """Retargeted faces with their lids as closed as their drivers', in proportion: each eye's aperture (gap -
    ``closed``) is the source's times ``lid_share`` of the driver's over the driver reference's (the reference's
    aperture taken as at least ``MIN_APERTURE``). A blink closes any source's eye fully, and
    the source's own eye shape stays; adding the driver's change of gap, as the rest of the face is retargeted,
    half-closes a wide-eyed source's eye and shuts a narrow-eyed one at a squint.

    faces: (T, 468, 2 or 3) meshes or (T, 68, 2) landmarks, retargeted; drivers: (T, N, >=2) the driver frames
    they come from; reference_gaps: (2,) or (T, 2) the driver reference's ``lid_gaps`` (``LidReference``: the
    median of the driver's so far); source: (N, >=2), of the faces' kind -> (T, N, 2 or 3) float64 (frames with a
    non-finite face or reference gap stay as they are; all of them when the source is not finite)."""
    output = np.array(faces, np.float64)
    references = np.broadcast_to(np.asarray(reference_gaps, np.float64), (len(output), 2))
    source_gaps = lid_gaps(source)
    if not np.isfinite(source_gaps).all() or closed <= 0:
        return output
    source_shut = closed_gaps(source_gaps, closed)
    for index, (driver, gaps) in enumerate(zip(np.asarray(drivers, np.float64), references)):
        if not (np.isfinite(output[index]).all() and np.isfinite(driver).all() and np.isfinite(gaps).all()):
            continue
        driver_shut = closed_gaps(gaps, closed)
        share = (lid_gaps(driver) - driver_shut) / np.maximum(gaps - driver_shut, MIN_APERTURE)
        goal = source_shut + (source_gaps - source_shut) * lid_share(share)
        output[index] = set_lid_gaps(output[index], goal)
    return output


class LidReference:
    """The driver's reference lid gaps, robust to a blink: the median ``lid_gaps`` of the driver's faces so far
    (the last ``frames``; module docstring, "The driver's reference lids"), the faces seen ahead (``look_ahead``)
    included. One per driver and kind of face (mesh or 68 points). Call it on each driver face, in order (NaN
    faces are skipped, but counted against those seen ahead) -> (2,) float64, NaN before the first finite face."""

    def __init__(self, frames: int = REST_FRAMES) -> None:
        self._gaps: collections.deque[np.ndarray] = collections.deque(maxlen=int(frames))
        self._ahead = 0  # faces counted by look_ahead and not driven yet

    def reset(self) -> None:
        self._gaps.clear()
        self._ahead = 0

    def _add(self, driver: np.ndarray) -> None:
        gaps = lid_gaps(driver)
        if np.isfinite(gaps).all():
            self._gaps.append(gaps)

    def look_ahead(self, drivers) -> None:
        """The driver's next faces (a file's first ``LOOK_AHEAD`` frames), counted before the first is driven; the
        calls that drive them then count them no more. drivers: (n, N, >=2) or a list of faces (None: no face)."""
        for driver in drivers:
            self._ahead += 1
            if driver is not None:
                self._add(np.asarray(driver, np.float64))

    def __call__(self, driver: np.ndarray) -> np.ndarray:
        if self._ahead:
            self._ahead -= 1
        else:
            self._add(driver)
        return np.median(np.stack(self._gaps), axis=0) if self._gaps else np.full(2, np.nan)


def running_reference_gaps(drivers: np.ndarray, look_ahead: int = LOOK_AHEAD,
                           frames: int = REST_FRAMES) -> np.ndarray:
    """``LidReference`` over a whole driver at once, as ``lsr reenact`` gets it from a file (its first
    ``look_ahead`` faces seen before the first is driven): (T, N, >=2) -> (T, 2)."""
    drivers = np.asarray(drivers, np.float64)
    reference = LidReference(frames)
    reference.look_ahead(drivers[:look_ahead])
    return np.array([reference(driver) for driver in drivers], np.float64).reshape(-1, 2)
