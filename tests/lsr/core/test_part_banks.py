"""The subject's own parts from its banks in the frame loop (issue 63): ``ReenactorBase.bank`` / ``bank_parts``,
``part_tracks`` and the per-frame choice in ``reenact``, ``Subject.part_banks`` / ``video_part_banks``, and
``LiveSession``'s tracks, on a tiny warp-guided model (crop 128: the synthetic faces' eyes are ~10 px wide there,
well over the bank's 4 px floor) and synthetic people (``lsr.data.synth``)."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import numpy as np
import pytest

K = 4
SOURCE_FACES, BLANK_AT = 12, 5  # the source video: 12 frames of a face, a black frame inserted at index 5
DRIVER_FRAMES = 16


@pytest.fixture(scope="module")
def reenactor(tmp_path_factory):
    import torch

    from lsr.pipeline import Reenactor
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path_factory.mktemp("w") / "w")
    runtime = Reenactor(weights)
    assert runtime.crop_size == 128 and (runtime.bank, runtime.bank_parts) == ("all", "eyes")  # the defaults
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a tiny net; on a busy 2-core box a 2nd torch thread spins against the loop's (10x slower)
    yield runtime
    torch.set_num_threads(threads)


def _write(path: Path, frames) -> Path:
    from landmarks.io.video import VideoWriter

    with VideoWriter(path, 25) as writer:
        for frame in frames:
            writer.write(frame)
    return path


@dataclasses.dataclass
class Clips:
    source: Path
    """A video of one synthetic person with one face-less (black) frame."""
    driver: Path
    """Another person, DRIVER_FRAMES frames, eyes open throughout."""
    short_driver: Path
    """Its first 4 frames."""
    still: Path
    """One photo of the source's person."""
    blank: Path
    """A video without any face."""
    driver_frames: np.ndarray


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Clips:
    from landmarks.io.image_files import write_image
    from lsr.data.synth import render_video

    folder = tmp_path_factory.mktemp("clips")
    source = list(render_video(31, SOURCE_FACES, 256).frames)
    write_image(folder / "still.png", source[0])
    source.insert(BLANK_AT, np.zeros_like(source[0]))
    driver = render_video(32, DRIVER_FRAMES, 256).frames
    return Clips(_write(folder / "source.mp4", source), _write(folder / "driver.mp4", driver),
                 _write(folder / "short.mp4", driver[:4]), folder / "still.png",
                 _write(folder / "blank.mp4", [np.zeros_like(source[0])] * 3), driver)


@contextlib.contextmanager
def _settings(reenactor, **values):
    """The reenactor's settings as given for the block, restored after (the module shares one reenactor)."""
    before = {name: getattr(reenactor, name) for name in values}
    try:
        for name, value in values.items():
            setattr(reenactor, name, value)
        yield reenactor
    finally:
        for name, value in before.items():
            setattr(reenactor, name, value)


@dataclasses.dataclass
class Driven:
    subject: object
    frames: dict[str, list]
    """By bank ("none", "all"): the re-enacted frames of the driver, eyes from the bank (``bank_parts`` "eyes")."""


@pytest.fixture(scope="module")
def driven(reenactor, clips) -> Driven:
    subject = reenactor.encode_subject(clips.source, k=K)
    frames = {}
    for bank in ("none", "all"):
        with _settings(reenactor, bank=bank, bank_parts="eyes"):
            frames[bank] = list(reenactor.reenact(clips.driver))
    return Driven(subject, frames)


def _switches(entries: list[int | None]) -> int:
    return sum(a != b for a, b in zip(entries, entries[1:]) if a is not None and b is not None)


# ---- which frames the banks hold -------------------------------------------------------------------------------


