"""The person's own eyes from every frame they give (landmarks.parts): what the bank holds, which entry a frame
takes and how long it keeps it, when it takes none, where and what is pasted, and how far an eye is from real."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from landmarks.parts.eyes.eye_bank import (CANON_WIDTH, LID_BAND, PATCH, STRETCH, WINK, EyeBank, EyeBankTrack,
                                           EyeChoice, build_eye_bank, gaze_span, head_turn, lid_stretch,
                                           paste_bank_eyes, shut_beyond_entry, state_cost)
from landmarks.parts.hysteresis import FADE, SWITCH
from landmarks.parts.eyes.eye_realism import eye_realism, realism_patches
from landmarks.shape.measures import eye_apertures, eye_axes
from landmarks.motion.head_pose import estimate_head_pose, project_canonical

SIDE = 160
IMAGE_SIZE = (SIDE, SIDE)
SKIN = (200, 150, 130)
WHITE, IRIS, PUPIL, LASH = (240, 240, 235), (60, 90, 150), (20, 20, 25), (50, 35, 30)
RINGS = (tuple(range(36, 42)), tuple(range(42, 48)))  # each eye: corner, 2 upper, corner, 2 lower


def _points(apertures=(0.3, 0.3), scale: float = 1.0, shift=(0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """The canonical face (eyes about 28 pixels wide at scale 1), each eye's lids rebuilt at ``apertures`` (lid gap
    over eye width, as ``eye_apertures`` reads it): the upper points a third and two thirds along the corner line,
    half the gap above it, the lower ones half below."""
    points = project_canonical(yaw, 0, 0, IMAGE_SIZE, scale=scale).astype(np.float64) + shift
    for ring, aperture in zip(RINGS, np.broadcast_to(np.asarray(apertures, np.float64), (2,))):
        start, end = points[ring[0]], points[ring[3]]
        width = float(np.hypot(*(end - start)))
        unit = (end - start) / width
        down = np.array([-unit[1], unit[0]])
        for upper, lower, share in ((ring[1], ring[5], 1 / 3), (ring[2], ring[4], 2 / 3)):
            on_line = start + share * (end - start)
            points[upper] = on_line - down * aperture * width / 2
            points[lower] = on_line + down * aperture * width / 2
    return points


def _lids(points: np.ndarray, eye: int, samples: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Smooth upper and lower lid curves (samples, 2) of an eye through its corners and its 6 points' gap."""
    ring = RINGS[eye]
    start, end = points[ring[0]], points[ring[3]]
    unit = (end - start) / np.hypot(*(end - start))
    down = np.array([-unit[1], unit[0]])
    half_gap = eye_apertures(points)[eye] * np.hypot(*(end - start)) / 2
    t = np.linspace(0.0, 1.0, samples)[:, None]
    bulge = np.sin(np.pi * t) / np.sin(np.pi / 3)  # meets the points at a third and two thirds along
    line = start + t * (end - start)
    return line - down * half_gap * bulge, line + down * half_gap * bulge


def _gaze_centres(points: np.ndarray, gazes: np.ndarray) -> np.ndarray:
    """(2, 2) each iris centre in pixels for gazes (2, 2) [along, across] in eye widths (``gaze_offsets``' terms)."""
    centres = []
    for eye in range(2):
        centre, along, width = eye_axes(points, eye)
        centres.append(centre + width * (gazes[eye, 0] * along + gazes[eye, 1] * np.array([-along[1], along[0]])))
    return np.array(centres)


