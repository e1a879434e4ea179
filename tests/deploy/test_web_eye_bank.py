"""The web runtime's eye bank (deploy/web/src/eye_bank.ts, hysteresis.ts, bank_rows.ts) against
landmarks.parts.eyes.eye_bank: the bank cut from the bundled source's frames as tracked, the entries a track
chooses over a made-up target sequence (the bundled driver retargeted onto the source's anchor, its lids opened,
blinked and winked, its gaze swept), the eyes laid in at those choices; and the site's bank (lsr.export.web_site),
with a site written before the bank still running without one."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from landmarks.parts.eyes.eye_bank import (
    EyeBank,
    EyeBankTrack,
    EyeChoice,
    build_eye_bank,
    paste_bank_eyes,
)
from lsr.eval.metrics import psnr

CROP = 256
SOURCE_STEP = 3  # every third frame of the bundled source makes the bank (25 entries)
NO_FACE = 4  # that bank frame's points are NaN: no face, skipped
DRIVEN = 48  # frames of the bundled driver in the made-up sequence


@pytest.fixture(scope="module")
def source_faces():
    """Every SOURCE_STEP-th frame of the bundled source (T, H, W, 3), its 68 points as the mesh tracker follows the
    clip (T, 68, 2; frame NO_FACE NaN) and its irises (T, 2, 4): what lsr.core.subject.video_part_banks reads."""
    from landmarks.detect.registry import make_tracker
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    tracker, frames, points, irises = make_tracker("mesh"), [], [], []
    for index, frame in enumerate(iter_frames(REAL_SOURCE)):
        found = tracker.update(frame)
        if index % SOURCE_STEP == 0:
            frames.append(frame)
            points.append(np.asarray(found, np.float64))
            irises.append(np.asarray(tracker.irises, np.float64))
    points = np.stack(points)
    points[NO_FACE] = np.nan
    return np.stack(frames), points, np.stack(irises)


@pytest.fixture(scope="module")
def python_bank(source_faces):
    return build_eye_bank(zip(*source_faces))


@pytest.fixture(scope="module")
def made_up():
    """(the source's anchor crop (C, C, 3), its 68 points (the subject's reference), targets (T, 68, 2) and gazes
    (T, 2, 2)): the bundled driver retargeted onto the anchor as the live session does (unsmoothed), its lids opened
    wider, half shut, blinked shut and one eye winked, one frame without a face, and a gaze swept side to side with
    a closing eye's unknown."""
    from landmarks.align import crop_transform, transform_landmarks
    from landmarks.detect.registry import make_tracker
    from landmarks.io.video import iter_frames
    from landmarks.motion.retarget_mesh import DriverReference
    from landmarks.motion.retarget_points import retarget_driving
    from landmarks.parts.eyes.lids import lid_gaps, set_lid_gaps
    from lsr.core.inputs import load_subject_shots
    from lsr.examples import REAL_DRIVER, REAL_SOURCE

    shots = load_subject_shots(REAL_SOURCE, CROP, k=8)
    anchor = shots.landmarks[shots.anchor].astype(np.float64)
    tracker, reference, targets = make_tracker("mesh"), DriverReference(), []
    for _, frame in zip(range(DRIVEN), iter_frames(REAL_DRIVER)):
        points = tracker.update(np.ascontiguousarray(frame))
        gaps, _ = reference.lids(points)
        crop_points = transform_landmarks(points, crop_transform(points, CROP))
        reference.start(crop_points)
        targets.append(retarget_driving(crop_points, reference.landmarks, anchor, gaps))
    t = np.arange(DRIVEN)
    opening = 1.0 + 0.3 * np.sin(t / 4.0)  # the lids open wider and narrow
    opening[14:17], opening[30:33] = 0.08, 0.5  # a blink: shut beyond every entry; half shut
    scales = np.stack([opening, opening], axis=1)
    scales[22:25, 0] = 0.08  # a wink: one eye shut
    targets = np.stack([set_lid_gaps(target, lid_gaps(target) * scale) for target, scale in zip(targets, scales)])
    targets[40] = np.nan  # no face
    along = 0.12 * np.sin(t / 3.0)
    gazes = np.stack([along, 0.02 * np.cos(t / 5.0)], axis=-1)[:, None, :].repeat(2, axis=1)  # (T, 2, 2)
    gazes[8:10, 1] = np.nan
    return shots.frames[shots.anchor], anchor, targets, gazes


def _wire(bank) -> dict:
    """An EyeBank as eye_bank.ts takes it."""
    return {"patches": bank.patches, "apertures": bank.apertures, "gazes": bank.gazes, "poses": bank.poses}


