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


def _python_run(frames: np.ndarray, live: bool = False) -> dict:
    tracker = make_tracker("mesh", live=live)
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
    out["gate"] = tracker.gate
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


def test_the_live_trackers_iris_gates_skip_alike(web):
    """The page's tracker as its worker makes it (irisGate: the iris net only where an eye changed) against Python's
    live tracker on the bundled driver, a still face: about half the iris runs kept, the same count within a few (the
    crops are sampled by each side's own bilinear sampler), the points within a fraction of a pixel of each other."""
    from lsr.examples import REAL_DRIVER

    frames = _frames(REAL_DRIVER, 30)
    expected = _python_run(frames, live=True)
    got = web.call("trackFramesDetailed", ASSETS, frames, {"irisGate": True})
    runs, skips = expected["gate"].runs, expected["gate"].skips
    assert runs + skips == got["irisRuns"] + got["irisSkips"] == 2 * (len(frames) - 1)  # the first frame detects
    assert 0.3 < skips / (runs + skips) < 0.8 and abs(got["irisSkips"] - skips) <= 4
    error = np.linalg.norm(got["landmarks"] - expected["landmarks"], axis=-1)
    assert error.mean() < 0.1 and error.max() < 0.5
    plain = web.call("trackFramesDetailed", ASSETS, frames[:3])
    assert plain["irisRuns"] == plain["irisSkips"] == 0  # off unless asked: videos refine every frame


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


SEEN, GAP = 6, 3  # frames with the face before it leaves, and frames without it


def _face_gone(frame: np.ndarray, shift: int = 240) -> np.ndarray:
    """The frame moved `shift` pixels left, its right edge repeated: the face (x 117-227 in the example video's
    frames) has left it to the left; the background beside it stays."""
    out = np.empty_like(frame)
    out[:, :-shift] = frame[:, shift:]
    out[:, -shift:] = frame[:, -1:]
    return out


@pytest.fixture(scope="module")
def lost_and_found():
    """The example video's face for SEEN frames, then GAP frames without it (moved out of the frame, a grey frame,
    moved out again), then the last frame before the gap again and the two after it: (frames, Python's run, Python's
    run of the video's frames without the gap)."""
    from lsr.examples import REAL_SOURCE

    frames = _frames(REAL_SOURCE, SEEN + 2)
    gone = [_face_gone(frames[SEEN]), np.full_like(frames[0], 128), _face_gone(frames[SEEN + 1])]
    sequence = np.stack([*frames[:SEEN], *gone, frames[SEEN - 1], *frames[SEEN:]])
    return sequence, _python_run(sequence), _python_run(frames)


def test_the_python_tracker_loses_the_face_and_finds_it_again(lost_and_found):
    frames, run, unbroken = lost_and_found
    back = SEEN + GAP  # the first frame with the face again: the video's frame SEEN - 1 once more
    missing = np.isnan(run["landmarks"]).any(axis=(1, 2))
    assert missing.tolist() == [False] * SEEN + [True] * GAP + [False] * 3
    # a detection on the first frame, on each frame of the gap and on the face's return; tracked otherwise
    assert run["detections"] == 1 + GAP + 1
    tracker = make_tracker("mesh")
    counts = []
    for frame in frames:
        before = tracker.detections
        tracker.update(frame)
        counts.append(tracker.detections - before)
    assert counts == [1] + [0] * (SEEN - 1) + [1] * (GAP + 1) + [0, 0]
    # found again as a fresh start finds it (the last face's box only picks among faces), where it was before the
    # gap, and tracked on from there as if the face had never left (a detection's mesh and a tracked one differ by
    # under a pixel on average)
    fresh = make_tracker("mesh").update(frames[back])
    np.testing.assert_allclose(run["landmarks"][back], fresh, atol=1e-5)
    for step in range(3):
        error = np.linalg.norm(run["landmarks"][back + step] - unbroken["landmarks"][SEEN - 1 + step], axis=-1)
        assert error.mean() < 1.0 and error.max() < 2.5, (step, error.mean(), error.max())


def test_the_web_tracker_loses_and_finds_the_face_as_python_does(web, lost_and_found):
    frames, expected, _ = lost_and_found
    got = web.call("trackFramesDetailed", ASSETS, frames)
    missing = np.isnan(expected["landmarks"]).any(axis=(1, 2))
    np.testing.assert_array_equal(np.isnan(got["landmarks"]).any(axis=(1, 2)), missing)
    np.testing.assert_array_equal(np.isnan(got["irises"]), np.isnan(expected["irises"]))
    assert got["detections"] == expected["detections"] == 1 + GAP + 1
    error = np.linalg.norm(got["landmarks"] - expected["landmarks"], axis=-1)[~missing]
    assert error.mean() < 0.1 and error.max() < 0.5
