"""lsr.pipeline.Reenactor and the shared frame loop (lsr.core.engine / lsr.core.inputs) on a tiny random model."""

from __future__ import annotations

import json
import resource

import numpy as np
import pytest

from lsr.core.engine import from_network, to_network
from lsr.core.inputs import SubjectShots, describe_driver, read_landmark_array
from landmarks.exceptions import InputFileError, NoFaceError
from lsr.errors import WeightsError

skimage_data = pytest.importorskip("skimage.data")


def face_frame(shift: int = 0, size: int = 256) -> np.ndarray:
    """A (size, size, 3) uint8 window of the astronaut image around her face, shifted right by ``shift`` px."""
    image = skimage_data.astronaut()
    return np.ascontiguousarray(image[20 : 20 + size, 100 - shift : 100 - shift + size])


def write_clip(path, frames, fps=25, audio=True):
    """H.264 clip of ``frames`` with (optionally) a 440 Hz sine AAC track, written with PyAV."""
    import av

    with av.open(str(path), mode="w") as container:
        video = container.add_stream("libx264", rate=fps)
        video.width, video.height, video.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        sound = container.add_stream("aac", rate=44100) if audio else None
        for frame in frames:
            for packet in video.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in video.encode(None):
            container.mux(packet)
        if sound is not None:
            samples = int(44100 * len(frames) / fps)
            wave = (0.2 * np.sin(2 * np.pi * 440 * np.arange(samples) / 44100)).astype(np.float32)
            for start in range(0, samples, 1024):
                chunk = av.AudioFrame.from_ndarray(wave[None, start : start + 1024], format="fltp", layout="mono")
                chunk.sample_rate = 44100
                for packet in sound.encode(chunk):
                    container.mux(packet)
            for packet in sound.encode(None):
                container.mux(packet)
    return path


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    torch = pytest.importorskip("torch")
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    return LSRModel(preset_config("tiny")).save_pretrained(tmp_path_factory.mktemp("weights") / "tiny")


@pytest.fixture(scope="module")
def reenactor(tiny_weights):
    from lsr.pipeline import Reenactor

    runtime = Reenactor(tiny_weights)
    runtime.encode_subject([face_frame(0), face_frame(12)])
    return runtime


def test_encode_subject_shapes_and_cache(reenactor):
    subject = reenactor.subject
    assert subject.shots.frames.shape == (2, 64, 64, 3) and subject.shots.frames.dtype == np.uint8
    assert subject.shots.landmarks.shape == (2, 68, 2)
    assert subject.layout_latent.shape == (1, 16) and subject.style_latent.shape == (1, 16)
    assert np.isfinite(subject.layout_latent).all()


def test_k_shot_average_matches_model(reenactor):
    """The cached latents are the model's K-shot average of exactly these crops (thesis eq. 4.3)."""
    import torch

    from landmarks.shape.raster import draw_landmarks

    shots = reenactor.subject.shots
    landmark_images = np.stack([draw_landmarks(p, 64) for p in shots.landmarks])
    with torch.no_grad():
        layout, style = reenactor.model.subject_encoder(
            torch.from_numpy(to_network(shots.frames)[None]), torch.from_numpy(to_network(landmark_images)[None])
        )
    np.testing.assert_allclose(reenactor.subject.style_latent, style.numpy(), atol=1e-6)
    np.testing.assert_allclose(reenactor.subject.layout_latent, layout.numpy(), atol=1e-6)


def test_network_conversions_round_trip(rng):
    image = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    converted = to_network(image)
    assert converted.shape == (3, 8, 8) and converted.min() >= -1 and converted.max() <= 1
    np.testing.assert_array_equal(from_network(converted), image)


def test_crop_landmark_driver_absolute_reproduces_target(reenactor):
    """Absolute crop-space landmarks go straight to the rasteriser: the landmark image equals draw_landmarks."""
    from landmarks.shape.raster import draw_landmarks

    points = reenactor.subject.shots.landmarks
    frames = list(reenactor(points, landmark_space="crop", mode="absolute", smooth=False, with_layout=True))
    assert len(frames) == 2 and all(f.has_face for f in frames)
    np.testing.assert_array_equal(frames[1].landmark_image, draw_landmarks(points[1], 64))
    assert frames[0].image.shape == (64, 64, 3) and frames[0].layout.shape == (19, 64, 64)


