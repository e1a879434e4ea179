"""A user's own photos encoded in the browser (issue 42): deploy/web/src/encode.ts (with pose.ts and segment.ts), in
Node, against what Python makes of the same photos: ``lsr.core.engine.ReenactorBase.encode_subject`` (the shots, their
68 points, the anchor, the latents; ``lsr.export.web_site.example_subject``), the anchor's scene
(``lsr.core.scene.SourceScene``) and its layers (``landmarks.scene.person_matte.person_matte``,
``landmarks.scene.compositing.background_plate``), and the live session drawing the person encoded in the page against
``lsr.core.live_session.LiveSession`` on the person encoded in Python."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval.metrics import psnr

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def photos():
    from lsr.examples import example_shots

    return np.stack(example_shots())  # the example person's photos: (4, H, W, 3)


@pytest.fixture(scope="module")
def python_person(site):
    """(the Python subject, its scene, its person matte and its layers) for the example person's photos."""
    from landmarks.scene.compositing import background_plate
    from landmarks.scene.person_matte import person_matte
    from lsr.export.bundle import cached_bundle
    from lsr.export.web_site import example_subject
    from lsr.weights import resolve_weights

    _, subject, scene = example_subject(cached_bundle(resolve_weights(None)), site.k)
    matte = person_matte(scene.image)
    return subject, scene, matte, background_plate(scene.image, scene.landmarks, matte)


@pytest.fixture(scope="module")
def web_person(site, web, photos):
    return web.call("encodePhotosFromFolder", str(site.folder), photos)


def test_the_page_cuts_the_same_shots_and_picks_the_same_anchor(python_person, web_person, photos):
    subject, scene, _, _ = python_person
    shots = subject.shots
    assert web_person["anchor"] == shots.anchor
    assert list(web_person["photos"]) == list(range(len(photos)))
    error = np.linalg.norm(web_person["shotLandmarks"] - shots.landmarks, axis=-1)
    scores = psnr(web_person["shots"], shots.frames)
    print(f"\nshot points: mean {error.mean():.4f} px, max {error.max():.4f} px; crops, dB: {np.round(scores, 1)}")
    assert error.max() < 0.1
    assert min(scores) >= 40.0
    np.testing.assert_array_equal(web_person["scene"], scene.image)  # the anchor's photo
    assert np.linalg.norm(web_person["sceneLandmarks"] - scene.landmarks, axis=-1).max() < 0.1
    np.testing.assert_allclose(web_person["sceneMatrix"], scene.matrix, atol=0.05)
    assert any("not checked for another person" in note for note in web_person["notes"])


def test_the_page_encodes_the_same_latents(python_person, web_person):
    subject = python_person[0]
    layout = np.abs(web_person["layoutLatent"] - subject.layout_latent.ravel()).max()
    style = np.abs(web_person["styleLatent"] - subject.style_latent.ravel()).max()
    print(f"\nlatents, max abs difference: layout {layout:.5f}, style {style:.5f} (values up to "
          f"{np.abs(subject.layout_latent).max():.2f}, {np.abs(subject.style_latent).max():.2f})")
    assert layout < 0.01 and style < 0.01


def test_the_page_finds_the_same_irises(python_person, web_person):
    """Each shot's iris centres (eyes "warped", lsr.core.subject.Subject.shot_irises) and the anchor's gaze
    (Subject.irises' second) by the page's iris net."""
    subject = python_person[0]
    centres, gaze = subject.shot_irises, subject.irises[1]
    np.testing.assert_array_equal(np.isnan(web_person["shotIrises"]), np.isnan(centres))
    error = np.nanmax(np.abs(web_person["shotIrises"] - centres))
    print(f"\nshot irises: max {error:.4f} px apart")
    assert error < 0.1 and np.isfinite(centres).any()
    np.testing.assert_allclose(web_person["anchorGaze"], gaze, atol=0.01, equal_nan=True)


def test_the_page_banks_the_photos_eyes(python_person, web_person):
    """The person's own eyes (deploy/web/src/eye_bank.ts buildEyeBank on the page's shots, their points and irises)
    against Python's bank of a photo source (lsr.core.subject.Subject.part_banks: its shots'): the same entries, cut
    from crops and points that differ as the shots do."""
    expected = python_person[0].part_banks("shots")[0]
    got = web_person["eyeBank"]
    assert got["patches"].shape == expected.patches.shape
    scores = psnr(got["patches"], expected.patches)  # (N, 2): each eye of each shot
    print(f"\neye bank of the photos: patches {np.round(scores.min(), 1)} dB at worst; apertures "
          f"{np.abs(got['apertures'] - expected.apertures).max():.4f}, gazes "
          f"{np.nanmax(np.abs(got['gazes'] - expected.gazes)):.4f}, head turns "
          f"{np.abs(got['poses'] - expected.poses).max():.3f} deg apart at most")
    assert scores.min() >= 35.0
    np.testing.assert_allclose(got["apertures"], expected.apertures, atol=0.005)
    np.testing.assert_allclose(got["gazes"], expected.gazes, atol=0.01)
    np.testing.assert_allclose(got["poses"], expected.poses, atol=0.5)


def test_the_page_makes_the_same_scene_layers(python_person, web_person):
    _, scene, matte, layers = python_person
    difference = np.abs(web_person["matte"] - matte)
    print(f"\nmatte: mean abs {difference.mean():.2e}, max {difference.max():.2e}")
    assert difference.mean() < 0.01
    stepped = np.rint(np.clip(matte, 0, 1) * 255) / 255  # the layers keep it at 8 bits, as lsr export --web does
    assert np.abs(web_person["layerMatte"] - stepped).max() <= 1 / 255 + 1e-6
    filled = np.any(layers.plate != scene.image, -1) | np.any(web_person["plate"] != scene.image, -1)
    assert filled.any()
    score = psnr(web_person["plate"][filled][None], layers.plate[filled][None])
    print(f"plate: {filled.sum()} pixels filled in, {score:.1f} dB there")
    assert score >= 35.0