def test_a_video_sources_bank_all_holds_every_frame_with_a_face_and_shots_only_its_k_shots(driven):
    from landmarks.parts.eyes.eye_bank import cut_eyes

    subject = driven.subject
    assert subject.shots.video is not None and len(subject.shots.frames) == K
    every_eyes, every_mouths = subject.part_banks("all")
    # every frame of the video but the black one (not the K shots): far more entries than shots
    assert len(every_eyes) == len(every_mouths) == SOURCE_FACES > K
    shot_eyes, shot_mouths = subject.part_banks("shots")
    assert len(shot_eyes) == len(shot_mouths) == K
    for index, (frame, points) in enumerate(zip(subject.shots.frames, subject.shots.landmarks)):
        np.testing.assert_array_equal(shot_eyes.patches[index], cut_eyes(frame, points))  # the shots' own eyes
    assert subject.part_banks("all")[0] is every_eyes  # built once, on first use
    assert np.isfinite(every_eyes.apertures).all() and np.isfinite(every_eyes.poses).all()


def test_a_source_frame_without_a_face_is_skipped_by_the_bank_and_a_video_without_any_gives_none(reenactor, clips):
    from lsr.core.subject import video_part_banks

    eyes, mouths = video_part_banks(clips.source, reenactor.detector)
    assert len(eyes) == len(mouths) == SOURCE_FACES  # the black frame skipped, the frames after it tracked again
    assert video_part_banks(clips.blank, reenactor.detector) == (None, None)


# ---- the frame loop --------------------------------------------------------------------------------------------


def test_the_eye_bank_changes_the_output_around_the_eyes_only(driven):
    from landmarks.shape.measures import inter_ocular_distance

    assert [f.has_face for f in driven.frames["all"]] == [True] * DRIVER_FRAMES
    for plain, banked in zip(driven.frames["none"], driven.frames["all"], strict=True):
        np.testing.assert_array_equal(plain.landmarks, banked.landmarks)  # the same targets
        changed = np.any(plain.image != banked.image, axis=-1)
        assert changed.sum() > 50  # the bank's eyes laid in
        points = banked.landmarks
        reach = 0.75 * float(inter_ocular_distance(points))
        rows, columns = np.mgrid[:changed.shape[0], :changed.shape[1]]
        near = np.zeros_like(changed)
        for eye in (slice(36, 42), slice(42, 48)):
            centre = points[eye].mean(axis=0)
            near |= np.maximum(np.abs(columns - centre[0]), np.abs(rows - centre[1])) <= reach
        assert (~near).mean() > 0.6  # the check sees most of the crop: mouth, nose, chin, hair, background
        assert not changed[~near].any()  # identical away from the eyes: the mouth is not the bank's here
        assert changed[near].any()


def test_frames_carry_the_banks_choice_which_is_held_rather_than_chosen_afresh_each_frame(driven):
    from landmarks.parts.eyes.eye_bank import EyeBankTrack
    from landmarks.parts.hysteresis import EntryTrack

    assert all(f.eye_choice is None and f.mouth_choice is None for f in driven.frames["none"])
    banked = driven.frames["all"]
    assert all(f.eye_choice is not None for f in banked)  # open eyes throughout: the bank always has a pair
    assert all(f.mouth_choice is None for f in banked)  # bank_parts "eyes"
    entries = [f.eye_choice.entry for f in banked]
    eyes, _ = driven.subject.part_banks("all")
    assert all(0 <= entry < len(eyes) for entry in entries)
    # the same targets, the nearest entry taken every frame (no hysteresis, no fade): it hops between near-equal
    # entries of the source's still eyes; the engine's track keeps one
    hopping = EyeBankTrack(eyes, driven.subject.reference_landmarks)
    hopping.entries = EntryTrack(switch=0.0, fade=0)
    nearest = [hopping(f.landmarks, f.gaze).entry for f in banked]
    # (an entry whose lids no longer reach the target's opening within the stretch is left at once, so the engine
    # switches too: 3 times in 16 frames here, against 5 to 7 hops, as the CPU kind rounds the tracking; the factor
    # hysteresis buys on noisy targets is tested in tests/landmarks/parts/eyes/test_eye_bank.py)
    assert _switches(entries) < _switches(nearest) and _switches(nearest) >= 4
    for before, after in zip(banked, banked[1:]):
        if after.eye_choice.entry != before.eye_choice.entry:  # a change cross-fades from the entry before
            assert after.eye_choice.previous == before.eye_choice.entry and after.eye_choice.previous_weight > 0


