"""The app's callbacks without a server: limits, shot loading, latent averaging, temp-file cleanup, no-weights page."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app import handlers
from landmarks.exceptions import InputFileError, NoFaceError
from lsr.errors import WeightsError


def test_driver_limits_are_enforced_with_a_message(app_inputs):
    assert handlers.check_driver(app_inputs["driver"], handlers.Limits()).frames == 5
    with pytest.raises(InputFileError, match="up to 3"):
        handlers.check_driver(app_inputs["driver"], handlers.Limits(max_video_frames=3))
    with pytest.raises(InputFileError, match=r"s long; this app accepts up to 0.1 s"):
        handlers.check_driver(app_inputs["driver"], handlers.Limits(max_video_seconds=0.1))
    with pytest.raises(InputFileError, match="MB"):
        handlers.check_driver(app_inputs["driver"], handlers.Limits(max_upload_mb=1e-6))


def test_faceless_images_are_skipped_and_named(app_inputs):
    from landmarks.detect.registry import make_detector

    detector = make_detector()
    shots, notes = handlers.load_shots([app_inputs["source"], app_inputs["no_face"]], 4, 64, detector, handlers.Limits())
    assert shots.frames.shape == (1, 64, 64, 3) and shots.landmarks.shape == (1, 68, 2)
    assert any("no_face.png: skipped" in note for note in notes)
    with pytest.raises(NoFaceError, match="no face found"):
        handlers.load_shots([app_inputs["no_face"]], 4, 64, detector, handlers.Limits())
    with pytest.raises(InputFileError, match="either images or one video"):
        handlers.load_shots([app_inputs["source"], app_inputs["driver"]], 4, 64, detector, handlers.Limits())
    with pytest.raises(InputFileError, match="K must be in 1..2"):
        handlers.load_shots([app_inputs["source"]], 3, 64, detector, handlers.Limits(max_k=2))


def test_latent_average_of_one_shot_is_that_shot(tiny_app_weights, app_inputs):
    """K=1: the 'average' panel must equal the shot encoded alone (thesis eq. 4.3 with K=1)."""
    store = handlers.ModelStore(tiny_app_weights, "cpu")
    reenactor = store.reenactor("torch")
    shots, _ = handlers.load_shots([app_inputs["source"]], 1, reenactor.crop_size, store.detector, handlers.Limits())
    reenactor.encode_subject(shots)
    items = handlers.latent_averaging(reenactor, shots, shots.landmarks[0])
    assert [caption for _, caption in items] == ["shot 1 alone", "average of K=1"]
    assert items[0][0].shape == (handlers.DISPLAY_SIDE, handlers.DISPLAY_SIDE, 3)
    np.testing.assert_allclose(items[0][0].astype(int), items[1][0].astype(int), atol=1)


def test_session_files_replace_runs_and_clean_up(tmp_path):
    files = handlers.SessionFiles(tmp_path / "root")
    first = files.new_run("abc")
    (first / "out.mp4").write_bytes(b"x")
    second = files.new_run("abc")
    assert not first.exists() and second.is_dir()  # one run per session is kept
    other = files.new_run("../../etc")  # session ids never escape the root
    assert files.root in other.parents
    files.drop("abc")
    assert not second.exists()
    files.drop_all()
    assert not files.root.exists()


def test_without_weights_the_page_explains_and_runs_refuse(tmp_path, monkeypatch):
    monkeypatch.setenv("LSR_WEIGHTS", str(tmp_path / "missing"))  # a broken override hides the shipped model
    store = handlers.ModelStore(handlers.default_weights())
    assert store.weights is None and "lsr train" in store.problem and "--random-init" in store.problem
    with pytest.raises(WeightsError, match="lsr app --weights"):
        store.reenactor("torch")


def test_readable_errors_become_gradio_errors():
    import gradio as gr

    with pytest.raises(gr.Error) as caught, handlers.readable_errors("re-enact"):
        raise NoFaceError("no face found in the source")
    assert caught.value.title == "No face found" and "no face found" in caught.value.message


def test_cli_rejects_a_missing_weights_folder(tmp_path, capsys):
    from lsr.cli import main

    assert main(["app", "--weights", str(tmp_path / "missing")]) == 2
    assert "is not a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_examples_are_generated_once_and_usable(tmp_path):
    from app import examples
    from landmarks.io.video import probe_video

    made = examples.ensure_examples(tmp_path)
    stamp = made.driver_video.stat().st_mtime_ns
    again = examples.ensure_examples(tmp_path)
    assert again.driver_video.stat().st_mtime_ns == stamp  # cached, not regenerated
    assert all(path.is_file() for path in made.source_images)
    info = probe_video(made.driver_video)
    assert info.frames == examples.DRIVER_FRAMES and info.has_audio
    landmarks = np.load(made.driver_landmarks, allow_pickle=False)
    assert landmarks.shape == (examples.DRIVER_FRAMES, 68, 2) and np.isfinite(landmarks).all()
    assert made.driver(examples.DRIVER_EXAMPLE_LANDMARKS) == made.driver_landmarks
    assert not list(tmp_path.glob(".staging-*"))


@pytest.mark.slow
def test_finetuning_is_per_run_and_leaves_the_served_model_untouched(tiny_app_weights, app_inputs, tmp_path):
    import torch

    store = handlers.ModelStore(tiny_app_weights, "cpu")
    base = store.reenactor("torch").model
    before = {name: tensor.clone() for name, tensor in base.state_dict().items()}
    files = handlers.SessionFiles(tmp_path / "sessions")
    result = handlers.run_reenactment(store, handlers.Limits(), files.new_run("s"), [app_inputs["source"]], 1,
                                      app_inputs["driver"], finetune_steps=1, watermark=False)
    assert result.frames == 5 and "| finetune |" in result.timing
    assert store.reenactor("torch").model is base
    assert all(torch.equal(before[name], tensor) for name, tensor in base.state_dict().items())


def test_model_summary_names_the_model_and_says_what_a_warp_guided_one_does(tmp_path):
    from app.ui import model_summary
    from lsr.weights import DEFAULT_WEIGHTS
    from models_def import LSRModel, preset_config

    folder = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "my_model")
    line = model_summary(folder, False)
    assert "`my_model`" in line and str(tmp_path) not in line  # the folder's name, not a machine path
    assert "warp_guided" in line and "64x64 network" in line and "at 128x128" in line  # tiny: 64^2, crop_scale 2
    default = model_summary(DEFAULT_WEIGHTS, False)
    assert "the shipped default model" in default and "64x64 network" in default and "at 256x256" in default


def test_errors_name_the_uploaded_file_not_the_server_temp_path(app_inputs, tmp_path):
    import gradio as gr

    from landmarks.detect.registry import make_detector

    upload = tmp_path / "gradio" / "4f1c9e" / "holiday photo.png"  # where gradio keeps an upload
    upload.parent.mkdir(parents=True)
    upload.write_bytes(b"\x89PNG broken")
    with pytest.raises(gr.Error) as caught, handlers.readable_errors("load the source"):
        handlers.load_shots([upload], 4, 64, make_detector(), handlers.Limits())
    assert "holiday photo.png" in caught.value.message and str(tmp_path) not in caught.value.message
    shots, notes = handlers.load_shots([app_inputs["source"], upload], 4, 64, make_detector(), handlers.Limits())
    assert len(shots.frames) == 1 and "cannot read holiday photo.png as an image: skipped" in notes


def test_the_app_and_lsr_reenact_write_the_same_video(tiny_app_weights, app_inputs, tmp_path):
    """One writer for both: the same shots, driver and options give the same frames, audio and provenance."""
    import av

    from landmarks.io.video import iter_frames
    from lsr.cli import main

    store = handlers.ModelStore(tiny_app_weights, "cpu")
    files = handlers.SessionFiles(tmp_path / "sessions")
    result = handlers.run_reenactment(store, handlers.Limits(), files.new_run("s"), [app_inputs["source"]], 1,
                                      app_inputs["driver"], motion="relative", finetune_steps=0, watermark=True)
    cli_out = tmp_path / "cli.mp4"
    assert main(["reenact", "--weights", str(tiny_app_weights), "--source", str(app_inputs["source"]),
                 "--k", "1", "--driver", str(app_inputs["driver"]), "--motion", "relative", "--finetune-steps", "0",
                 "--watermark", "--out", str(cli_out), "--no-progress"]) == 0
    app_frames, cli_frames = list(iter_frames(result.video)), list(iter_frames(cli_out))
    assert len(app_frames) == len(cli_frames) == 5
    # the app says what the driver asks beyond the shots, as lsr reenact does (landmarks.parts.coverage)
    assert re.search(r"- (the driver .* would help|the shots cover the driver)", result.summary)
    for app_frame, cli_frame in zip(app_frames, cli_frames):
        np.testing.assert_array_equal(app_frame, cli_frame)
    with av.open(str(result.video)) as app_video, av.open(str(cli_out)) as cli_video:
        assert bool(app_video.streams.audio) and bool(cli_video.streams.audio)
        assert app_video.metadata["comment"] == cli_video.metadata["comment"]


def test_sliders_edit_the_person_and_the_saved_pose_drives_lsr_reenact(tiny_app_weights, tmp_path):
    """The expression tab: neutral sliders draw the anchor's own face, the mouth slider opens it, and the saved pose
    (neutral, then the edit) is a landmark driver `lsr reenact` accepts."""
    from app import live_tab as live
    from landmarks.io.video import iter_frames
    from lsr.cli import main

    store = handlers.ModelStore(tiny_app_weights, "cpu")
    examples = tmp_path / "examples"
    neutral = [spec[3] for spec in live.EDIT_SLIDERS]
    with pytest.raises(InputFileError, match="move a slider"):
        live.save_pose(None, tmp_path)
    image, _, status, state = live.edit_frame(store, handlers.Limits(), None, None, 2, neutral, examples)
    assert image.ndim == 3 and "ms" in status
    np.testing.assert_allclose(state.target, state.session.subject.reference_landmarks)
    opened = [0.4 if spec[0] == "mouth" else spec[3] for spec in live.EDIT_SLIDERS]
    edited, _, _, same = live.edit_frame(store, handlers.Limits(), state, None, 2, opened, examples)
    assert same is state and not np.array_equal(edited, image)  # encoded once, drawn again
    pose = live.save_pose(state, tmp_path / "pose")
    frames = np.load(pose)
    assert frames.shape == (2, 68, 2) and not np.allclose(frames[0], frames[1])
    source = live.live_person(None, 2, examples)[0][0]
    out = tmp_path / "posed.mp4"
    assert main(["reenact", "--weights", str(tiny_app_weights), "--source", str(source), "--driver", str(pose),
                 "--out", str(out), "--no-progress"]) == 0
    assert len(list(iter_frames(out))) == 2
    # saving keeps the pose while a new run replaces the previous run's files
    files = handlers.SessionFiles(tmp_path / "sessions")
    kept = live.save_pose(state, files.folder("s", "pose"))
    files.new_run("s")
    assert kept.is_file()


def test_photos_of_another_person_are_left_out_and_named(app_inputs, tmp_path, monkeypatch):
    from landmarks.detect import same_person as identity
    from landmarks.detect.registry import make_detector
    from landmarks.io.image_files import read_image, write_image

    # descriptors that read a blue tint as another person (dlib's do not separate the synthetic people)
    monkeypatch.setattr(identity, "available", lambda: True)
    monkeypatch.setattr(identity, "face_descriptor",
                        lambda image, points: np.full(identity.DESCRIPTOR_SIZE, image[..., 2].mean() / 100.0))
    person = read_image(app_inputs["source"])
    paths = []
    for number, tint in enumerate((0, 0, 80, 0)):
        paths.append(tmp_path / f"shot{number}.png")
        write_image(paths[-1], np.clip(person.astype(np.int16) + (0, 0, tint), 0, 255).astype(np.uint8))
    shots, notes = handlers.load_shots(paths, 4, 64, make_detector(), handlers.Limits())
    assert shots.names == ["shot0.png", "shot1.png", "shot3.png"]
    assert notes[0] == "using 3 of 3 shot(s) with a face of the person (K=4)"
    assert any("left out 1 of 4 chosen source frame(s) showing another person's face" in note for note in notes)


def test_the_live_layout_picture_is_redrawn_every_few_frames(tiny_app_weights, app_inputs, tmp_path):
    """The live tab sends its latent-layout picture on every LIVE_LAYOUT_EVERY-th frame shown and leaves it as it is
    between (a second picture each frame costs the stream its rate); every frame gets its re-enacted image."""
    import gradio as gr

    from app import live_tab as live
    from lsr.data.synth import render_video

    store = handlers.ModelStore(tiny_app_weights, "cpu")
    frames = render_video(12, 2 * live.LIVE_LAYOUT_EVERY + 2, 128).frames
    stream, seen = None, []
    for frame in frames:
        image, layout, status, stream = live.live_frame(store, handlers.Limits(), stream, frame,
                                                        [str(app_inputs["source"])], 1, tmp_path / "examples")
        assert isinstance(image, np.ndarray) and image.ndim == 3
        index = int(re.search(r"frame (\d+)", status).group(1))
        seen.append((index, isinstance(layout, np.ndarray)))
        if not isinstance(layout, np.ndarray):
            assert layout == gr.skip()
    stream.close()
    assert [drawn for _, drawn in seen] == [index % live.LIVE_LAYOUT_EVERY == 0 for index, _ in seen]
    assert any(drawn for _, drawn in seen) and not all(drawn for _, drawn in seen)
