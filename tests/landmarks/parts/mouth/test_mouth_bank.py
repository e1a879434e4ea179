"""The person's own mouth from every frame they give (landmarks.parts.mouth.mouth_bank): what the bank holds and in which
frame, which entry a target takes and how long it keeps it, when it takes none, and where and what is pasted."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.parts.eyes.eye_bank import head_turn
from landmarks.parts.hysteresis import FADE, SWITCH
from landmarks.parts.mouth.mouth_bank import (CANON_WIDTH, PATCH, TOLERANCE, MouthBank, MouthBankTrack, MouthChoice,
                                       build_mouth_bank, mouth_affine, own_lips, paste_bank_mouth, shape_cost)
from landmarks.shape.expression import mouth_opening
from landmarks.motion.head_pose import project_canonical
from landmarks.shape.measures import inter_ocular_distance

SIDE = 160
IMAGE_SIZE = (SIDE, SIDE)
SKIN = (200, 150, 130)
LIP, CAVITY, TEETH = (185, 95, 95), (45, 15, 20), (245, 245, 240)
SMUDGE = (195, 135, 125)  # a synthesis' blurred mouth: lip-tinted skin, no cavity, no teeth
TEETH_DEPTH = 0.25
"""The upper teeth's band: this share of the inner lips' gap, down from the upper inner lip."""


def _points(gap: float = 0.0, width: float = 1.0, scale: float = 1.0, shift=(0.0, 0.0), yaw: float = 0.0,
            outer_gap: float | None = None) -> np.ndarray:
    """The canonical face (mouth about 54 pixels wide, eyes about 62 apart at scale 1), its 20 lip points rebuilt
    around the corners' midpoint: the inner lips ``gap`` eye distances apart (``mouth_opening`` reads it exactly),
    the outer lips a lip's thickness beyond them (or beyond a gap of ``outer_gap``: thinner or thicker lips), the
    corners ``width`` times as far apart as the face's (below 1: a rounder "O")."""
    points = project_canonical(yaw, 0, 0, IMAGE_SIZE, scale=scale).astype(np.float64) + shift
    eyes = float(inter_ocular_distance(points))
    start, end = points[48].copy(), points[54].copy()
    full = float(np.hypot(*(end - start)))
    unit = (end - start) / full
    down = np.array([-unit[1], unit[0]])
    centre, half, half_gap, lip = (start + end) / 2, width * full / 2, gap * eyes / 2, 0.1 * full
    outer = half_gap if outer_gap is None else outer_gap * eyes / 2

    def at(along: float, depth: float) -> np.ndarray:
        return centre + along * half * unit + depth * down

    points[48], points[54] = at(-1.0, 0.0), at(1.0, 0.0)
    for index, along, thick in zip(range(49, 54), (-0.66, -0.33, 0.0, 0.33, 0.66), (0.6, 0.9, 0.8, 0.9, 0.6)):
        points[index] = at(along, -outer - thick * lip)
    for index, along, thick in zip(range(55, 60), (0.66, 0.33, 0.0, -0.33, -0.66), (0.7, 1.0, 1.1, 1.0, 0.7)):
        points[index] = at(along, outer + thick * lip)
    points[60], points[64] = at(-0.84, 0.0), at(0.84, 0.0)
    for upper, lower, along in ((61, 67, -0.4), (62, 66, 0.0), (63, 65, 0.4)):  # the pairs mouth_opening reads
        points[upper], points[lower] = at(along, -half_gap), at(along, half_gap)
    return points


def _polygon(polygon: np.ndarray) -> np.ndarray:
    """(SIDE, SIDE) bool: a filled polygon (N, 2) of pixel points, at quarter-pixel precision."""
    mask = np.zeros(IMAGE_SIZE, np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(polygon) * 4).astype(np.int32)], 255, lineType=cv2.LINE_8, shift=2)
    return mask > 0


def _inner(points: np.ndarray) -> np.ndarray:
    return _polygon(points[60:68])


