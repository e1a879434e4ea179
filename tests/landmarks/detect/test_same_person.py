"""Shots of another person: ``landmarks.detect.same_person`` and the subject loader that leaves them out."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.detect import same_person as identity
from landmarks.detect import dlib_models as models
from landmarks.exceptions import InputFileError, ModelFilesError

skimage_data = pytest.importorskip("skimage.data")


def _cluster(rng, centre, count, spread=0.1):
    return centre + spread * rng.standard_normal((count, identity.DESCRIPTOR_SIZE)) / np.sqrt(identity.DESCRIPTOR_SIZE)


def test_same_person_leaves_out_the_minority():
    rng = np.random.default_rng(0)
    person, other = np.zeros(identity.DESCRIPTOR_SIZE), np.full(identity.DESCRIPTOR_SIZE, 0.1)  # 1.13 apart
    descriptors = np.concatenate([_cluster(rng, person, 6), _cluster(rng, other, 2)])
    descriptors[3] = np.nan  # a face without a descriptor is not judged
    np.testing.assert_array_equal(identity.same_person(descriptors), [True] * 6 + [False] * 2)


def test_same_person_keeps_all_without_a_majority():
    rng = np.random.default_rng(1)
    person, other = np.zeros(identity.DESCRIPTOR_SIZE), np.full(identity.DESCRIPTOR_SIZE, 0.1)
    assert identity.same_person(np.concatenate([_cluster(rng, person, 3), _cluster(rng, other, 3)])).all()
    assert identity.same_person(np.concatenate([_cluster(rng, person, 1), _cluster(rng, other, 1)])).all()
    # the radius decides: the same two groups are one person under a radius wider than their distance
    spread = np.concatenate([_cluster(rng, person, 5), _cluster(rng, other, 2)])
    assert not identity.same_person(spread).all()
    assert identity.same_person(spread, radius=2.0).all()


def test_turned_faces_are_not_judged(monkeypatch):
    from landmarks.motion.head_pose import project_canonical

    assert identity.judged(project_canonical(10.0, 0.0, 0.0, (256, 256)), (256, 256, 3))
    assert not identity.judged(project_canonical(60.0, 0.0, 0.0, (256, 256)), (256, 256, 3))
    assert not identity.judged(np.full((68, 2), np.nan), (256, 256, 3))
    monkeypatch.setattr(identity, "face_descriptor", lambda image, points: np.ones(identity.DESCRIPTOR_SIZE))
    images = [np.zeros((256, 256, 3), np.uint8)] * 2
    found = identity.face_descriptors(images, [project_canonical(yaw, 0.0, 0.0, (256, 256)) for yaw in (10.0, -60.0)])
    assert np.isfinite(found[0]).all() and np.isnan(found[1]).all()


def test_available_is_false_without_the_model(monkeypatch):
    def missing():
        raise ModelFilesError("dlib is not importable")

    monkeypatch.setattr(models, "face_recognizer", missing)
    assert not identity.available()
    with pytest.raises(ModelFilesError):
        identity.face_descriptor(np.zeros((64, 64, 3), np.uint8), np.full((68, 2), 32.0))


def _astronaut(shift: int, tint: bool = False) -> np.ndarray:
    frame = np.ascontiguousarray(skimage_data.astronaut()[20:276, 100 - shift : 356 - shift])
    if tint:  # "another person": the fake descriptor below reads the tint
        frame = np.clip(frame.astype(np.int16) + (0, 0, 60), 0, 255).astype(np.uint8)
    return frame


def _fake_descriptors(monkeypatch):
    """Descriptors that tell the tinted frames apart (dlib's would not: it is the same face)."""
    monkeypatch.setattr(identity, "available", lambda: True)
    monkeypatch.setattr(identity, "face_descriptor",
                        lambda image, points: np.full(identity.DESCRIPTOR_SIZE, image[..., 2].mean() / 100.0))


def test_loader_replaces_another_persons_shots(monkeypatch):
    from lsr.core import inputs as sources
    from lsr.core.inputs import load_subject_shots

    _fake_descriptors(monkeypatch)
    # the chooser's pick (lsr.core.inputs.choose_shots) fixed, so that both of another person's frames are in it
    monkeypatch.setattr(sources, "choose_shots", lambda frames, points, k: [0, 1, 3, 4, 6, 7, 9, 10][:k]
                        if k <= 8 else list(range(k)))
    frames = [_astronaut(2 * i, tint=i in (3, 6)) for i in range(11)]
    shots = load_subject_shots(frames, 128, k=8)
    # 8 chosen of 11 = 0, 1, 3, 4, 6, 7, 9, 10: shots 3 and 6 replaced by 2 and 5
    assert shots.names == [f"array#{i}" for i in (0, 1, 2, 4, 5, 7, 9, 10)]
    assert any("left out 2 of 8 chosen source frame(s) showing another person's face" in n and "2 other frame(s)" in n
               for n in shots.notes)
    with pytest.raises(InputFileError, match="K=10 is larger than the source frames that show the person, 9: left out 2 of 10"):
        load_subject_shots(frames, 128, k=10)


def test_loader_without_dlib_says_the_shots_were_not_checked(monkeypatch):
    from lsr.core.inputs import load_subject_shots

    monkeypatch.setattr(identity, "available", lambda: False)
    shots = load_subject_shots([_astronaut(0), _astronaut(2), _astronaut(4, tint=True)], 128)
    assert len(shots.frames) == 3
    assert any("not checked for another person's face" in n for n in shots.notes)
    # two shots have no majority to judge by: nothing to check, nothing to say
    assert not any("another person" in n for n in load_subject_shots([_astronaut(0), _astronaut(4)], 128).notes)


def test_loader_keeps_one_person_with_real_descriptors():
    from lsr.core.inputs import load_subject_shots

    if not identity.available():
        pytest.skip("dlib's face recogniser is not installed")
    shots = load_subject_shots([_astronaut(2 * i) for i in range(4)], 128)
    assert len(shots.frames) == 4 and not any("another person" in n for n in shots.notes)


@pytest.mark.slow
def test_fsth_interviewer_frames_are_the_only_other_person(shared_data):
    """On the FSTH sample, 3 of id00081's input frames show his interviewer (the video cuts away); id03969's
    frames come nearest the radius among the other people (0.57 from the medoid) and all stay."""
    if not identity.available():
        pytest.skip("dlib's face recogniser is not installed")
    from landmarks.detect.registry import make_detector
    from landmarks.io.image_files import read_image

    detector = make_detector("mesh")
    for person, expected in (("id00081", {"00028", "00029", "00030"}), ("id03969", set())):
        paths = sorted((shared_data / "fsth_eval_sample" / "train" / person).glob("*/combined/*_rgb.png"))
        images, points, names = [], [], []
        for path in paths:
            image = read_image(path)
            faces = detector.detect(image)
            if faces:
                images.append(image)
                points.append(faces[0].landmarks)
                names.append(path.name.split("_")[0])
        descriptors = identity.face_descriptors(images, points)  # his profile frames (> 45 deg) are not judged
        others = {name for name, keep in zip(names, identity.same_person(descriptors)) if not keep}
        assert len(names) >= 30 and others == expected, (person, sorted(others))