def _python_choices(bank, reference, targets, gazes):
    track = EyeBankTrack(bank, reference)
    return [track(target, gaze) for target, gaze in zip(targets, gazes)], track.switches


def _same_choice(got: dict | None, expected: EyeChoice | None) -> None:
    if expected is None:
        assert got is None
        return
    assert got is not None
    assert (got["entry"], got["previous"], tuple(got["eyes"]), tuple(got["shut"])) == (
        expected.entry, expected.previous, expected.eyes, expected.shut)
    assert got["previousWeight"] == pytest.approx(expected.previous_weight, abs=1e-12)
    np.testing.assert_allclose(got["apertures"], expected.apertures, rtol=1e-9)
    np.testing.assert_allclose(np.array(got["gazes"], np.float64), expected.gazes, atol=1e-12)


def test_the_bank_is_cut_and_indexed_as_python_builds_it(web, source_faces, python_bank):
    frames, points, irises = source_faces
    spread = 5  # max_entries: every other frame kept once 4 x 5 are read, then evenly spread
    got, few, none = web.calls(("buildEyeBankOfFrames", [frames, points, irises]),
                               ("buildEyeBankOfFrames", [frames, points, irises, spread]),
                               ("buildEyeBankOfFrames", [frames[:1], points[NO_FACE:NO_FACE + 1], irises[:1]]))
    assert len(python_bank) == len(frames) - 1  # the frame without a face is skipped
    assert got["patches"].shape == python_bank.patches.shape and got["patches"].dtype == np.uint8
    difference = np.abs(got["patches"].astype(int) - python_bank.patches.astype(int))
    print(f"\npatches: {np.count_nonzero(difference)} of {difference.size} values differ, by at most "
          f"{difference.max()}")
    assert difference.max() <= 1 and np.mean(difference == 0) >= 0.999  # bilinear, float weights as OpenCV 5's
    np.testing.assert_allclose(got["apertures"], python_bank.apertures, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["gazes"], python_bank.gazes, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["poses"], python_bank.poses, rtol=0, atol=0.01)  # degrees, through the head pose
    expected_few = build_eye_bank(zip(*source_faces), max_entries=spread)
    assert len(expected_few) == spread
    np.testing.assert_array_equal(few["apertures"], expected_few.apertures)
    assert none is None and build_eye_bank([(frames[0], points[NO_FACE], irises[0])]) is None


@pytest.mark.parametrize("relative", [True, False], ids=["relative", "absolute"])
def test_a_track_chooses_the_entries_python_chooses(web, python_bank, made_up, relative):
    """The choice sequence over the made-up targets, frame for frame: the entry, the one it fades from and how much,
    which eyes take the bank's and which are shut further than it shows, the openings asked (with the subject's
    reference: the driver's own lid motion)."""
    _, anchor, targets, gazes = made_up
    reference = anchor if relative else None
    bank = _wire(python_bank)
    got = web.call("eyeBankChoices", bank, reference, targets, gazes)
    expected, switches = _python_choices(python_bank, reference, targets, gazes)
    for frame, (mine, theirs) in enumerate(zip(got["choices"], expected)):
        try:
            _same_choice(mine, theirs)
        except AssertionError as error:
            raise AssertionError(f"frame {frame}: {mine} != {theirs}") from error
    assert got["switches"] == switches
    # the sequence asks for everything: switches and cross-fades, no choice (the gap); as they are (absolute), the
    # blink shuts further than the bank shows; the wink is shown by no one entry, so its shut eye keeps the
    # synthesis' drawn lids and the other takes the bank's
    chosen = [choice for choice in expected if choice is not None]
    shut = [frame for frame, choice in enumerate(expected) if choice is not None and any(choice.shut)]
    print(f"\n{len(chosen)} of {len(expected)} frames take bank eyes, {switches} switches, entries "
          f"{sorted({choice.entry for choice in chosen})}, shut further than the bank shows at {shut}")
    assert switches >= 2 and any(choice.previous is not None for choice in chosen) and expected[40] is None
    assert all(choice is not None for frame, choice in enumerate(expected) if frame != 40)
    assert all(choice.eyes == (False, True) for choice in expected[22:25])
    if not relative:
        assert expected[15].shut == (True, True)
    # the gaze sweeps past where the person's eyes were seen looking: those irises stop at the bank's span
    moved = [(choice.gazes[0], asked) for choice, asked in zip(expected, gazes[:, 0, 0]) if choice is not None]
    assert any(np.isfinite(g) and g != asked for g, asked in moved) and any(g == asked for g, asked in moved)