def _face(points: np.ndarray) -> np.ndarray:
    """A flat skin face with a drawn mouth: red lips inside the outer lips, a dark cavity inside the inner lips and
    a white band of upper teeth along the upper inner lip (``TEETH_DEPTH``)."""
    image = np.empty((SIDE, SIDE, 3), np.uint8)
    image[:] = SKIN
    image[_polygon(points[48:60])] = LIP
    inner = _inner(points)
    image[inner] = CAVITY
    upper, down = points[60:65], points[66] - points[62]
    image[inner & _polygon(np.vstack([upper, (upper + TEETH_DEPTH * down)[::-1]]))] = TEETH
    return image


def _smudged(points: np.ndarray) -> np.ndarray:
    """A synthesis' smudged mouth: a soft lip-tinted blot over the outer lips on skin with a seeded grain (so that
    skin pasted from the bank differs from it wherever it lands)."""
    grain = np.random.default_rng(40).normal(0.0, 4.0, (SIDE, SIDE, 1))
    blot = cv2.GaussianBlur(_polygon(points[48:60]).astype(np.float32), (0, 0), 3.0)[..., None]
    return np.clip(np.rint((1 - blot) * (np.array(SKIN) + grain) + blot * np.array(SMUDGE)), 0, 255).astype(np.uint8)


def _sample(gap: float = 0.0, width: float = 1.0, **placement) -> tuple[np.ndarray, np.ndarray]:
    """One source frame of the bank: (frame, its 68 points)."""
    points = _points(gap, width, **placement)
    return _face(points), points


def _bank(states) -> MouthBank:
    """The bank of drawn frames, one per (gap, width) state."""
    bank = build_mouth_bank(_sample(gap, width) for gap, width in states)
    assert bank is not None and len(bank) == len(states)
    return bank


def _similar(points: np.ndarray, degrees: float, scale: float, shift) -> np.ndarray:
    """The points turned by ``degrees`` and scaled about the image centre, then shifted."""
    matrix = cv2.getRotationMatrix2D((SIDE / 2, SIDE / 2), degrees, scale)
    return points @ matrix[:, :2].T + matrix[:, 2] + shift


def _far_from_the_mouth(points: np.ndarray, reach: float) -> np.ndarray:
    """(SIDE, SIDE) bool: the pixels farther than ``reach`` eye distances outside the outer lips' box."""
    margin = reach * float(inter_ocular_distance(points))
    x0, y0 = np.floor(points[48:60].min(axis=0) - margin).astype(int)
    x1, y1 = np.ceil(points[48:60].max(axis=0) + margin).astype(int) + 1
    outside = np.ones(IMAGE_SIZE, bool)
    outside[max(y0, 0):y1, max(x0, 0):x1] = False
    return outside


def _brightness(image: np.ndarray, mask: np.ndarray) -> float:
    return float(image[mask].astype(np.float64).mean())


def _contrast(image: np.ndarray, mask: np.ndarray) -> float:
    return float(image[mask].astype(np.float64).mean(axis=-1).std())


CLOSED, OPEN, ROUND = (0.0, 1.0), (0.25, 1.0), (0.25, 0.7)  # (gap, width): shut lips, an open mouth, an "O"


def _own_gap(lips: np.ndarray) -> float:
    """The inner lips' mean gap (61-63 against 67-65) of 20 lip points."""
    return float(np.abs(lips[13:16, 1] - lips[[19, 18, 17], 1]).mean())


# ---- the mouth's own frame ------------------------------------------------------------------------------------


def test_mouth_affine_levels_the_corners_canon_width_apart_around_the_patch_centre():
    points = _similar(_points(0.2), 25.0, 0.8, (3.0, -5.0))
    matrix = mouth_affine(points)
    assert matrix.shape == (2, 3)
    corners = points[[48, 54]] @ matrix[:, :2].T + matrix[:, 2]
    centre = np.array(PATCH, np.float64) / 2
    np.testing.assert_allclose(corners, [centre - (CANON_WIDTH / 2, 0.0), centre + (CANON_WIDTH / 2, 0.0)],
                               atol=1e-9)
    linear = matrix[:, :2]  # a similarity: a rotation times the scale that makes the mouth CANON_WIDTH wide
    width = float(np.hypot(*(points[54] - points[48])))
    np.testing.assert_allclose(linear @ linear.T, (CANON_WIDTH / width) ** 2 * np.eye(2), atol=1e-9)
    assert np.linalg.det(linear) > 0  # no mirror
    same = points.copy()
    same[54] = same[48]
    with pytest.raises(ValueError, match="apart"):
        mouth_affine(same)


