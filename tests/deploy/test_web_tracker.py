"""The web runtime's face tracker (deploy/web/src/tracker.ts, facedetect.ts, facemesh.ts on onnxruntime-web) against
``landmarks.detect.registry.make_tracker("mesh")`` (landmarks.detect.mediapipe_tracker, landmarks.detect.mediapipe_mesh, landmarks.shape.mesh68) on the same
frames: the same frames with and without a face, the same detections, the 68 points, meshes and irises within a
small fraction of a pixel (the crops are resampled by the TypeScript's own bilinear sampler, not OpenCV's)."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from landmarks.detect.registry import make_tracker
from landmarks.shape.mesh68 import MAPPING_FILE, mesh_to_68
from landmarks.io.video import iter_frames

ASSETS = str(MAPPING_FILE.parent)  # landmarks/assets: mediapipe/*.onnx, mesh68.json, mesh_canonical.json
BLACK_AT = 12  # a face-less frame in the middle of the sequence: the face is lost, then detected again


def _python_run(frames: np.ndarray) -> dict:
    tracker = make_tracker("mesh")
    tracker.reset()
    count = len(frames)
    out = {"landmarks": np.full((count, 68, 2), np.nan), "meshes": np.full((count, 468, 3), np.nan),
           "irises": np.full((count, 2, 4), np.nan), "ms": np.zeros(count)}
    for index, frame in enumerate(frames):
        start = time.perf_counter()
        points = tracker.update(frame)
        out["ms"][index] = (time.perf_counter() - start) * 1e3
        if points is not None:
            out["landmarks"][index], out["meshes"][index], out["irises"][index] = points, tracker.mesh, tracker.irises
    out["detections"] = tracker.detections
    return out


def _frames(video, count: int) -> np.ndarray:
    return np.stack(list(itertools.islice(iter_frames(video), count)))


@pytest.fixture(scope="module")
def source_runs(web):
    from lsr.examples import REAL_SOURCE

    frames = _frames(REAL_SOURCE, 20)
    frames[BLACK_AT] = 0
    return _python_run(frames), web.call("trackFramesDetailed", ASSETS, frames)


def test_tracker_matches_python_on_the_example_video(source_runs):
    expected, got = source_runs
    missing = np.isnan(expected["landmarks"]).any(axis=(1, 2))
    np.testing.assert_array_equal(np.isnan(got["landmarks"]).any(axis=(1, 2)), missing)
    assert missing.sum() == 1 and missing[BLACK_AT]
    assert got["detections"] == expected["detections"] == 3  # the first frame, the black one, the one after it
    error = np.linalg.norm(got["landmarks"] - expected["landmarks"], axis=-1)[~missing]  # (frames, 68) px
    mesh_error = np.linalg.norm(got["meshes"][..., :2] - expected["meshes"][..., :2], axis=-1)[~missing]
    print(f"\n68 points: mean {error.mean():.4f} px, max {error.max():.4f} px; mesh: mean {mesh_error.mean():.4f} px; "
          f"median ms per frame: web {np.median(got['ms']):.1f}, python {np.median(expected['ms']):.1f}")
    assert error.mean() < 0.1 and error.max() < 0.5
    assert mesh_error.mean() < 0.1
    np.testing.assert_allclose(got["meshes"][~missing, :, 2], expected["meshes"][~missing, :, 2], atol=0.5)


def test_tracker_keeps_the_irises_like_python(source_runs):
    expected, got = source_runs
    np.testing.assert_array_equal(np.isnan(got["irises"]), np.isnan(expected["irises"]))
    found = ~np.isnan(expected["irises"])
    np.testing.assert_allclose(got["irises"][found], expected["irises"][found], atol=0.1)


def test_a_face_less_frame_gives_no_face(web):
    # 400 x 640: the whole-frame detection finds nothing, so the tiles of half the shorter side run too
    black = np.zeros((1, 400, 640, 3), np.uint8)
    assert make_tracker("mesh").update(black[0]) is None
    got = web.call("trackFrames", ASSETS, black)
    assert got.shape == (1, 68, 2) and np.isnan(got).all()


def test_tracker_matches_python_on_a_second_video(web):
    from lsr.examples import REAL_DRIVER

    frames = _frames(REAL_DRIVER, 3)
    expected = _python_run(frames)["landmarks"]
    got = web.call("trackFrames", ASSETS, frames)
    assert not np.isnan(expected).any() and not np.isnan(got).any()
    error = np.linalg.norm(got - expected, axis=-1)
    assert error.mean() < 0.1 and error.max() < 0.5


def test_mesh_to_68_matches_python_on_turned_heads(web, source_runs):
    """The 68-from-468 mapping with its yaw-dependent jaw (Horn's quaternion for the Kabsch rotation), on meshes
    turned about the vertical axis so that the yaw term matters (and is clipped at 45 degrees)."""
    import json

    from landmarks.motion.mesh_rotation import CANONICAL_FILE

    mesh = source_runs[0]["meshes"][0].astype(np.float64)
    centre = mesh.mean(0)
    mesh68, canonical = json.loads(MAPPING_FILE.read_text()), json.loads(CANONICAL_FILE.read_text())
    calls, expected = [], []
    for angle in (-60.0, -25.0, 0.0, 20.0):
        a = np.radians(angle)
        turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
        turned = ((mesh - centre) @ turn.T + centre).astype(np.float32)
        calls.append(("meshTo68Records", [turned, mesh68, canonical]))
        expected.append(mesh_to_68(turned))
    for got, want in zip(web.calls(*calls), expected):
        np.testing.assert_allclose(got, want, atol=2e-3)
