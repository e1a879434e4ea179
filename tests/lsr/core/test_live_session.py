"""``lsr.core.live_session``: a camera stream drives one subject frame by frame (the app's live tab)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def reenactor(tmp_path_factory):
    import torch

    from lsr.pipeline import Reenactor
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    weights = LSRModel(preset_config("tiny")).save_pretrained(tmp_path_factory.mktemp("w") / "tiny")
    return Reenactor(weights, device="cpu")


def _shots(tmp_path, seed, frames, pad):
    from landmarks.io.image_files import write_image
    from lsr.data.synth import render_video

    clip = render_video(seed, frames, 256)
    paths = []
    for index, frame in enumerate(clip.frames):
        paths.append(tmp_path / f"{seed}_{index}.png")
        write_image(paths[-1], np.pad(frame, ((0, 0), (pad, pad), (0, 0)), mode="edge"))
    return paths


def test_a_stream_drives_its_own_subject_into_its_scene_and_survives_a_lost_face(reenactor, tmp_path):
    from lsr.core.live_session import LiveSession
    from lsr.data.synth import render_video

    cached = reenactor.encode_subject(_shots(tmp_path, 42, 2, pad=0), k=2)  # a batch run's
    subject = reenactor.encode_subject(_shots(tmp_path, 41, 4, pad=48), k=4, cache=False)
    assert reenactor.subject is cached  # the stream's own subject leaves the batch run's alone
    session = LiveSession(reenactor, subject, with_layout=True)
    camera = render_video(43, 6, 256).frames
    shown = [session.step(frame, timestamp=index / 15) for index, frame in enumerate(camera)]
    assert all(frame.face for frame in shown)
    assert {frame.image.shape for frame in shown} == {(256, 352, 3)}  # the subject's anchor photo, not the camera's
    assert all(np.isfinite(frame.layout).all() for frame in shown) and shown[0].landmark_image.shape == (64, 64, 3)
    assert session.one_euro.fps == pytest.approx(15.0)  # smoothing at the frames' real rate
    assert not np.array_equal(shown[0].image, shown[-1].image)  # it moves with the camera
    lost = session.step(np.zeros_like(camera[0]))  # a hand in front of the camera
    assert not lost.face and lost.note and np.array_equal(lost.image, shown[-1].image)
    assert session.step(camera[2]).face  # and back
    session.recentre()
    assert session.reference.landmarks is None
    assert session.step(camera[3]).face and session.reference.landmarks is not None
    assert (session.frames, session.faces) == (9, 8)
    # a camera stream: the mesh tracker reruns the iris net only on an eye that changed
    assert session.tracker.gate is not None and session.tracker.gate.runs > 0


def test_the_face_crop_instead_of_the_scene(reenactor, tmp_path):
    from lsr.core.live_session import LiveSession
    from lsr.data.synth import render_video

    subject = reenactor.encode_subject(_shots(tmp_path, 44, 2, pad=48), k=2)
    session = LiveSession(reenactor, subject, paste_back=False, watermark=False)
    first = session.step(np.zeros((200, 200, 3), np.uint8))  # no face yet: the anchor shot, not an error
    assert not first.face and first.image.shape == (reenactor.crop_size, reenactor.crop_size, 3)
    frame = session.step(render_video(45, 1, 256).frames[0])
    assert frame.face and frame.image.shape == (reenactor.crop_size, reenactor.crop_size, 3) and frame.layout is None


@pytest.mark.parametrize("eyes", ["drawn", "warped"])
def test_drawn_or_warped_eyes_follow_the_cameras_gaze_from_the_trackers_irises(reenactor, tmp_path, eyes):
    from lsr.core.live_session import LiveSession
    from lsr.data.synth import render_video

    subject = reenactor.encode_subject(_shots(tmp_path, 46, 2, pad=48), k=2, cache=False)
    reenactor.eyes = eyes
    try:
        session = LiveSession(reenactor, subject, paste_back=False, watermark=False)
        assert session.gazes is not None
        camera = render_video(47, 3, 256).frames
        prepared = session.prepare(camera[0])
        assert prepared.gaze is not None and prepared.gaze.shape == (2, 2)  # the mesh tracker's irises, no rerun
        assert session.finish(prepared).face and session.step(camera[1]).face
        session.recentre()
        assert session.gazes.reference is None
    finally:
        reenactor.eyes = "warped"


def test_an_open_mouth_on_camera_gives_the_synthesis_its_inside(reenactor, tmp_path):
    from landmarks.shape.expression import mouth_opening
    from lsr.core.live_session import LiveSession
    from lsr.data.synth import render_video

    subject = reenactor.encode_subject(_shots(tmp_path, 41, 2, pad=0), k=2, cache=False)
    clip = render_video(44, 5, 256)
    assert mouth_opening(clip.landmarks[4]) > 0.08
    wide = LiveSession(reenactor, subject).prepare(clip.frames[4])
    assert wide.driver_mouth is not None and wide.driver_mouth.opening > 0.05  # landmarks.parts.mouth.interior
    reenactor.mouth_interior = "shots"
    try:
        assert LiveSession(reenactor, subject).prepare(clip.frames[4]).driver_mouth is None
    finally:
        reenactor.mouth_interior = "driver"


def test_a_blink_on_camera_gives_the_synthesis_the_shut_lids(reenactor, tmp_path):
    from lsr.core.live_session import LiveSession
    from lsr.data.synth import render_video

    subject = reenactor.encode_subject(_shots(tmp_path, 41, 2, pad=0), k=2, cache=False)
    clip = render_video(44, 4, 256)  # open, closing, shut, shut
    session = LiveSession(reenactor, subject)
    prepared = [session.prepare(frame) for frame in clip.frames]
    assert all(p.driver_eyes is None for p in prepared)  # the default draws the subject's lids: nothing to cut
    try:
        reenactor.lids = "driver"
        session = LiveSession(reenactor, subject)
        prepared = [session.prepare(frame) for frame in clip.frames]
        assert prepared[0].driver_eyes is None  # open: nothing cut
        # landmarks.parts.eyes.driver_lids, against the lids at rest so far (a camera has nothing ahead: two of three closing)
        assert prepared[2].driver_eyes is not None and prepared[2].driver_eyes.strength > 0
        reenactor.lids = "shots"
        session = LiveSession(reenactor, subject)
        assert all(session.prepare(frame).driver_eyes is None for frame in clip.frames)
    finally:
        reenactor.lids = "drawn"