def test_the_eyes_are_laid_in_as_python_lays_them(web, python_bank, made_up):
    """At the track's choices (a cross-fade, one eye, irises moved to the gaze, openings stretched), on the source's
    anchor crop: within 2 grey levels (bicubic and the Gaussian feather in float32, as eyes.ts's are); the same bytes
    with the remap in WebAssembly and in JavaScript."""
    image, anchor, targets, gazes = made_up
    expected_choices, _ = _python_choices(python_bank, anchor, targets, gazes)
    frames = [frame for frame, choice in enumerate(expected_choices) if choice is not None]
    fading = [frame for frame in frames if expected_choices[frame].previous is not None][:2]
    winking = [frame for frame in frames if expected_choices[frame].eyes == (False, True)][:1]
    picked = sorted({*frames[::6], *fading, *winking})
    bank = _wire(python_bank)

    def wire(choice: EyeChoice) -> dict:
        return {"entry": choice.entry, "previous": choice.previous, "previousWeight": choice.previous_weight,
                "eyes": list(choice.eyes), "apertures": list(choice.apertures), "gazes": list(choice.gazes),
                "shut": list(choice.shut), "bank": None}

    calls = [("pasteBankEyes", [image, targets[frame], bank, wire(expected_choices[frame])]) for frame in picked]
    results = web.calls(("useWebAssembly", [False]), *calls, ("useWebAssembly", [True]), *calls)
    javascript, got = results[1:1 + len(calls)], results[2 + len(calls):]
    for first, second in zip(javascript, got):  # the bank's eyes remapped in WebAssembly: the JavaScript's bytes
        np.testing.assert_array_equal(second, first)
    scores = []
    for frame, pasted in zip(picked, got):
        expected = paste_bank_eyes(image, targets[frame], python_bank, expected_choices[frame])
        assert not np.array_equal(expected, image)
        scores.append(psnr(pasted, expected))
        assert np.abs(pasted.astype(int) - expected.astype(int)).max() <= 2, frame
    print(f"\nlaid in at frames {picked}: dB {np.round(scores, 1).tolist()}")
    assert min(scores) >= 50.0
    assert fading and winking  # the cases the choices above must include


def test_no_opening_in_the_bank_gives_no_choice_and_leaves_the_image(web, made_up, python_bank):
    """A target whose lids meet (no opening at all: no entry's stretches onto it): no choice, Python's and the
    page's, and nothing laid in."""
    image, anchor, _, _ = made_up
    shut = anchor.copy()
    for upper, lower in ((37, 41), (38, 40), (43, 47), (44, 46)):
        shut[[upper, lower]] = shut[[upper, lower]].mean(axis=0)
    bank, wire = python_bank, _wire(python_bank)
    assert EyeBankTrack(bank)(shut) is None and EyeBankTrack(bank, anchor)(shut) is None
    got = web.calls(("eyeBankChoices", [wire, anchor, shut[None], None]),
                    ("eyeBankChoices", [wire, None, shut[None], None]), ("pasteBankEyes", [image, shut, wire, None]))
    assert got[0]["choices"] == [None] and got[1]["choices"] == [None]
    np.testing.assert_array_equal(got[2], image)
    assert paste_bank_eyes(image, shut, bank, None) is image


def test_the_bank_is_written_and_read_back_as_it_was(python_bank, tmp_path):
    from lsr.export.web_site import read_eye_bank, write_eye_bank

    write_eye_bank(tmp_path, python_bank)
    back = read_eye_bank(tmp_path)
    for name in ("patches", "apertures", "gazes", "poses"):
        np.testing.assert_array_equal(getattr(back, name), getattr(python_bank, name))
    (tmp_path / "eye_bank.u8").write_bytes((tmp_path / "eye_bank.u8").read_bytes()[:-1])
    with pytest.raises(ValueError, match="export the site again"):
        read_eye_bank(tmp_path)


def test_a_bad_bank_or_image_is_one_clear_error(web, python_bank, made_up):
    image, anchor, _, _ = made_up
    short = {"patches": python_bank.patches, "apertures": python_bank.apertures[:-1], "gazes": python_bank.gazes,
             "poses": python_bank.poses}
    with pytest.raises(RuntimeError, match="one row per patch"):
        web.call("eyeBankChoices", short, None, anchor[None], None)
    with pytest.raises(RuntimeError, match=r"image must be \(H, W, 3\) uint8"):
        web.call("pasteBankEyes", image[..., 0], anchor, None, None)


# ---- the site ---------------------------------------------------------------------------------------------------