@pytest.mark.parametrize("scale", [(3.0, 3.0), (0.6, 0.7)])
def test_the_layers_of_larger_and_smaller_photos(site, web, python_person, scale):
    """A larger photo (the segmenter's input area-averaged, the plate filled in at 384 px and enlarged) and a
    smaller one (the segmenter's input enlarged): the uint8 resizes are OpenCV's up to a grey level here and there."""
    import cv2

    from landmarks.scene.compositing import background_plate
    from landmarks.scene.person_matte import person_matte

    _, scene, _, _ = python_person
    image = cv2.resize(scene.image, None, fx=scale[0], fy=scale[1], interpolation=cv2.INTER_CUBIC)
    height, width = scene.image.shape[:2]
    points = (scene.landmarks + 0.5) * [image.shape[1] / width, image.shape[0] / height] - 0.5
    matte = person_matte(image)
    plate = background_plate(image, points, matte).plate
    got = web.call("sceneLayersFromFolder", str(site.folder), image, points)
    filled = np.any(plate != image, -1) | np.any(got["plate"] != image, -1)
    score = psnr(got["plate"][filled][None], plate[filled][None])
    print(f"\n{image.shape[1]}x{image.shape[0]}: matte mean abs {np.abs(got['matte'] - matte).mean():.2e}; plate "
          f"{score:.1f} dB where filled in")
    assert np.abs(got["matte"] - matte).mean() < 0.01 and score >= 35.0


def test_the_crop_and_the_head_pose_are_pythons(web, photos):
    """The ports under the shots on the same points: landmarks.align.crop (also where a large face is area-averaged
    first) and landmarks.motion.head_pose.estimate_head_pose / landmarks.shape.expression.pick_anchor."""
    import cv2

    from landmarks.align import crop
    from landmarks.detect.registry import make_detector
    from landmarks.shape.expression import pick_anchor
    from landmarks.motion.head_pose import estimate_head_pose, project_canonical

    frame = photos[0]
    large = cv2.resize(frame, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)  # a 650-px face: shrunk > 2x
    points = make_detector().detect(frame)[0].landmarks.astype(np.float64)
    rng = np.random.default_rng(0)
    angles = rng.uniform([-50, -30, -20, -30, -30], [50, 30, 20, 30, 30], (12, 5))
    faces = np.concatenate([np.stack([project_canonical(*a[:3], (256, 256), translation=tuple(a[3:]))
                                      for a in angles]) + rng.normal(0, 1.5, (12, 68, 2)),
                            points[None]])  # (OpenCV's 20 LM steps stop short of the minimum on far-off faces)
    got = web.calls(("cropFaceTensor", [frame, points, 256]), ("cropFaceTensor", [large, points * 3 + 1, 256]),
                    ("estimateHeadPoses", [faces, 256, 256]), ("pickAnchor", [faces, 256, 256]),
                    ("pickAnchor", [faces[:6], 256, 256]))
    for result, (image, at) in zip(got[:2], [(frame, points), (large, points * 3 + 1)]):
        expected, matrix = crop(image, at, 256)
        np.testing.assert_allclose(result["matrix"], matrix, rtol=0, atol=1e-9)
        score = psnr(result["crop"], expected)
        print(f"\ncrop of a {image.shape[1]}x{image.shape[0]} frame: {score:.1f} dB")
        assert score >= 50.0
    poses = np.stack([estimate_head_pose(face, (256, 256)) for face in faces])
    print("head pose, max abs difference (yaw, pitch, roll), degrees:", np.abs(got[2] - poses).max(0))
    assert np.abs(got[2] - poses).max() < 0.01
    assert got[3] == pick_anchor(faces, (256, 256)) and got[4] == pick_anchor(faces[:6], (256, 256))


def test_photos_without_a_face_are_left_out_and_k_takes_the_first(site, web, photos):
    blank = np.zeros_like(photos[0])
    got = web.call("encodePhotosFromFolder", str(site.folder), np.stack([blank, *photos]), {"k": 2})
    assert list(got["photos"]) == [1, 2] and got["shots"].shape[0] == 2
    assert any("no face" in note for note in got["notes"])
    with pytest.raises(RuntimeError, match="no face found"):
        web.call("encodePhotosFromFolder", str(site.folder), blank[None])


def test_the_person_encoded_in_the_page_is_drawn_as_python_draws_it(site, web, photos, python_session):
    """End to end: the live session on the person encoded in the page (renderEncodedTargets) against Python's live
    session on the person encoded in Python, at the same landmarks; the person's own eyes from its photos' bank (the
    page's, cut from its shots; Python's bank "shots", which a photo source's "all" is)."""
    from landmarks.shape.expression import set_mouth_opening

    session = python_session("shots")
    reference = session.subject.reference_landmarks.astype(np.float64)
    targets = np.stack([reference, set_mouth_opening(reference, 0.35), reference + [6.0, -4.0]])
    expected = np.stack([session.render(target).image for target in targets])
    got = web.call("renderEncodedTargets", str(site.folder), photos, targets)
    scores = psnr(got, expected)
    print("\nthe page's person vs Python's, at given landmarks, dB:", np.round(scores, 1))
    assert min(scores) >= 40.0