def test_relative_mode_first_frame_is_source_shape(reenactor):
    """Relative motion: the driver's first frame maps onto the source's own (anchor) landmarks, the mouth opened as
    wide as the driver's and the lids as far as the driver's from its reference lids, the median of the faces it
    sees ahead (retarget_driving)."""
    from landmarks.parts.eyes.lids import lid_gaps, running_reference_gaps, set_lid_gaps
    from landmarks.shape.expression import mouth_opening, set_mouth_opening
    from landmarks.shape.raster import draw_landmarks
    from landmarks.motion.retarget_points import retarget_driving

    driver = reenactor.subject.shots.landmarks[::-1] * 1.1 + 3  # another face shape and place
    assert reenactor.crop_size == 64  # the driver's crop pixels are the shots'
    first = next(iter(reenactor(driver, landmark_space="crop", mode="relative", smooth=False)))
    source = reenactor.subject.reference_landmarks
    lids = lid_gaps(retarget_driving(driver, driver[0], source, running_reference_gaps(driver))[0])
    assert np.abs(lids - lid_gaps(source)).max() > 0.003  # the driver's first face is not at rest
    expected = draw_landmarks(set_lid_gaps(set_mouth_opening(source, mouth_opening(driver[0])), lids), 64)
    assert np.abs(first.landmark_image.astype(int) - expected).max() <= 2


def test_video_driver_passes_faceless_frames_through_in_the_driver_scene(reenactor, tmp_path):
    frames = [face_frame(0), np.zeros((256, 256, 3), np.uint8), face_frame(6), face_frame(9)]
    clip = write_clip(tmp_path / "drive.mp4", frames, audio=False)
    out = list(reenactor(clip, paste_back=True, scene="driver"))
    assert [f.has_face for f in out] == [True, False, True, True]
    assert reenactor.last_stats.frames == 4 and reenactor.last_stats.no_face == 1
    assert all(f.image.shape == (256, 256, 3) for f in out)
    np.testing.assert_array_equal(out[1].image, out[1].driver_frame)  # passed through unchanged
    # Paste-back changes only the head region: the frame corners stay the driver's.
    assert np.abs(out[0].image[:8, :8].astype(int) - out[0].driver_frame[:8, :8]).max() == 0
    crop_output = list(reenactor(clip, paste_back=False))
    assert crop_output[1].image.shape == (64, 64, 3) and crop_output[0].image.shape == (64, 64, 3)


def test_a_video_driver_gives_each_open_mouth_frame_its_interior(reenactor, tmp_path):
    from lsr.data.synth import render_video

    clip = write_clip(tmp_path / "talk.mp4", list(render_video(44, 5, 256).frames), audio=False)  # opens at frame 4
    out = list(reenactor(clip))
    assert out[4].driver_mouth is not None and out[4].driver_mouth.patch.ndim == 3  # landmarks.parts.mouth.interior
    reenactor.mouth_interior = "shots"
    try:
        assert all(frame.driver_mouth is None for frame in reenactor(clip))
    finally:
        reenactor.mouth_interior = "driver"


