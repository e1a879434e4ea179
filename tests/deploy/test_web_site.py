"""``lsr export --web``: the static site, and its per-frame path (deploy/web, in Node) against the Python live
session (lsr.core.live_session.LiveSession) on the same camera frames and on the same landmarks (issue 42's parity)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lsr.eval.metrics import psnr

pytestmark = pytest.mark.slow

FRAMES = 10
FPS = 25.0


def test_the_site_holds_the_page_the_models_and_the_person(site):
    names = {path.relative_to(site.folder).as_posix() for path in site.files}
    assert {"index.html", "app.js", "sw.js", "ort.wasm.min.mjs", "ort-wasm-simd-threaded.wasm", "site.json", "NOTICE.md",
            "models/frame_generator.onnx", "models/mediapipe/face_landmark.onnx", "models/subject_encoder.onnx",
            "models/mediapipe/selfie_segmentation.onnx", "person/subject.json",
            "person/shots.u8", "person/scene.u8", "person/matte.u8", "person/plate.u8"} <= names
    config = json.loads((site.folder / "site.json").read_text())
    assert config["crop_size"] == 256 and config["resolution"] == 64 and config["references"] == 5
    subject = json.loads((site.folder / "person" / "subject.json").read_text())
    assert np.shape(subject["shot_landmarks"]) == (site.k, 68, 2) and len(subject["style_latent"]) == config["latent_dim"]
    assert "GRID" in (site.folder / "NOTICE.md").read_text()


def test_the_browser_path_re_enacts_camera_frames_as_the_python_live_session(site, python_session, web, driver_frames):
    frames = driver_frames(FRAMES)
    frames[4] = 0  # a frame without a face: both show the last good output
    session = python_session()
    expected = [session.step(frame, index / FPS).image for index, frame in enumerate(frames)]
    result = web.call("reenactFrames", str(site.folder), frames, FPS)
    scores = psnr(result["frames"], np.stack(expected))
    print("web vs python, dB per frame:", np.round(scores, 1))
    assert min(scores) >= 40.0
    assert np.isnan(result["targets"][4]).all() and np.isfinite(result["targets"][np.arange(FRAMES) != 4]).all()


def test_the_browser_path_draws_given_landmarks_as_python(site, python_session, web):
    from landmarks.shape.expression import set_mouth_opening

    session = python_session()
    reference = session.subject.reference_landmarks.astype(np.float64)
    targets = np.stack([reference, set_mouth_opening(reference, 0.35), reference + [6.0, -4.0]])  # one opens wide
    expected = [session.render(target).image for target in targets]
    got = web.call("renderTargets", str(site.folder), targets)
    scores = psnr(got, np.stack(expected))
    print("web vs python at given landmarks, dB:", np.round(scores, 1))
    assert min(scores) >= 40.0


def test_without_npm_the_export_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    import deploy.web_build
    from lsr.cli import main

    monkeypatch.setattr(deploy.web_build.shutil, "which", lambda name: None)
    assert main(["export", "--web", str(tmp_path / "site")]) == 2
    message = capsys.readouterr().err.strip()
    assert message.startswith("lsr: error:") and "npm" in message and "\n" not in message
    assert not (tmp_path / "site").exists()


def test_web_and_int8_do_not_go_together(tmp_path, capsys):
    from lsr.cli import main

    assert main(["export", "--web", str(tmp_path / "site"), "--int8"]) == 2
    assert "--int8" in capsys.readouterr().err