def _site_copy(site, folder, config_change=None):
    """The site in ``folder``, its files linked, without its eye bank's files; site.json changed by
    ``config_change`` (a function of the config)."""
    shutil.copytree(site.folder, folder, ignore=shutil.ignore_patterns("eye_bank.*"), copy_function=os.symlink)
    config = json.loads((site.folder / "site.json").read_text())
    (folder / "site.json").unlink()
    (folder / "site.json").write_text(json.dumps(config if config_change is None else config_change(config)))
    return folder


def test_the_session_lays_the_persons_own_eyes_in_last_as_python(site, web, python_session, tmp_path):
    """The live session at given targets (renderTargets) against Python's, on the site's bank and on a site whose
    bank holds only the example person's more open eyes: open, wider, a blink and a wink, which that bank shows no
    eye shut enough for (the lids drawn again over its eyes, as lsr.core.finish.finish_parts draws them)."""
    from landmarks.parts.eyes.lids import lid_gaps, set_lid_gaps
    from lsr.export.web_site import read_eye_bank, write_eye_bank

    bank = read_eye_bank(site.folder / "person")
    least = bank.apertures.min(axis=1)
    opened = EyeBank(*(values[least >= np.median(least)] for values in (bank.patches, bank.apertures, bank.gazes,
                                                                         bank.poses)))
    open_site = _site_copy(site, tmp_path / "open")
    write_eye_bank(open_site / "person", opened)
    session = python_session()
    reference = session.subject.reference_landmarks.astype(np.float64)
    gaps = lid_gaps(reference)
    targets = np.stack([reference, set_lid_gaps(reference, gaps * 1.3), set_lid_gaps(reference, gaps * 0.05),
                        set_lid_gaps(reference, gaps * [1.0, 0.05]), reference + [3.0, -2.0]])
    track = EyeBankTrack(opened, reference)
    shut = [choice.shut for choice in (track(target) for target in targets)]
    assert shut[2] == (True, True) and shut[3] == (False, True)
    for folder, eye_bank in ((site.folder, None), (open_site, opened)):
        session = python_session("all", eye_bank)
        expected = np.stack([session.render(target).image for target in targets])
        got = web.call("renderTargets", str(folder), targets)
        scores = psnr(got, expected)
        print(f"\n{folder.name}: the session with its eye bank vs Python's, dB:", np.round(scores, 1))
        assert min(scores) >= 40.0


def test_the_site_carries_the_example_persons_eye_bank(site, web):
    """lsr export --web writes the bank of every frame of the example person's video (bounded for the web), and the
    page reads back the bank Python wrote."""
    from landmarks.io.video import probe_video
    from lsr.examples import REAL_SOURCE
    from lsr.export.web_site import WEB_BANK_ENTRIES, read_eye_bank

    config = json.loads((site.folder / "site.json").read_text())
    assert config["bank"] == "all"
    bank = read_eye_bank(site.folder / "person")
    assert 0.9 * probe_video(REAL_SOURCE).frames <= len(bank) <= WEB_BANK_ENTRIES  # its frames with a face
    got = web.call("eyeBankFromFolder", str(site.folder))
    np.testing.assert_array_equal(got["patches"], bank.patches)
    for name in ("apertures", "gazes", "poses"):
        np.testing.assert_array_equal(got[name], getattr(bank, name))
    size = sum(path.stat().st_size for path in site.files if path.name.startswith("eye_bank"))
    print(f"\nthe site's eye bank: {len(bank)} entries, {size / 2**20:.2f} MiB")


def test_a_site_written_before_the_bank_still_runs_without_one(site, web, python_session, tmp_path):
    """No bank files and no "bank" in site.json: the page loads it and draws the synthesis' own eyes, as Python does
    with bank "none"; the same targets with the bank lay other eyes in."""

    def before_the_bank(config: dict) -> dict:
        return {key: value for key, value in config.items() if key != "bank"}

    old = _site_copy(site, tmp_path / "old", before_the_bank)
    assert not list(old.rglob("eye_bank.*"))
    session = python_session("none")
    reference = session.subject.reference_landmarks.astype(np.float64)
    targets = np.stack([reference, reference + [3.0, -2.0]])
    expected = np.stack([session.render(target).image for target in targets])
    got, banked = web.calls(("renderTargets", [str(old), targets]), ("renderTargets", [str(site.folder), targets]))
    scores = psnr(got, expected)
    print("\na site without a bank vs Python with bank none, dB:", np.round(scores, 1))
    assert min(scores) >= 40.0
    assert max(psnr(banked, got)) < 60.0  # with the bank, the person's own eyes