def test_a_video_driver_gives_its_blink_its_shut_lids(reenactor, tmp_path):
    from lsr.data.synth import render_video

    clip = write_clip(tmp_path / "blink.mp4", list(render_video(44, 8, 256).frames), audio=False)  # shut at 2-3
    drawn = list(reenactor(clip))  # the default: the subject's own lids drawn where the target's shut, nothing cut
    assert reenactor.lids == "drawn" and all(frame.driver_eyes is None for frame in drawn)
    try:
        reenactor.lids = "driver"
        out = list(reenactor(clip))
        assert out[0].driver_eyes is None and out[7].driver_eyes is None  # open: nothing cut
        assert out[2].driver_eyes is not None and out[2].driver_eyes.patch.ndim == 3  # landmarks.parts.eyes.driver_lids
        absolute = list(reenactor(clip, mode="absolute"))  # the driver's own lids, and still its shut eyes
        assert absolute[2].driver_eyes is not None and absolute[0].driver_eyes is None
        reenactor.lids = "shots"
        lowered = list(reenactor(clip))
        assert all(frame.driver_eyes is None for frame in lowered)
    finally:
        reenactor.lids = "drawn"
    assert np.array_equal(drawn[0].synthesis, lowered[0].synthesis)  # open eyes: as the warps give them
    eyes = drawn[2].landmarks[36:48]
    rows = slice(int(eyes[:, 1].min()) - 6, int(eyes[:, 1].max()) + 7)
    assert not np.array_equal(drawn[2].synthesis[rows], lowered[2].synthesis[rows])  # shut: the lids drawn down


def test_bf16_error_is_reported(reenactor, capsys):
    error = reenactor.precision_error(list(reenactor.subject.shots.landmarks), "bf16")
    assert error.frames == 2 and 0 < error.max_abs < 1.0 and error.mean_abs <= error.max_abs
    assert "bf16 vs fp32" in capsys.readouterr().out


# ---- bad input ---------------------------------------------------------------------------------------------


def test_source_without_face_is_a_clear_error(reenactor, tmp_path):
    from landmarks.io.image_files import write_image

    blank = tmp_path / "blank.png"
    write_image(blank, np.full((128, 128, 3), 90, np.uint8))
    with pytest.raises(NoFaceError, match="no face found in the source.*blank.png"):
        reenactor.encode_subject(blank)


def test_k_larger_than_usable_frames(reenactor):
    with pytest.raises(InputFileError, match="K=3 is larger than the usable source frames"):
        reenactor.encode_subject([face_frame(0), np.zeros((100, 100, 3), np.uint8)], k=3)


@pytest.mark.parametrize("content", ["missing", "corrupt", "txt"])
def test_missing_corrupt_unsupported_files(reenactor, tmp_path, content):
    path = tmp_path / ("x.txt" if content == "txt" else "x.mp4")
    if content == "corrupt":
        path.write_bytes(b"\x00not a video" * 50)
    elif content == "txt":
        path.write_text("hello")
    with pytest.raises(InputFileError, match=str(path.name)):
        list(reenactor(path))
    with pytest.raises(InputFileError, match=str(path.name)):
        reenactor.encode_subject(path) if content != "txt" else describe_driver(path)


def test_zero_frame_video_is_rejected(reenactor, tmp_path):
    import av

    path = tmp_path / "empty.mp4"
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height = 64, 64
    with pytest.raises(InputFileError, match="empty.mp4"):
        list(reenactor(path))


def test_nan_landmark_arrays_are_rejected(tmp_path):
    array = np.zeros((4, 68, 2), np.float32)
    array[2, 5] = np.nan
    np.save(tmp_path / "lm.npy", array)
    (tmp_path / "lm.json").write_text(json.dumps({"landmarks": np.where(np.isnan(array), 0, array).tolist(), "space": "nope"}))
    with pytest.raises(InputFileError, match=r"lm.npy contain NaN/inf in 1 frame\(s\) \(first: \[2\]\)"):
        read_landmark_array(tmp_path / "lm.npy")
    with pytest.raises(InputFileError, match="must be 'frame' or 'crop'"):
        read_landmark_array(tmp_path / "lm.json")
    with pytest.raises(InputFileError, match=r"\(N, 68, 2\)"):
        read_landmark_array(np.zeros((3, 5, 2)))


def test_missing_weights_folder(tmp_path):
    from lsr.pipeline import Reenactor

    with pytest.raises(WeightsError, match="--weights DIR"):
        Reenactor(tmp_path / "nope")


def test_subject_shots_are_checked(reenactor):
    with pytest.raises(InputFileError, match=r"\(K, 64, 64, 3\)"):
        reenactor.encode_subject(SubjectShots(np.zeros((1, 32, 32, 3), np.uint8), np.zeros((1, 68, 2), np.float32), ["x"]))