def test_a_single_image_source_banks_its_one_shot_and_drives(reenactor, clips):
    subject = reenactor.encode_subject(clips.still)
    assert subject.shots.video is None and len(subject.shots.frames) == 1
    eyes, mouths = subject.part_banks("all")  # no video: "all" is the shots
    assert len(eyes) == len(mouths) == 1
    frames = list(reenactor.reenact(clips.short_driver))
    assert len(frames) == 4 and all(f.has_face for f in frames)
    assert all(f.eye_choice is not None and f.eye_choice.entry == 0 for f in frames)
    assert all(f.image.shape == (reenactor.crop_size, reenactor.crop_size, 3) for f in frames)


@pytest.mark.parametrize(("parts", "eyes", "mouth"), [("eyes", True, False), ("both", True, True),
                                                      ("mouth", False, True)])
def test_part_tracks_follow_bank_parts_and_relative_motion_and_none_has_none(reenactor, driven, parts, eyes, mouth):
    subject = driven.subject
    with _settings(reenactor, bank_parts=parts):
        tracks = reenactor.part_tracks(subject, relative=True)
        assert (tracks.eyes is not None, tracks.mouth is not None) == (eyes, mouth)
        if eyes:  # the targets' lids were retargeted onto the anchor: the track undoes their gain from it
            np.testing.assert_array_equal(tracks.eyes.reference, subject.reference_landmarks)
            assert reenactor.part_tracks(subject, relative=False).eyes.reference is None
        with _settings(reenactor, bank="none"):
            assert reenactor.part_tracks(subject, relative=True) is None


@pytest.mark.parametrize(("setting", "value"), [("bank", "everything"), ("bank", "eyes"), ("bank_parts", "ears"),
                                                ("bank_parts", "all")])
def test_an_unknown_bank_setting_is_a_value_error_that_names_it(reenactor, setting, value):
    before = getattr(reenactor, setting)
    with pytest.raises(ValueError, match=rf"^{setting} must be one of .*{value!r}"):
        setattr(reenactor, setting, value)
    assert getattr(reenactor, setting) == before


# ---- a live stream ---------------------------------------------------------------------------------------------


def test_a_live_session_takes_the_banks_eyes_and_chooses_afresh_after_a_face_less_frame(reenactor, driven, clips):
    from lsr.core.live_session import LiveSession

    camera = clips.driver_frames
    session = LiveSession(reenactor, driven.subject, paste_back=False, watermark=False)
    track = session.tracks.eyes
    assert track is not None and session.tracks.mouth is None  # bank_parts "eyes"
    prepared = session.prepare(camera[0])
    assert prepared.eye_choice is not None and prepared.mouth_choice is None
    shown = session.finish(prepared)
    assert shown.face and shown.image.shape == (reenactor.crop_size, reenactor.crop_size, 3)
    assert session.step(camera[1], timestamp=0.04).face
    assert track.entries.current is not None
    lost = session.step(np.zeros_like(camera[0]))  # a hand in front of the camera
    assert not lost.face and track.entries.current is None  # the parts are chosen afresh after the gap
    assert session.step(camera[2]).face and track.entries.current is not None
    with _settings(reenactor, bank="none"):
        plain = LiveSession(reenactor, driven.subject, paste_back=False, watermark=False)
        assert plain.tracks is None and plain.prepare(camera[0]).eye_choice is None


def test_a_bank_scope_other_than_all_or_shots_is_a_value_error(driven):
    with pytest.raises(ValueError, match="scope must be 'all' or 'shots', got 'none'"):
        driven.subject.part_banks("none")


# ---- the source's scene takes the bank pass's tracking --------------------------------------------------------