def test_own_lips_do_not_depend_on_where_the_face_lies_how_large_it_is_or_how_it_is_turned_in_the_image():
    for state in (CLOSED, OPEN, ROUND):
        points = _points(*state)
        lips = own_lips(points)
        assert lips.shape == (20, 2) and lips.dtype == np.float64
        for degrees, scale, shift in ((30.0, 1.0, (0.0, 0.0)), (-15.0, 0.6, (7.0, -4.0)), (0.0, 1.3, (-9.0, 2.0))):
            np.testing.assert_allclose(own_lips(_similar(points, degrees, scale, shift)), lips, atol=1e-9)
    # what differs between mouths stays: an open mouth's inner lips lie apart in its own frame, an "O"'s further
    closed, opened, rounded = (own_lips(_points(*state)) for state in (CLOSED, OPEN, ROUND))
    assert _own_gap(closed) < 1e-9 and _own_gap(opened) > 10.0 and _own_gap(rounded) > 1.3 * _own_gap(opened)


# ---- the bank --------------------------------------------------------------------------------------------------


def test_the_bank_holds_each_frames_mouth_cut_level_in_its_own_frame_with_what_was_read_there():
    upright = _sample(*OPEN)
    moved_points = _similar(_points(*OPEN), 20.0, 0.8, (4.0, -6.0))  # the same mouth, turned, smaller, elsewhere
    samples = [upright, (_face(moved_points), moved_points), _sample(*CLOSED)]
    bank = build_mouth_bank(samples)
    assert isinstance(bank, MouthBank) and len(bank) == 3
    assert bank.patches.shape == (3, PATCH[1], PATCH[0], 3) and bank.patches.dtype == np.uint8
    assert bank.lips.shape == (3, 20, 2) and bank.lips.dtype == np.float64
    assert bank.openings.shape == (3,) and bank.openings.dtype == np.float64
    assert bank.poses.shape == (3, 2) and bank.poses.dtype == np.float64
    np.testing.assert_allclose(bank.openings, [0.25, 0.25, 0.0], atol=1e-9)
    for entry, (_, points) in enumerate(samples):
        np.testing.assert_allclose(bank.lips[entry], own_lips(points), atol=1e-9)
        np.testing.assert_allclose(bank.poses[entry], head_turn(points), atol=1e-9)
    np.testing.assert_allclose(bank.lips[0], bank.lips[1], atol=1e-9)
    # the mouth's own frame: the turned, smaller mouth cut as the upright one (but for resampling at its edges)
    upright_patch, moved_patch = bank.patches[0].astype(int), bank.patches[1].astype(int)
    assert np.abs(upright_patch - moved_patch).mean() < 3.0
    assert np.abs(upright_patch - bank.patches[2]).mean() > 5 * np.abs(upright_patch - moved_patch).mean()
    # the cavity at the patch centre (between the corners), the teeth just under the upper inner lip, skin around
    centre_x, centre_y = PATCH[0] // 2, PATCH[1] // 2
    upper_lip_y = float(bank.lips[0, 14, 1])  # point 62 in the patch
    teeth_y = round(upper_lip_y + TEETH_DEPTH / 2 * (bank.lips[0, 18, 1] - upper_lip_y))
    for patch in (upright_patch, moved_patch):
        assert np.abs(patch[centre_y, centre_x] - CAVITY).max() < 20
        assert np.abs(patch[teeth_y, centre_x] - TEETH).max() < 20
        assert np.abs(patch[2, 2] - SKIN).max() <= 2 and np.abs(patch[-3, -3] - SKIN).max() <= 2
    assert np.abs(bank.patches[2, centre_y + 3, centre_x].astype(int) - LIP).max() < 20  # shut: lips there