@pytest.mark.slow
def test_4k_driver_streams_with_bounded_memory(reenactor, tmp_path):
    """A 3840x2160 clip is decoded one frame at a time: peak traced memory stays far below the decoded clip.

    tracemalloc sees numpy's buffers (decoded frames, crops, outputs); RSS peaks of earlier tests cannot mask it.
    """
    import tracemalloc

    import cv2

    frame = np.zeros((2160, 3840, 3), np.uint8)
    frame[600:1624, 1400:2424] = cv2.resize(face_frame(0), (1024, 1024))  # the detector sees 4K at 1/6 scale
    frames = 10
    clip = write_clip(tmp_path / "uhd.mp4", [frame] * frames, audio=False)
    del frame
    decoded_bytes = frames * 2160 * 3840 * 3  # 249 MB if the clip were held in memory
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    try:
        count = 0
        for output in reenactor(clip, paste_back=True, scene="driver"):  # composited into the 4K driver frames
            assert output.image.shape == (2160, 3840, 3)
            count += 1
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert count == frames and reenactor.last_stats.no_face == 0
    assert peak < 0.5 * decoded_bytes, f"peak {peak / 1e6:.0f} MB traced for a {decoded_bytes / 1e6:.0f} MB clip"
    rss_growth_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss_before
    assert rss_growth_kb * 1024 < decoded_bytes


@pytest.mark.parametrize("variant", ["latent_layout", "warp_guided", "spade_landmarks"])
def test_one_frame_runs_traced_with_the_eager_result_and_follows_the_model(variant, rng):
    """TorchBackend traces the frame generator for one-frame fp32 CPU calls (GIL-free beside the frame loop's
    threads): the image and layout equal the eager ones; the trace shares the weights (an in-place change shows) and
    a new model (fine-tuning swaps one in) drops it; batches run eagerly."""
    import torch

    from lsr.pipeline import TorchBackend
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    model = LSRModel(preset_config("tiny", variant=variant))
    backend = TorchBackend(model)
    size, dim = model.config.resolution, model.config.latent_dim
    inputs = [rng.uniform(-1, 1, (1, 3, size, size)).astype(np.float32), rng.normal(size=(1, dim)).astype(np.float32),
              rng.normal(size=(1, dim)).astype(np.float32)]
    if model.config.uses_references:
        crop, count = size * model.config.crop_scale, model.config.warp_references
        inputs += [rng.uniform(-1, 1, (1, count, 3, crop, crop)).astype(np.float32),
                   np.ones((1, count, 1, crop, crop), np.float32)]

    def eager(with_layout):
        with torch.inference_mode():
            references = dict(zip(("references", "reference_masks"), (torch.from_numpy(a) for a in inputs[3:])))
            outputs = model.frame_generator.synthesize(*(torch.from_numpy(a) for a in inputs[:3]), None, **references)
        return outputs.image.numpy(), None if outputs.layout is None or not with_layout else outputs.layout.numpy()

    for with_layout in (False, True):
        image, layout = backend.synthesize(*inputs[:3], with_layout, *inputs[3:])
        expected_image, expected_layout = eager(with_layout)
        np.testing.assert_allclose(image, expected_image, atol=1e-5)
        assert (layout is None) == (expected_layout is None)
        if layout is not None:
            np.testing.assert_allclose(layout, expected_layout, atol=1e-5)
    assert len(backend._traced) == (1 if model.config.layout_kind == "none" else 2)  # one trace per output set
    with torch.no_grad():
        next(model.frame_generator.parameters()).add_(0.05)  # as an optimiser step does
    np.testing.assert_allclose(backend.synthesize(*inputs[:3], False, *inputs[3:])[0], eager(False)[0], atol=1e-5)
    backend.model = backend.model  # e.g. fine-tuning's copy, swapped in and back
    assert not backend._traced
    batch = [np.concatenate([a, a]) for a in inputs]
    assert backend.synthesize(*batch[:3], False, *batch[3:])[0].shape[0] == 2 and not backend._traced