def _face(points: np.ndarray, gazes=((0.0, 0.0), (0.0, 0.0))) -> np.ndarray:
    """A flat skin face with two drawn eyes: a white between the lids, a blue iris with a dark pupil at ``gazes``
    (hidden where the lids cover it) and a dark lash line along the upper lid."""
    gazes = np.asarray(gazes, np.float64)
    image = np.empty((SIDE, SIDE, 3), np.uint8)
    image[:] = SKIN
    for eye, iris_centre in enumerate(_gaze_centres(points, gazes)):
        upper, lower = _lids(points, eye)
        width = eye_axes(points, eye)[2]
        white = np.zeros((SIDE, SIDE), np.uint8)
        cv2.fillPoly(white, [np.round(np.vstack([upper, lower[::-1]]) * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        drawn = image.copy()
        drawn[white > 0] = WHITE
        centre = tuple(int(v) for v in np.round(iris_centre * 16))
        cv2.circle(drawn, centre, int(round(0.22 * width * 16)), IRIS, -1, cv2.LINE_AA, 4)
        cv2.circle(drawn, centre, int(round(0.09 * width * 16)), PUPIL, -1, cv2.LINE_AA, 4)
        image[white > 0] = drawn[white > 0]
        cv2.polylines(image, [np.round(upper * 16).astype(np.int32)], False, LASH, 2, cv2.LINE_AA, 4)
    return image


def _smudged(points: np.ndarray) -> np.ndarray:
    """A synthesis' smudged eyes: a soft grey blot where each eye is, no iris, no lash line, on skin with a seeded
    grain (so that skin pasted from the bank differs from it wherever it lands)."""
    grain = np.random.default_rng(40).normal(0.0, 4.0, (SIDE, SIDE, 1))
    blot = np.zeros((SIDE, SIDE), np.float32)
    for eye in range(2):
        centre, along, width = eye_axes(points, eye)
        cv2.ellipse(blot, (tuple(centre), (width, 0.35 * width), float(np.degrees(np.arctan2(along[1], along[0])))),
                    1.0, -1)
    blot = cv2.GaussianBlur(blot, (0, 0), 3.0)[..., None]
    return np.clip(np.rint((1 - blot) * (np.array(SKIN) + grain) + blot * 150.0), 0, 255).astype(np.uint8)


def _irises(points: np.ndarray, gazes) -> np.ndarray:
    """``find_irises``' (2, 4) rows for the drawn eyes: [x, y, radius, aperture]."""
    centres = _gaze_centres(points, np.asarray(gazes, np.float64))
    widths = np.array([eye_axes(points, eye)[2] for eye in range(2)])
    return np.column_stack([centres, 0.22 * widths, eye_apertures(points)])


def _sample(apertures=(0.3, 0.3), gazes=((0.0, 0.0), (0.0, 0.0)), **placement):
    """One source frame of the bank: (frame, its 68 points, its irises)."""
    points = _points(apertures, **placement)
    return _face(points, gazes), points, _irises(points, gazes)


def _bank(states) -> EyeBank:
    """The bank of drawn frames, one per (apertures, gazes) state."""
    bank = build_eye_bank(_sample(apertures, gazes) for apertures, gazes in states)
    assert bank is not None and len(bank) == len(states)
    return bank


STRAIGHT = ((0.0, 0.0), (0.0, 0.0))


def _eye_boxes_outside(points: np.ndarray, reach: float) -> np.ndarray:
    """(SIDE, SIDE) bool: the pixels farther than ``reach`` eye widths (a square) from both eyes' centres."""
    outside = np.ones(IMAGE_SIZE, bool)
    for eye in range(2):
        centre, _, width = eye_axes(points, eye)
        x0, y0 = np.floor(centre - reach * width).astype(int)
        x1, y1 = np.ceil(centre + reach * width).astype(int) + 1
        outside[max(y0, 0):y1, max(x0, 0):x1] = False
    return outside


def _eye_box(points: np.ndarray, eye: int, reach: float) -> tuple[slice, slice]:
    centre, _, width = eye_axes(points, eye)
    x0, y0 = np.floor(centre - reach * width).astype(int)
    x1, y1 = np.ceil(centre + reach * width).astype(int) + 1
    return slice(y0, y1), slice(x0, x1)


# ---- the bank ------------------------------------------------------------------------------------------------


def test_the_bank_holds_each_frames_eyes_cut_level_with_what_was_read_there():
    gazes = ((0.1, 0.0), (0.1, 0.0))
    samples = [_sample((0.3, 0.25), gazes), _sample((0.2, 0.2), STRAIGHT, scale=0.8, shift=(3.0, -4.0))]
    bank = build_eye_bank(samples)
    assert len(bank) == 2
    assert bank.patches.shape == (2, 2, PATCH[1], PATCH[0], 3) and bank.patches.dtype == np.uint8
    assert bank.apertures.shape == (2, 2) and bank.apertures.dtype == np.float64
    assert bank.gazes.shape == (2, 2, 2) and bank.gazes.dtype == np.float64
    assert bank.poses.shape == (2, 2) and bank.poses.dtype == np.float64
    np.testing.assert_allclose(bank.apertures, [[0.3, 0.25], [0.2, 0.2]], atol=1e-9)
    np.testing.assert_allclose(bank.gazes, [gazes, STRAIGHT], atol=1e-9)
    np.testing.assert_allclose(bank.poses[0], head_turn(_points((0.3, 0.25))), atol=1e-6)  # read in its own crop
    np.testing.assert_allclose(bank.poses[0], bank.poses[1], atol=1.0)  # a scaled, shifted face reads alike
    np.testing.assert_allclose(bank.least_aperture, [0.2, 0.2], atol=1e-9)
    # the eye's own frame: the straight-looking eye's pupil at the patch centre, skin in its corners, whatever the
    # face's size and place in the frame
    straight = bank.patches[1].astype(int)
    assert np.abs(straight[:, PATCH[1] // 2, PATCH[0] // 2] - PUPIL).max() < 40
    assert np.abs(straight[:, 2, 2] - SKIN).max() <= 2 and np.abs(straight[:, -3, -3] - SKIN).max() <= 2
    looking = bank.patches[0, 0].astype(int)  # its iris moved along the eye, toward the image right
    assert looking[PATCH[1] // 2, PATCH[0] // 2 + 3].sum() < looking[PATCH[1] // 2, PATCH[0] // 2 - 3].sum()


def test_frames_without_a_face_or_with_eyes_too_small_are_skipped_and_none_leaves_no_bank():
    frame, points, irises = _sample()
    nan_points = points.copy()
    nan_points[40] = np.nan
    tiny = _points(scale=0.12)  # eyes about 3 pixels wide
    assert eye_axes(tiny, 0)[2] < 4.0
    faces = [(frame, None, None), (frame, points, irises), (frame, nan_points, irises), (_face(tiny), tiny, None),
             (frame, points, None)]
    bank = build_eye_bank(faces)
    assert len(bank) == 2
    assert np.isnan(bank.gazes[1]).all() and np.isfinite(bank.gazes[0]).all()  # no irises: gaze unknown
    assert build_eye_bank([(frame, None, None), (frame, nan_points, None), (_face(tiny), tiny, None)]) is None
    assert build_eye_bank([]) is None


def test_max_entries_spreads_evenly_over_the_frames():
    apertures = np.linspace(0.1, 0.37, 10)  # one label per frame
    bank = build_eye_bank((_sample((a, a)) for a in apertures), max_entries=4)
    assert len(bank) == 4
    np.testing.assert_allclose(bank.apertures[:, 0], apertures[[0, 3, 6, 9]], atol=1e-9)
    assert len(build_eye_bank((_sample((a, a)) for a in apertures[:3]), max_entries=4)) == 3


def test_a_frame_that_is_not_uint8_rgb_raises():
    frame, points, irises = _sample()
    with pytest.raises(ValueError, match="uint8"):
        build_eye_bank([(frame.astype(np.float32), points, irises)])
    with pytest.raises(ValueError, match="uint8"):
        build_eye_bank([(frame[..., 0], points, irises)])


# ---- the choice ----------------------------------------------------------------------------------------------


def test_the_track_takes_the_entry_nearest_the_targets_aperture_and_gaze():
    by_aperture = _bank([((a, a), STRAIGHT) for a in (0.1, 0.2, 0.3)])
    for asked, expected in ((0.32, 2), (0.27, 2), (0.19, 1), (0.12, 0)):
        choice = EyeBankTrack(by_aperture)(_points((asked, asked)))
        assert isinstance(choice, EyeChoice)
        assert choice.entry == expected and choice.previous is None and choice.eyes == (True, True)
    by_gaze = _bank([((0.3, 0.3), ((g, 0.0), (g, 0.0))) for g in (-0.15, 0.0, 0.15)])
    for asked, expected in ((-0.12, 0), (0.02, 1), (0.13, 2)):
        choice = EyeBankTrack(by_gaze)(_points(), np.array([[asked, 0.0], [asked, 0.0]]))
        assert choice.entry == expected
    # an unknown gaze (a closing eye) asks nothing of the gaze
    half_known = np.array([[np.nan, np.nan], [0.13, 0.0]])
    assert EyeBankTrack(by_gaze)(_points(), half_known).entry == 2


def test_the_iris_is_moved_no_further_than_the_gazes_the_bank_shows():
    # the person's eyes were seen looking between -0.05 and 0.1 along the corner line: a target looking further
    # gets its iris moved to the nearest of those, one within them where it looks, an unknown gaze stays unknown
    bank = _bank([((0.3, 0.3), ((g, 0.0), (g, 0.0))) for g in np.linspace(-0.05, 0.1, 31)])
    span = gaze_span(bank)
    assert span.shape == (2, 2) and np.all(span[:, 0] > -0.05) and np.all(span[:, 1] < 0.1)
    np.testing.assert_allclose(span, [[-0.047, 0.097], [-0.047, 0.097]], atol=1e-9)
    asked = np.array([[-0.2, 0.0], [0.03, 0.0]])
    choice = EyeBankTrack(bank)(_points(), asked)
    assert choice.gazes == (pytest.approx(span[0, 0]), pytest.approx(0.03))
    assert np.isnan(EyeBankTrack(bank)(_points(), np.array([[np.nan, 0.0], [0.5, 0.0]])).gazes[0])
    assert EyeBankTrack(bank)(_points(), np.array([[np.nan, 0.0], [0.5, 0.0]])).gazes[1] == pytest.approx(span[1, 1])
    # a bank with no iris read leaves the target's gaze as asked (the entries' irises cannot be moved anyway)
    blind = dataclasses.replace(bank, gazes=np.full_like(bank.gazes, np.nan))
    assert np.isnan(gaze_span(blind)).all()
    assert EyeBankTrack(blind)(_points(), asked).gazes == (-0.2, 0.03)


def test_the_track_prefers_an_entry_whose_head_turns_as_the_targets():
    # each target's aperture matches the other entry's, a little nearer than the head's turn allows
    bank = build_eye_bank([_sample((0.3, 0.3), yaw=0.0), _sample((0.28, 0.28), yaw=20.0)])
    assert abs(abs(bank.poses[1, 0] - bank.poses[0, 0]) - 20.0) < 3.0
    assert EyeBankTrack(bank)(_points(0.28, yaw=3.0)).entry == 0
    assert EyeBankTrack(bank)(_points(0.3, yaw=17.0)).entry == 1


def test_one_entry_gives_both_eyes_even_when_each_eye_would_pick_another():
    # entry 0 looks to the image left with both eyes, entry 1 to the right; the target's eyes part ways, the left
    # eye a little further: both eyes come from entry 0, never one from each
    left, right = ((-0.15, 0.0), (-0.15, 0.0)), ((0.15, 0.0), (0.15, 0.0))
    bank = _bank([((0.3, 0.3), left), ((0.3, 0.3), right)])
    points = _points()
    choice = EyeBankTrack(bank)(points, np.array([[-0.16, 0.0], [0.14, 0.0]]))
    assert choice.entry == 0
    real = np.stack([realism_patches(_face(points, gazes), points) for gazes in (left, right)])
    unmoved = dataclasses.replace(choice, gazes=(np.nan, np.nan))  # the entry's own irises, where it looked
    correlations = np.einsum("ep,nep->en", realism_patches(paste_bank_eyes(_smudged(points), points, bank, unmoved),
                                                           points), real)  # (eye, entry)
    assert (correlations.argmax(axis=1) == 0).all()
    assert (correlations[:, 0] > correlations[:, 1] + 0.1).all()
    # with the target's gaze, each iris of that one entry moves where its eye looks (within MAX_SHIFT): the right
    # eye's to the right
    glancing = dataclasses.replace(choice, gazes=(-0.16, 0.05))
    moved = realism_patches(paste_bank_eyes(_smudged(points), points, bank, glancing), points)
    wanted = realism_patches(_face(points, ((-0.16, 0.0), (0.05, 0.0))), points)
    stayed = realism_patches(paste_bank_eyes(_smudged(points), points, bank, unmoved), points)
    toward, before = np.einsum("ep,ep->e", moved, wanted), np.einsum("ep,ep->e", stayed, wanted)
    assert toward[0] > 0.95 and toward[1] > before[1] + 0.05


# ---- hysteresis and cross-fade -------------------------------------------------------------------------------


def _open_and_half() -> EyeBank:
    return _bank([((0.3, 0.3), STRAIGHT), ((0.2, 0.2), STRAIGHT)])


def test_a_small_move_toward_another_entry_keeps_the_current_one():
    bank = _open_and_half()
    track = EyeBankTrack(bank)
    assert track(_points(0.3)).entry == 0
    nudged = _points(0.248)  # now nearer entry 1, but by less than SWITCH
    cost = state_cost(bank, eye_apertures(nudged), None, head_turn(nudged))
    assert cost.argmin() == 1 and 0 < cost[0] - cost[1] < SWITCH
    for _ in range(5):
        choice = track(nudged)
        assert choice.entry == 0 and choice.previous is None
    assert track.switches == 0
    # a fresh track has no entry to keep: it takes the nearest
    assert EyeBankTrack(bank)(nudged).entry == 1


def test_a_clear_move_switches_and_cross_fades_over_fade_frames():
    track = EyeBankTrack(_open_and_half())
    assert track(_points(0.3)).entry == 0
    choices = [track(_points(0.2)) for _ in range(FADE + 2)]
    assert track.switches == 1
    assert all(choice.entry == 1 for choice in choices)
    fading = choices[:FADE]
    assert all(choice.previous == 0 for choice in fading)
    weights = [choice.previous_weight for choice in fading]
    assert all(0 < weight < 1 for weight in weights) and all(np.diff(weights) < 0)
    assert all(choice.previous is None and choice.previous_weight == 0 for choice in choices[FADE:])


def test_noisy_targets_around_one_state_switch_far_fewer_times_than_the_nearest_entry_does():
    bank = _open_and_half()
    rng = np.random.default_rng(63)
    targets = [_points(a) for a in 0.25 + 0.0015 * rng.standard_normal(120)]  # between the two entries
    nearest = [int(state_cost(bank, eye_apertures(p), None, head_turn(p)).argmin())
               for p in targets]
    nearest_changes = int(np.count_nonzero(np.diff(nearest)))
    track = EyeBankTrack(bank)
    entries = [track(p).entry for p in targets]
    assert nearest_changes >= 30  # without hysteresis the eyes would flicker
    assert track.switches == np.count_nonzero(np.diff(entries)) <= min(3, nearest_changes // 10)


# ---- when the bank has no eye for the target ----------------------------------------------------------------


def test_a_target_shut_beyond_a_bank_of_open_eyes_takes_its_least_open_entry_marked_shut():
    bank = _bank([((0.3, 0.3), STRAIGHT), ((0.25, 0.25), STRAIGHT)])  # a source whose eyes are never shut
    least = 0.25
    track = EyeBankTrack(bank)
    assert track(_points(0.3)).entry == 0 and track(_points(0.3)).shut == (False, False)
    # beyond every entry: the nearest extreme (its stretch bounded), its lids to be drawn over it (finish_parts)
    choice = EyeBankTrack(bank)(_points(0.1))
    assert choice.entry == 1 and choice.eyes == (True, True) and choice.shut == (True, True)
    assert EyeBankTrack(bank)(_points(0.95 * least)).shut == (False, False)
    assert EyeBankTrack(bank)(_points(1.05 * least / STRETCH)).shut == (False, False)
    assert EyeBankTrack(bank)(_points(0.95 * least / STRETCH)).shut == (True, True)
    # opened beyond every entry: the widest entry, stretched as far as it goes; nothing drawn over it
    wide = EyeBankTrack(bank)(_points(0.6))
    assert wide.entry == 0 and wide.shut == (False, False)
    # one eye shut: that eye is marked, the other not
    winking = EyeBankTrack(bank)(_points((0.1, 0.3)))
    assert winking.eyes == (True, True) and winking.shut == (True, False)


def test_one_blink_read_apart_shuts_both_eyes_and_a_wink_one():
    bank = _bank([((0.3, 0.3), STRAIGHT), ((0.25, 0.25), STRAIGHT)])
    # the mesh reads a lowered head's blink as one eye at 0.44 of the entry's opening, the other at 0.92: both shut,
    # not one eye shut and the other open
    blink = EyeBankTrack(bank)(_points((0.11, 0.23)))
    assert blink.entry == 1 and blink.shut == (True, True)
    assert shut_beyond_entry(np.array([0.11, 0.23]), np.array([0.25, 0.25]), np.array([True, True])).tolist() == [
        True, True]
    # apart by more than WINK: a wink, the open eye left open
    apart = 0.25 * (1.0 / STRETCH - 0.05 + WINK + 0.02)
    assert shut_beyond_entry(np.array([0.25 * (1.0 / STRETCH - 0.05), apart]), np.array([0.25, 0.25]),
                             np.array([True, True])).tolist() == [True, False]
    # both within the stretch: neither; an eye that takes no bank eye is never shut, nor sets the other's
    assert not shut_beyond_entry(np.array([0.21, 0.25]), np.array([0.25, 0.25]), np.array([True, True])).any()
    one = shut_beyond_entry(np.array([0.05, 0.25]), np.array([0.25, 0.25]), np.array([False, True]))
    assert one.tolist() == [False, False]


def test_no_reading_of_an_eye_in_the_bank_takes_no_bank_eye():
    def bank_of(apertures) -> EyeBank:
        return EyeBank(np.zeros((1, 2, PATCH[1], PATCH[0], 3), np.uint8), np.array([apertures], np.float64),
                       np.full((1, 2, 2), math.nan), np.zeros((1, 2)))

    assert EyeBankTrack(bank_of((math.nan, math.nan)))(_points(0.3)) is None
    half = EyeBankTrack(bank_of((math.nan, 0.3)))(_points(0.1))
    assert half.eyes == (False, True) and half.shut == (False, True)


def test_the_lids_are_drawn_over_a_bank_eye_the_target_shuts_further_than_the_bank_shows():
    from types import SimpleNamespace

    from landmarks.parts.eyes.drawn_lids import draw_lids
    from lsr.core.finish import finish_parts

    from landmarks.parts.eyes.lids import lid_gaps

    bank = _bank([((0.3, 0.3), STRAIGHT), ((0.25, 0.25), STRAIGHT)])
    subject = SimpleNamespace(lid_gaps=lid_gaps(_points(0.3)), shots=SimpleNamespace(landmarks=None))
    settings = SimpleNamespace(mouth="blend", mouth_interior="shots", lids="drawn", eyes="warped")
    winking = _points((0.05, 0.3))
    choice = EyeBankTrack(bank)(winking)
    assert choice.shut == (True, False)
    drawn = _smudged(winking)
    finished = finish_parts(drawn, settings, {}, winking, subject, None, None, None, choice, None)
    pasted = paste_bank_eyes(draw_lids(drawn, winking, subject.lid_gaps), winking, bank, choice)
    left, right = _eye_box(winking, 0, 0.5), _eye_box(winking, 1, 0.5)
    # the shut eye: the bank's eye with the lids drawn down over it again; the open one: the bank's eye alone
    np.testing.assert_array_equal(finished[left], draw_lids(pasted, winking, subject.lid_gaps, (True, False))[left])
    assert np.abs(finished[left].astype(int) - pasted[left]).max() > 30
    np.testing.assert_array_equal(finished[right], pasted[right])


def test_a_single_photo_makes_a_bank():
    bank = _bank([((0.28, 0.28), STRAIGHT)])
    track = EyeBankTrack(bank)
    points = _points((0.22, 0.33), scale=1.1, shift=(2.0, 3.0))
    choices = [track(points) for _ in range(3)]
    assert all(choice.entry == 0 and choice.previous is None for choice in choices) and track.switches == 0
    drawn = _smudged(points)
    assert not np.array_equal(paste_bank_eyes(drawn, points, bank, choices[0]), drawn)


def test_a_choice_is_pasted_from_the_bank_it_was_chosen_from():
    # a reenactor whose bank setting changes mid-stream must not paste entry 1 of another, smaller bank
    bank, other = _open_and_half(), _bank([((0.3, 0.3), STRAIGHT)])
    points = _points(0.2)
    choice = EyeBankTrack(bank)(points)
    assert choice.entry == 1 and choice.bank is bank
    drawn = _smudged(points)
    np.testing.assert_array_equal(paste_bank_eyes(drawn, points, None, choice),
                                  paste_bank_eyes(drawn, points, bank, choice))
    assert not np.array_equal(paste_bank_eyes(drawn, points, None, choice), drawn)
    assert paste_bank_eyes(drawn, points, None, dataclasses.replace(choice, bank=None)) is drawn
    assert len(other) == 1  # given explicitly, another bank is the caller's to match


def test_a_frame_without_a_face_resets_the_track():
    bank = _open_and_half()
    track = EyeBankTrack(bank)
    assert track(_points(0.3)).entry == 0
    assert track(np.full((68, 2), np.nan)) is None
    assert track.entries.current is None and track.entries.previous is None and track.entries.fading == 0
    # afresh: the nearest entry, though a kept entry 0 would have held against this small move; no switch, no fade
    choice = track(_points(0.248))
    assert choice.entry == 1 and choice.previous is None and track.switches == 0


# ---- pasting ---------------------------------------------------------------------------------------------------


def test_no_choice_returns_the_image_itself_and_a_bad_image_raises():
    bank = _open_and_half()
    points = _points()
    image = _smudged(points)
    assert paste_bank_eyes(image, points, bank, None) is image
    assert paste_bank_eyes(image, points, None, EyeChoice(0)) is image
    assert paste_bank_eyes(image, np.full((68, 2), np.nan), bank, EyeChoice(0)) is image
    with pytest.raises(ValueError, match="uint8"):
        paste_bank_eyes(image.astype(np.float32), points, bank, EyeChoice(0))


def test_pasting_changes_only_the_eyes_and_lays_in_the_persons_real_eye():
    states = [((0.3, 0.3), ((0.1, 0.0), (-0.1, 0.0))), ((0.2, 0.2), STRAIGHT)]  # entry 0's eyes look inward
    bank = _bank(states)
    points = _points(0.3, scale=1.15, shift=(4.0, -3.0))  # the target's face elsewhere and larger than the bank's
    smudged = _smudged(points)
    choice = EyeBankTrack(bank)(points, np.array(states[0][1]))
    assert choice.entry == 0
    pasted = paste_bank_eyes(smudged, points, bank, choice)
    assert pasted is not smudged and pasted.dtype == np.uint8 and pasted.shape == smudged.shape
    outside = _eye_boxes_outside(points, 1.5)
    np.testing.assert_array_equal(pasted[outside], smudged[outside])
    for eye, pupil in enumerate(_gaze_centres(points, np.array(states[0][1]))):
        x, y = np.round(pupil).astype(int)
        assert np.abs(pasted[y, x].astype(int) - PUPIL).max() < 50  # each eye's pupil where the smudge was
    # against the person's real eyes, the pasted eyes are nearly real and the smudge is not
    real = np.stack([realism_patches(_face(_points(a), g), _points(a)) for a, g in states])
    pasted_distance = eye_realism(realism_patches(pasted, points)[None], real)
    smudged_distance = eye_realism(realism_patches(smudged, points)[None], real)
    assert (pasted_distance < 0.05).all()
    assert (smudged_distance > 4 * pasted_distance + 0.1).all()


def test_a_cross_fade_lies_between_its_two_entries():
    bank = _bank([((0.3, 0.3), ((-0.15, 0.0), (-0.15, 0.0))), ((0.3, 0.3), ((0.15, 0.0), (0.15, 0.0)))])
    points = _points()
    smudged = _smudged(points)
    first, second = (paste_bank_eyes(smudged, points, bank, EyeChoice(entry)).astype(float) for entry in (0, 1))
    half = paste_bank_eyes(smudged, points, bank, EyeChoice(1, previous=0, previous_weight=0.5)).astype(float)
    eyes = ~_eye_boxes_outside(points, 1.5)
    assert np.abs(half - (first + second) / 2)[eyes].max() <= 2  # rounding, and the light matched on the blend
    assert np.abs(first - second)[eyes].max() > 100


# ---- eye realism -----------------------------------------------------------------------------------------------


def test_a_bank_eye_is_stretched_at_its_lids_alone():
    """The lids and what lies between them move by the whole stretch, the crease, brow and cheek beyond LID_BAND
    stay where the real eye has them, and the map never folds over (a monotonic map of rows)."""
    middle = PATCH[1] / 2.0
    rows = np.linspace(-PATCH[1], 2 * PATCH[1], 2001, dtype=np.float32)[:, None]  # the map's rows, patch pixels
    assert lid_stretch(rows, 1.0, 0.3) is rows
    assert lid_stretch(rows, STRETCH, math.nan) is rows
    for aperture in (0.1, 0.3, 0.6):
        inner = LID_BAND[0] * aperture * CANON_WIDTH
        outer = inner + LID_BAND[1] * CANON_WIDTH
        offset = rows[:, 0] - middle
        for stretch in (STRETCH, 1.0 / STRETCH):
            moved = lid_stretch(rows, stretch, aperture)[:, 0]
            lids = np.abs(offset) <= inner
            np.testing.assert_allclose(moved[lids] - middle, offset[lids] / stretch, atol=1e-4)
            beyond = np.abs(offset) >= outer
            np.testing.assert_allclose(moved[beyond], rows[beyond, 0], atol=1e-4)
            assert (np.diff(moved) > 0).all(), (aperture, stretch)


def test_eye_realism_is_zero_for_the_same_eyes_and_rises_when_they_are_excluded():
    points = [_points(0.3), _points(0.2)]
    frames = [_face(points[0]), _face(points[1], ((0.12, 0.0), (0.12, 0.0)))]
    real = np.stack([realism_patches(frame, p) for frame, p in zip(frames, points)])  # (2, 2, P)
    assert real.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(real, axis=2), 1.0, atol=1e-5)
    distances = eye_realism(real, real)
    assert distances.shape == (2, 2) and distances.dtype == np.float64
    np.testing.assert_allclose(distances, 0.0, atol=1e-5)
    excluded = eye_realism(real, real, exclude=[[0], [1]])
    assert (excluded > 0.05).all() and (excluded <= 2.0).all()
    assert np.isnan(eye_realism(real[:1], real, exclude=[[0, 1]])).all()  # every real eye excluded


def test_eye_realism_checks_its_shapes_and_reads_unknown_eyes_as_nan():
    points = _points()
    real = realism_patches(_face(points), points)[None]
    with pytest.raises(ValueError):
        eye_realism(real, real[..., :-1])
    with pytest.raises(ValueError):
        eye_realism(real[0], real)
    unknown = realism_patches(_face(points), np.full((68, 2), np.nan))
    assert unknown.shape == real.shape[1:] and np.isnan(unknown).all()
    assert np.isnan(eye_realism(unknown[None], real)).all()
    assert np.isnan(eye_realism(real, unknown[None])).all()  # no real eye to compare with
    flat = realism_patches(np.full((SIDE, SIDE, 3), 128, np.uint8), points)  # no texture: no correlation
    assert np.isnan(flat).all()
    one_known = np.stack([real[0, 0], unknown[1]])[None]
    distances = eye_realism(one_known, real)
    assert distances[0, 0] == pytest.approx(0.0, abs=1e-5) and np.isnan(distances[0, 1])