def test_a_row_given_the_head_turn_read_already_is_the_row_that_reads_it():
    from landmarks.parts.mouth.mouth_bank import mouth_row

    frame, points = _sample(*OPEN)
    own, given = mouth_row(frame, points), mouth_row(frame, points, head_turn(points))
    for mine, theirs in zip(own, given, strict=True):
        np.testing.assert_array_equal(mine, theirs)


def test_frames_without_a_face_or_with_a_mouth_too_small_are_skipped_and_none_leaves_no_bank():
    frame, points = _sample(*OPEN)
    nan_points = points.copy()
    nan_points[62] = np.nan
    tiny = _points(*OPEN, scale=0.12)  # a mouth about 6.5 pixels wide
    assert np.hypot(*(tiny[54] - tiny[48])) < 8.0
    faces = [(frame, None), (frame, points), (frame, nan_points), (_face(tiny), tiny), _sample(*CLOSED)]
    bank = build_mouth_bank(faces)
    assert len(bank) == 2
    np.testing.assert_allclose(bank.openings, [0.25, 0.0], atol=1e-9)
    assert build_mouth_bank([(frame, None), (frame, nan_points), (_face(tiny), tiny)]) is None
    assert build_mouth_bank([]) is None
    assert build_mouth_bank(iter(())) is None


def test_max_entries_spreads_evenly_over_the_frames():
    gaps = np.linspace(0.0, 0.27, 10)  # one label per frame
    bank = build_mouth_bank((_sample(gap) for gap in gaps), max_entries=4)
    assert len(bank) == 4
    np.testing.assert_allclose(bank.openings, gaps[[0, 3, 6, 9]], atol=1e-9)
    assert len(build_mouth_bank((_sample(gap) for gap in gaps[:3]), max_entries=4)) == 3
    one = build_mouth_bank((_sample(gap) for gap in gaps), max_entries=1)
    assert len(one) == 1 and one.openings[0] == pytest.approx(0.0, abs=1e-9)
    # a long video keeps every other frame as it goes: still at most max_entries, spread from the first frame on
    many = np.linspace(0.0, 0.3, 30)
    thinned = build_mouth_bank((_sample(gap) for gap in many), max_entries=3)
    assert len(thinned) == 3
    assert thinned.openings[0] == pytest.approx(0.0, abs=1e-9) and thinned.openings[-1] > 0.25
    assert (np.diff(thinned.openings) > 0).all()


def test_a_frame_that_is_not_uint8_rgb_or_a_max_entries_below_one_raises():
    frame, points = _sample(*OPEN)
    with pytest.raises(ValueError, match="uint8"):
        build_mouth_bank([(frame.astype(np.float32), points)])
    with pytest.raises(ValueError, match="uint8"):
        build_mouth_bank([(frame[..., 0], points)])
    with pytest.raises(ValueError, match="uint8"):
        build_mouth_bank([(frame[..., :2], points)])
    for bad in (0, -3):
        with pytest.raises(ValueError, match="max_entries"):
            build_mouth_bank([(frame, points)], max_entries=bad)
    with pytest.raises(ValueError):
        build_mouth_bank([(frame, points[:60])])  # not 68 points


def test_a_bank_checks_its_rows():
    bank = _bank([OPEN, CLOSED])
    with pytest.raises(ValueError, match="uint8"):
        MouthBank(bank.patches.astype(np.float32), bank.lips, bank.openings, bank.poses)
    with pytest.raises(ValueError, match="one row per patch"):
        MouthBank(bank.patches, bank.lips[:1], bank.openings, bank.poses)
    with pytest.raises(ValueError, match="one row per patch"):
        MouthBank(bank.patches, bank.lips, bank.openings, bank.poses[:, :1])


# ---- the choice -------------------------------------------------------------------------------------------------