def test_the_scene_of_a_video_source_streams_the_bank_pass_points_as_if_it_tracked_them(reenactor, driven):
    """The "all" banks' pass keeps each source frame's points (None for the black frame). The scene streamed with them
    is the scene that tracks the video itself, frame for frame, past the video's end too (the way back); and so is
    one told the driver is shorter than it turns out to be (its frames are then read again for the way back)."""
    from lsr.core.scene import SourceScene

    subject = driven.subject
    tracked_by, track = subject.video_track
    assert tracked_by is reenactor.detector and len(track) == SOURCE_FACES + 1 and track[BLANK_AT] is None
    count = 2 * (SOURCE_FACES + 1) + 3  # forth, back, and forth again

    def stream(**options):
        scene = SourceScene(subject.shots, reenactor.crop_size, detector=reenactor.detector, **options)
        return [next(scene) for _ in range(count)]

    tracked = stream()
    for options in ({"track": track}, {"track": track, "frames_needed": 2}):
        for own, given in zip(tracked, stream(**options), strict=True):
            np.testing.assert_array_equal(own.image, given.image)
            assert (own.landmarks is None) == (given.landmarks is None)
            if own.landmarks is not None:
                np.testing.assert_array_equal(own.landmarks, given.landmarks)


def test_a_video_scene_that_fits_in_memory_plays_its_own_frames_back_with_their_layers(reenactor, driven,
                                                                                       monkeypatch):
    """The way back of a video that fits ``KEPT_BYTES`` shows the first pass's own scene frames (the very pixels, and
    the matte and plate their composite made, not made again); a longer one shows JPEG copies of them."""
    import lsr.core.scene as scene_module

    subject = driven.subject
    frames = SOURCE_FACES + 1
    count = 2 * frames + 1

    def stream():
        scene = scene_module.SourceScene(subject.shots, reenactor.crop_size, detector=reenactor.detector,
                                         track=subject.video_track[1])
        return [next(scene) for _ in range(count)]

    kept = stream()
    back = kept[frames:]  # frames - 2 .. 1, then 0 .. frames - 2 again
    order = list(range(frames - 2, 0, -1)) + list(range(0, frames - 1))
    faces = [index for index in order if kept[index].landmarks is not None]
    assert faces and all(back[order.index(index)] is kept[index] for index in faces)
    monkeypatch.setattr(scene_module, "KEPT_BYTES", 0)
    copies = stream()
    differences = []
    for index in faces:
        copy = copies[frames + order.index(index)]
        assert copy is not kept[index] and copy.layers is None
        np.testing.assert_array_equal(copy.landmarks, kept[index].landmarks)
        differences.append(np.abs(copy.image.astype(int) - kept[index].image.astype(int)).mean())
    assert 0 < np.mean(differences) < 2.0  # JPEG at quality 95 (the black frame among them is exact)
    # a header that under-counts the frames (1): kept in memory until 2 frames' worth is passed, then JPEG after all
    from landmarks.io import video as video_module

    header = video_module.probe_video(subject.shots.video)
    monkeypatch.setattr(video_module, "probe_video", lambda path: dataclasses.replace(header, frames=1))
    monkeypatch.setattr(scene_module, "KEPT_BYTES", 2 * kept[0].image.size * 10 // 3)
    short = stream()
    for index in faces:
        np.testing.assert_array_equal(short[frames + order.index(index)].image, copies[frames + order.index(index)].image)


def test_the_frame_loop_gives_the_scene_the_bank_pass_points_and_the_drivers_length(reenactor, driven, clips,
                                                                                  monkeypatch):
    import lsr.core.scene as scene_module

    given = {}
    original = scene_module.SourceScene.__init__

    def spy(self, *args, **options):
        given.update(options)
        original(self, *args, **options)

    monkeypatch.setattr(scene_module.SourceScene, "__init__", spy)
    monkeypatch.setattr(reenactor, "subject", driven.subject)  # the video source (another test drives a photo)
    frames = list(reenactor.reenact(clips.short_driver, paste_back=True))
    assert len(frames) == 4 and given["track"] is driven.subject.video_track[1] and given["frames_needed"] == 4