def test_the_track_takes_the_entry_whose_lips_lie_nearest_the_targets():
    bank = _bank([CLOSED, OPEN, ROUND])
    for asked, expected in (((0.0, 1.0), 0), ((0.01, 1.0), 0), ((0.22, 1.0), 1), ((0.28, 1.0), 1),
                            ((0.25, 0.75), 2), ((0.3, 0.7), 2)):
        choice = MouthBankTrack(bank)(_points(*asked))
        assert isinstance(choice, MouthChoice)
        assert choice.entry == expected and choice.previous is None and choice.previous_weight == 0.0, asked
    # the shape, not only the opening: an "O" opened as much as the open entry takes the "O"
    rounded = _points(0.25, 0.75)
    assert np.argmin(np.abs(_bank([OPEN, ROUND]).openings - mouth_opening(rounded))) == 0
    assert MouthBankTrack(bank)(rounded).entry == 2
    # the inner lips weigh most: a target whose outer lips are the closed entry's and inner lips the open one's
    thin_lipped = _points(0.22, outer_gap=0.0)
    np.testing.assert_allclose(own_lips(thin_lipped)[:12], bank.lips[0, :12], atol=1e-9)
    assert MouthBankTrack(bank)(thin_lipped).entry == 1
    # where the face lies, how large and how turned in the image does not matter
    turned = _similar(_points(0.22), -20.0, 0.85, (5.0, 3.0))
    assert MouthBankTrack(bank)(turned).entry == 1


def test_the_track_prefers_an_entry_whose_head_turns_as_the_targets():
    # each target's lips match the other entry's a little better than the head's turn allows
    bank = build_mouth_bank([_sample(0.2, yaw=0.0), _sample(0.21, yaw=20.0)])
    assert abs(abs(bank.poses[1, 0] - bank.poses[0, 0]) - 20.0) < 3.0
    assert MouthBankTrack(bank)(_points(0.21, yaw=3.0)).entry == 0
    assert MouthBankTrack(bank)(_points(0.2, yaw=17.0)).entry == 1


# ---- hysteresis and cross-fade -----------------------------------------------------------------------------------


def _two_openings() -> MouthBank:
    return _bank([(0.14, 1.0), (0.18, 1.0)])  # near enough that either may show a target between them


def _cost(bank: MouthBank, points: np.ndarray) -> np.ndarray:
    return shape_cost(bank, own_lips(points), float(mouth_opening(points)), head_turn(points))


def test_a_small_move_toward_another_entry_keeps_the_current_one():
    bank = _two_openings()
    track = MouthBankTrack(bank)
    assert track(_points(0.14)).entry == 0
    nudged = _points(0.1605)  # now nearer entry 1, but by less than SWITCH
    cost = _cost(bank, nudged)
    assert cost.argmin() == 1 and 0 < cost[0] - cost[1] < SWITCH
    for _ in range(5):
        choice = track(nudged)
        assert choice.entry == 0 and choice.previous is None
    assert track.switches == 0
    assert MouthBankTrack(bank)(nudged).entry == 1  # a fresh track has no entry to keep


def test_a_clear_move_switches_and_cross_fades_over_fade_frames():
    track = MouthBankTrack(_two_openings())
    assert track(_points(0.14)).entry == 0
    choices = [track(_points(0.17)) for _ in range(FADE + 2)]
    assert track.switches == 1
    assert all(choice.entry == 1 for choice in choices)
    fading = choices[:FADE]
    assert all(choice.previous == 0 for choice in fading)
    weights = [choice.previous_weight for choice in fading]
    assert all(0 < weight < 1 for weight in weights) and all(np.diff(weights) < 0)
    assert all(choice.previous is None and choice.previous_weight == 0 for choice in choices[FADE:])


def test_noisy_targets_between_two_entries_switch_far_fewer_times_than_the_nearest_entry_does():
    bank = _two_openings()
    rng = np.random.default_rng(63)
    targets = [_points(gap) for gap in 0.16 + 0.0002 * rng.standard_normal(120)]  # between the two entries
    nearest = [int(_cost(bank, points).argmin()) for points in targets]
    nearest_changes = int(np.count_nonzero(np.diff(nearest)))
    track = MouthBankTrack(bank)
    entries = [track(points).entry for points in targets]
    assert nearest_changes >= 30  # without hysteresis the mouth would flicker
    assert track.switches == np.count_nonzero(np.diff(entries)) <= min(3, nearest_changes // 10)


# ---- when the bank has no mouth for the target -------------------------------------------------------------------


def test_a_target_opened_beyond_a_bank_that_never_opens_takes_none_and_the_image_stands():
    bank = _bank([(0.0, 1.0), (0.04, 1.0)])  # a source whose mouth never opens (beyond a parting of the lips)
    limit = max(0.04 + TOLERANCE[0], 0.04 / (1.0 - TOLERANCE[1]))  # the widest opening the widest entry may show
    track = MouthBankTrack(bank)
    assert track(_points(0.0)).entry == 0
    yawning = _points(0.3)
    assert track(yawning) is None
    assert track.entries.current is None  # the next frame chooses afresh
    image = _smudged(yawning)
    before = image.copy()
    assert paste_bank_mouth(image, yawning, bank, track(yawning)) is image
    np.testing.assert_array_equal(image, before)
    # a bounded stretch: a little beyond the bank's widest still takes its widest entry, no further
    assert MouthBankTrack(bank)(_points(0.05)).entry == 1
    assert MouthBankTrack(bank)(_points(0.97 * limit)).entry == 1
    assert MouthBankTrack(bank)(_points(1.03 * limit)) is None
    # a bank of shut mouths only: an opening beyond the tolerance takes none
    shut = MouthBankTrack(_bank([(0.0, 1.0)]))
    assert shut(_points(0.01)).entry == 0 and shut(_points(0.03)) is None


def test_a_single_photo_makes_a_bank():
    bank = _bank([OPEN])
    track = MouthBankTrack(bank)
    points = _points(0.22, 0.9, scale=1.1, shift=(2.0, 3.0))
    choices = [track(points) for _ in range(3)]
    assert all(choice.entry == 0 and choice.previous is None for choice in choices) and track.switches == 0
    # a shut mouth is not drawn from the photo's open one: the bank gives none, the synthesis stands
    assert track(_points(0.0)) is None and track.switches == 0
    smudged = _smudged(points)
    assert not np.array_equal(paste_bank_mouth(smudged, points, bank, choices[0]), smudged)


def test_a_frame_without_a_face_resets_the_track():
    bank = _two_openings()
    track = MouthBankTrack(bank)
    assert track(_points(0.14)).entry == 0
    assert track(np.full((68, 2), np.nan)) is None
    assert track.entries.current is None and track.entries.previous is None and track.entries.fading == 0
    # afresh: the nearest entry, though a kept entry 0 would have held against this small move; no switch, no fade
    choice = track(_points(0.1605))
    assert choice.entry == 1 and choice.previous is None and track.switches == 0
    # one non-finite point is no face either; a mouth with its corners together neither
    partial = _points(0.1)
    partial[10] = np.inf
    assert track(partial) is None and track.entries.current is None
    pinched = _points(0.1)
    pinched[54] = pinched[48]
    assert track(pinched) is None
    with pytest.raises(ValueError):
        track(np.zeros((67, 2)))


# ---- pasting ------------------------------------------------------------------------------------------------------


def test_no_choice_returns_the_image_itself_and_a_bad_image_raises():
    bank = _bank([OPEN])
    points = _points(*OPEN)
    image = _smudged(points)
    assert paste_bank_mouth(image, points, bank, None) is image
    assert paste_bank_mouth(image, points, None, MouthChoice(0)) is image
    assert paste_bank_mouth(image, np.full((68, 2), np.nan), bank, MouthChoice(0)) is image
    away = _points(*OPEN, shift=(400.0, 0.0))  # the mouth's region lies outside the image
    assert paste_bank_mouth(image, away, bank, MouthChoice(0)) is image
    with pytest.raises(ValueError, match="uint8"):
        paste_bank_mouth(image.astype(np.float32), points, bank, MouthChoice(0))
    with pytest.raises(ValueError, match="uint8"):
        paste_bank_mouth(image[..., 0], points, bank, MouthChoice(0))


@pytest.mark.parametrize("scale, shift", [(1.0, (0.0, 0.0)), (1.15, (4.0, -3.0)), (0.8, (-6.0, -10.0))])
def test_pasting_changes_only_the_mouth_and_lays_in_the_persons_real_cavity_and_teeth(scale, shift):
    bank_frame, bank_points = _sample(*OPEN)
    bank = build_mouth_bank([_sample(*CLOSED), (bank_frame, bank_points)])
    points = _points(*OPEN, scale=scale, shift=shift)  # the target's face larger or smaller, elsewhere
    smudged = _smudged(points)
    choice = MouthBankTrack(bank)(points)
    assert choice == MouthChoice(1)
    pasted = paste_bank_mouth(smudged, points, bank, choice)
    assert pasted is not smudged and pasted.dtype == np.uint8 and pasted.shape == smudged.shape
    far = _far_from_the_mouth(points, 0.4)
    assert far.mean() > 0.5
    np.testing.assert_array_equal(pasted[far], smudged[far])
    # inside the target's inner lips: the bank frame's cavity and teeth, not the smudge
    inner, bank_inner = _inner(points), _inner(bank_points)
    assert inner.sum() > 100
    wanted = _brightness(bank_frame, bank_inner)
    assert abs(_brightness(pasted, inner) - wanted) < 10
    assert abs(_brightness(smudged, inner) - wanted) > 35
    contrast = _contrast(bank_frame, bank_inner)  # white teeth over a dark cavity
    assert abs(_contrast(pasted, inner) - contrast) < 0.15 * contrast and _contrast(smudged, inner) < 0.1 * contrast
    # and in place: white teeth just under the upper inner lip, the dark cavity below them
    top, bottom = points[62], points[66]
    for share, colour in ((TEETH_DEPTH / 2, TEETH), (0.7, CAVITY)):
        x, y = np.round(top + share * (bottom - top)).astype(int)
        assert np.abs(pasted[y, x - 1:x + 2].astype(int) - colour).max() < 40, (share, colour)
    assert np.abs(smudged[inner].astype(int) - CAVITY).min() > 60  # none of it was there before


def test_a_different_opening_is_stretched_onto_the_targets_lips():
    bank_frame, bank_points = _sample(0.2)
    bank = build_mouth_bank([(bank_frame, bank_points)])
    points = _points(0.26, scale=1.1, shift=(3.0, 2.0))  # wider open than the entry: the affine fit stretches it
    pasted = paste_bank_mouth(_smudged(points), points, bank, MouthBankTrack(bank)(points))
    inner = _inner(points)
    assert abs(_brightness(pasted, inner) - _brightness(bank_frame, _inner(bank_points))) < 15


def test_a_cross_fade_lies_between_its_two_entries():
    bank = _bank([CLOSED, OPEN])
    points = _points(0.12)
    smudged = _smudged(points)
    first, second = (paste_bank_mouth(smudged, points, bank, MouthChoice(entry)).astype(float) for entry in (0, 1))
    half = paste_bank_mouth(smudged, points, bank, MouthChoice(1, previous=0, previous_weight=0.5)).astype(float)
    mouth = ~_far_from_the_mouth(points, 0.4)
    assert np.abs(half - (first + second) / 2)[mouth].max() <= 2  # rounding, and the light matched on the blend
    assert np.abs(first - second)[mouth].max() > 100
    mostly_first = paste_bank_mouth(smudged, points, bank, MouthChoice(1, previous=0, previous_weight=0.75))
    assert np.abs(mostly_first - (0.75 * first + 0.25 * second))[mouth].max() <= 2  # the weight is the previous'
    # a zero weight is no fade
    unweighted = paste_bank_mouth(smudged, points, bank, MouthChoice(1, previous=0, previous_weight=0.0))
    np.testing.assert_array_equal(unweighted, second.astype(np.uint8))
