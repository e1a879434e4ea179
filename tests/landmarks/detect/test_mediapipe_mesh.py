"""The default face geometry: MediaPipe's detector and face mesh on onnxruntime, the 68 points mapped from the mesh,
the tracker, and the default path running with dlib not importable."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from landmarks.detect import mediapipe_mesh as face_mesh
from landmarks.detect.registry import make_detector, make_tracker
from landmarks.exceptions import NoFaceError
from landmarks.shape.mesh68 import fit_mapping, mapping, mesh_to_68
from landmarks.detect.mediapipe_tracker import MeshDetector, MeshTracker

REPO = Path(__file__).resolve().parents[3]


def _nme(points: np.ndarray, reference: np.ndarray) -> float:
    """Mean point distance over the distance between the reference's eye centres."""
    iod = np.linalg.norm(reference[36:42].mean(0) - reference[42:48].mean(0))
    return float(np.linalg.norm(points - reference, axis=1).mean() / iod)


@pytest.fixture(scope="module")
def dlib_points(astronaut) -> np.ndarray:
    return make_detector("hog").detect_one(astronaut).landmarks


def test_anchors_are_mediapipes_896():
    anchors = face_mesh.ssd_anchors()
    assert anchors.shape == (896, 2)
    assert np.allclose(anchors[0], [0.5 / 16, 0.5 / 16]) and np.allclose(anchors[1], anchors[0])  # 2 per cell at stride 8
    assert np.allclose(anchors[512], [0.5 / 8, 0.5 / 8]) and np.allclose(anchors[512:518], anchors[512])  # 6 at stride 16


def test_weighted_nms_merges_a_cluster_and_keeps_a_separate_face():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], np.float32)
    points = np.zeros((3, 6, 2), np.float32)
    points[1] += 2.0
    kept = face_mesh.weighted_nms(boxes, points, np.array([0.9, 0.9, 0.6], np.float32))
    assert len(kept) == 2
    box, keypoints, score = kept[0]
    assert np.allclose(box, [0.5, 0, 10.5, 10]) and np.allclose(keypoints, 1.0) and score == pytest.approx(0.9)


def test_the_astronaut_is_detected_with_her_keypoints_in_place(astronaut, dlib_points):
    found = face_mesh.detect_faces(astronaut)
    assert len(found) == 1 and found[0].score > 0.9
    eyes, nose, mouth = found[0].keypoints[:2], found[0].keypoints[2], found[0].keypoints[3]
    assert eyes[0, 0] < eyes[1, 0] and eyes[:, 1].max() < nose[1] < mouth[1]  # image-left eye first, then down the face
    assert np.linalg.norm(eyes[0] - dlib_points[36:42].mean(0)) < 12 and np.linalg.norm(eyes[1] - dlib_points[42:48].mean(0)) < 12


def test_mesh_and_its_68_points_match_dlib_on_a_real_face(astronaut, dlib_points, mesh_detector):
    detection, result = mesh_detector.meshes(astronaut)[0]
    assert result.mesh.shape == (468, 3) and np.isfinite(result.mesh).all() and result.presence > 0.9
    face = mesh_detector.detect_one(astronaut)
    assert face.landmarks.shape == (68, 2) and face.landmarks.dtype == np.float32
    assert _nme(face.landmarks, dlib_points) < 0.06


def test_the_mapping_is_convex_off_the_jaw_and_translation_equivariant(astronaut, mesh_detector):
    from landmarks.shape.mesh68 import JAW, yaw_mapping

    weights, yaw_weights = mapping(), yaw_mapping()
    assert weights.shape == yaw_weights.shape == (68, 468)
    inner = [row for row in range(68) if row not in JAW]
    assert (weights[inner] >= 0).all() and not yaw_weights[inner].any()  # convex, no yaw term off the jaw
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-4)
    np.testing.assert_allclose(yaw_weights.sum(1), 0.0, atol=1e-4)
    mesh = mesh_detector.meshes(astronaut)[0][1].mesh
    np.testing.assert_allclose(mesh_to_68(mesh + [5.0, -3.0, 1.0]), mesh_to_68(mesh) + [5.0, -3.0], atol=1e-3)
    both = mesh_to_68(np.stack([mesh, mesh + [1.0, 2.0, 0.0]]))  # batched as one by one
    np.testing.assert_allclose(both[1], mesh_to_68(mesh) + [1.0, 2.0], atol=1e-3)


def test_the_jaw_slides_with_the_yaw_as_dlibs_silhouette_does(astronaut, mesh_detector):
    """Without depth (no yaw) the jaw takes its yaw-0 weights; the astronaut turns a little, so the two differ there
    and only there."""
    mesh = mesh_detector.meshes(astronaut)[0][1].mesh
    with_yaw, flat = mesh_to_68(mesh), mesh_to_68(mesh[:, :2])
    assert np.abs(with_yaw[17:] - flat[17:]).max() < 1e-3
    assert np.abs(with_yaw[:17] - flat[:17]).max() > 0.05


def test_fit_mapping_recovers_a_known_combination():
    """Targets made as 0.3 / 0.7 blends of two neighbouring vertices of moving, noisy meshes are fitted back."""
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 100, (468, 2))
    truth = np.zeros((68, 468))
    for row in range(68):
        first = rng.integers(468)
        second = int(np.argsort(np.linalg.norm(base - base[first], axis=1))[1])  # its nearest neighbour
        truth[row, [first, second]] = [0.3, 0.7]
    scales, shifts = rng.uniform(0.8, 1.2, (40, 1, 1)), rng.uniform(-20, 20, (40, 1, 2))
    meshes = base * scales + shifts + rng.normal(0, 0.5, (40, 468, 2))
    targets = np.einsum("pv,nvc->npc", truth, meshes)
    weights, errors = fit_mapping(meshes, targets)
    assert errors.max() < 1e-3
    np.testing.assert_allclose(weights, truth, atol=1e-3)


def test_a_turned_face_is_followed_by_the_regions_rotation(astronaut, dlib_points, mesh_detector):
    height, width = astronaut.shape[:2]
    turn = cv2.getRotationMatrix2D((width / 2, height / 2), -30, 1.0)  # 30 degrees clockwise on screen
    rotated = cv2.warpAffine(astronaut, turn, (width, height), borderMode=cv2.BORDER_REFLECT)
    expected = dlib_points @ turn[:, :2].T + turn[:, 2]
    _, result = mesh_detector.meshes(rotated)[0]
    assert np.degrees(result.region.rotation) == pytest.approx(30, abs=6)  # the eye line's angle, clockwise
    assert _nme(mesh_to_68(result.mesh), expected) < 0.08


def test_a_small_face_in_a_large_frame_is_found_through_tiles(astronaut, mesh_detector):
    canvas = np.full((1400, 1800, 3), 90, np.uint8)
    face = cv2.resize(astronaut[20:260, 120:360], (150, 150), interpolation=cv2.INTER_AREA)  # face about 70 px wide
    canvas[900:1050, 1400:1550] = face
    assert face_mesh.detect_faces(canvas) == []  # too small for the 128-px whole-frame view
    faces = mesh_detector.detect(canvas)
    assert len(faces) == 1
    centre = faces[0].landmarks.mean(0)
    assert 1400 < centre[0] < 1550 and 900 < centre[1] < 1050


def test_no_face_is_an_empty_list_then_a_clear_error(mesh_detector):
    noise = np.random.default_rng(2).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    assert mesh_detector.detect(noise) == []
    with pytest.raises(NoFaceError, match="no face found in the image"):
        mesh_detector.detect_one(noise)


def test_tracker_follows_a_moving_face_with_one_detection_and_recovers_after_a_cut(astronaut, dlib_points):
    frames, shifts = [], []
    for step in range(12):
        shift = np.array([3.0 * step, 2.0 * step])
        frames.append(cv2.warpAffine(astronaut, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (512, 512),
                                     borderMode=cv2.BORDER_REFLECT))
        shifts.append(shift)
    frames[6] = np.zeros_like(astronaut)  # a cut to black: lost, then found again by detection
    tracker = make_tracker()
    assert isinstance(tracker, MeshTracker)
    result = tracker.track_frames(frames)
    assert result.missing.tolist() == [index == 6 for index in range(12)]
    assert result.detections == 3  # the first frame, the black frame, the frame after it
    for index in (0, 5, 11):
        assert _nme(result.landmarks[index], dlib_points + shifts[index]) < 0.06
    assert tracker.mesh is not None and tracker.mesh.shape == (468, 3)


def test_make_detector_names_the_kinds():
    assert isinstance(make_detector(), MeshDetector) and make_detector().kind == "mesh"
    assert make_detector("hog").kind == "hog"
    with pytest.raises(ValueError, match="mesh, hog, cnn"):
        make_detector("retina")


_NO_DLIB = """
import sys
sys.modules["dlib"] = None  # `import dlib` now raises ImportError, as on a machine without it
sys.modules["face_recognition_models"] = None
"""


@pytest.mark.slow
def test_reenact_the_app_and_the_demo_run_without_dlib(tmp_path):
    """`lsr demo` (which runs `lsr reenact`) and the app's re-enactment, with dlib not importable."""
    script = _NO_DLIB + textwrap.dedent(f"""
        from pathlib import Path
        from lsr.cli import main
        out = Path({str(tmp_path)!r})
        assert main(["demo", "--out", str(out / "demo"), "--frames", "12", "--no-progress"]) == 0
        from app import handlers
        store = handlers.ModelStore(handlers.default_weights(), "cpu")
        files = handlers.SessionFiles(out / "sessions")
        inputs = out / "demo" / "inputs"
        result = handlers.run_reenactment(store, handlers.Limits(), files.new_run("s"), [inputs / "source.mp4"], 4,
                                          inputs / "driver.mp4", paste_back=True, watermark=False)
        assert result.frames == 12, result.frames
        assert "dlib" not in sys.modules or sys.modules["dlib"] is None
        print("no-dlib run ok")
    """)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "no-dlib run ok" in done.stdout
    assert (tmp_path / "demo" / "demo.mp4").stat().st_size > 0


def test_kabsch_recovers_a_known_similarity():
    from landmarks.motion.mesh_rotation import kabsch
    from landmarks.motion.head_pose import rotation_matrix

    rng = np.random.default_rng(3)
    source = rng.normal(size=(50, 3))
    rotation = rotation_matrix(20.0, -10.0, 5.0)
    target = 2.5 * source @ rotation.T + [1.0, -2.0, 3.0]
    found, scale, shift = kabsch(source, target)
    np.testing.assert_allclose(found, rotation, atol=1e-9)
    assert scale == pytest.approx(2.5) and np.allclose(shift, [1.0, -2.0, 3.0])


def test_mesh_head_pose_follows_synthetic_heads_of_known_pose(mesh_detector):
    """Against the renderer's true angles: yaw and roll within a few degrees; pitch up to a constant offset (the
    canonical face's 'level' differs from the renderer's by a fixed tilt), then within a few degrees too."""
    from landmarks.motion.mesh_rotation import canonical, mesh_head_pose
    from lsr.data.synth.generate import render_framed

    vertices, rigid = canonical()
    assert vertices.shape == (468, 3) and 150 < rigid.sum() < 300
    errors = []
    for seed in range(4):
        clip = render_framed(seed, 4, size=256, framing="camera")
        for frame, truth in zip(clip.frames, clip.pose):
            found = mesh_detector.meshes(frame)
            if found:
                errors.append(mesh_head_pose(found[0][1].mesh) - truth[:3])
    errors = np.array(errors)
    assert len(errors) >= 12
    assert np.abs(errors[:, 0]).mean() < 3.5 and np.abs(errors[:, 2]).mean() < 2.0
    assert np.abs(errors[:, 1] - errors[:, 1].mean()).mean() < 3.0
    assert np.isnan(mesh_head_pose(np.full((468, 3), np.nan))).all()


def test_the_iris_net_moves_only_the_eye_contours_and_keeps_them_in_order(astronaut, mesh_detector):
    _, result = mesh_detector.meshes(astronaut)[0]
    raw = face_mesh.predict_mesh(astronaut, result.region, eyes=False).mesh
    refined = face_mesh.predict_mesh(astronaut, result.region).mesh
    contours = sorted(index for _, contour, _ in face_mesh.EYE_CONTOURS for index in contour)
    assert refined.dtype == np.float32 and sorted(np.flatnonzero(np.abs(refined - raw).max(1) > 0)) == contours
    distance = np.linalg.norm(raw[33, :2] - raw[263, :2])
    assert np.abs(refined - raw).max() < 0.1 * distance  # a refinement, not a different face
    for _, contour, _ in face_mesh.EYE_CONTOURS:
        lower, upper = refined[list(contour[1:8]), 1], refined[list(contour[9:]), 1]
        assert (upper < lower.max()).all() and upper.mean() < lower.mean() - 0.05 * distance  # open: upper lid above
    assert np.isnan(face_mesh.refine_eye_contours(astronaut, np.full((468, 3), np.nan))).all()


def _refine_into(queue, image: np.ndarray, mesh: np.ndarray) -> None:
    queue.put(face_mesh.refine_eye_contours(image, mesh))


def test_the_second_eye_runs_on_its_own_thread_and_a_forked_child_still_refines(astronaut, mesh_detector):
    """The two eyes run at once (the second on ``landmarks.detect.mediapipe_mesh``'s iris thread): the same points every time, and a
    child forked after the thread started (``lsr prepare``'s workers) starts its own instead of waiting forever."""
    import multiprocessing

    _, result = mesh_detector.meshes(astronaut)[0]
    mesh = face_mesh.predict_mesh(astronaut, result.region, eyes=False).mesh
    refined = face_mesh.refine_eye_contours(astronaut, mesh)
    np.testing.assert_array_equal(face_mesh.refine_eye_contours(astronaut, mesh), refined)
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_refine_into, args=(queue, astronaut, mesh))
    child.start()
    child.join(60)
    waiting = child.is_alive()
    if waiting:
        child.kill()
    assert not waiting, "the forked child waited for its parent's iris thread"
    np.testing.assert_array_equal(queue.get(timeout=10), refined)


def test_the_iris_net_treats_a_mirrored_face_as_the_mirror_image(astronaut, mesh_detector):
    """The image-right eye goes through the net mirrored: its square, its mirroring and the way back must make a
    mirrored frame's eyes the mirror of the frame's, to a hundredth of a pixel."""
    _, result = mesh_detector.meshes(astronaut)[0]
    mesh = face_mesh.predict_mesh(astronaut, result.region, eyes=False).mesh.astype(np.float64)
    (_, left, _), (_, right, _) = face_mesh.EYE_CONTOURS
    width = astronaut.shape[1]
    mirrored = mesh.copy()
    mirrored[:, 0] = width - 1 - mirrored[:, 0]
    mirrored[list(left)], mirrored[list(right)] = mirrored[list(right)].copy(), mirrored[list(left)].copy()
    found = face_mesh.refine_eye_contours(np.ascontiguousarray(astronaut[:, ::-1]), mirrored)[:, :2].astype(np.float64)
    found[:, 0] = width - 1 - found[:, 0]
    refined = face_mesh.refine_eye_contours(astronaut, mesh)[:, :2]
    assert np.abs(found[list(left)] - refined[list(right)]).max() < 0.01
    assert np.abs(found[list(right)] - refined[list(left)]).max() < 0.01


def test_refined_lids_read_more_of_a_lid_that_moved(astronaut, mesh_detector):
    """The astronaut's lids moved by a warp (gaps 0.6-1.2 times hers): the mesh with refined eyes reads more of
    that motion than the mesh net alone (about 0.35 against 0.26 of it), which barely moves its lids."""
    from landmarks.parts.eyes.lids import lid_gaps, set_lid_gaps
    from landmarks.warp.piecewise_affine import warp_mesh

    _, result = mesh_detector.meshes(astronaut)[0]
    shares = {}
    for eyes in (False, True):
        face = face_mesh.predict_mesh(astronaut, result.region, eyes=eyes).mesh.astype(np.float64)
        gaps = lid_gaps(face)
        read = []
        for scale in (0.6, 0.8, 1.2):
            target = set_lid_gaps(face, gaps * scale)
            moved, _ = warp_mesh(astronaut, face, target)
            found = face_mesh.predict_mesh(moved, result.region, eyes=eyes).mesh
            read.append((lid_gaps(found) - gaps).mean() / (lid_gaps(target) - gaps).mean())
        shares[eyes] = float(np.mean(read))
    assert 0.0 < shares[False] < shares[True] - 0.05, shares


def test_block_change_sees_one_block_that_the_crops_mean_barely_moves():
    """A dark iris moving through one 8 x 8 block changes that block's mean by its own contrast, while the whole
    crop's mean moves 64 times less."""
    rng = np.random.default_rng(0)
    last = rng.uniform(0.3, 0.7, (1, 64, 64, 3)).astype(np.float32)
    moved = last.copy()
    moved[0, 24:32, 40:48] -= 0.2
    assert face_mesh.block_change(last, last) == 0.0
    assert face_mesh.block_change(moved, last) == pytest.approx(0.2, abs=1e-6)
    assert np.abs(moved - last).mean() == pytest.approx(0.2 / 64, abs=1e-6)


def test_the_iris_gate_keeps_an_unchanged_eye_at_most_twice_in_a_row():
    """An eye keeps its last outputs while its input and lid gap hold, never more than ``max_skips`` frames in a
    row; a changed block, a moved lid or a reset runs the net again."""
    gate = face_mesh.IrisGate()
    tensor = np.full((1, 64, 64, 3), 0.5, np.float32)
    outputs = (np.zeros((71, 3), np.float32), np.ones((5, 3), np.float32))
    assert gate.kept(0, tensor, 3.0) is None  # never run
    gate.ran(0, tensor, 3.0, outputs)
    assert gate.kept(1, tensor, 3.0) is None  # the other eye has its own runs
    assert gate.kept(0, tensor + 0.01, 3.2) is outputs and gate.kept(0, tensor, 3.0) is outputs
    assert gate.kept(0, tensor, 3.0) is None  # two in a row: the third runs
    gate.ran(0, tensor, 3.0, outputs)
    changed = tensor.copy()
    changed[0, :8, :8] += 0.03
    assert gate.kept(0, changed, 3.0) is None
    assert gate.kept(0, tensor, 3.31) is None  # the mesh's lids moved by more than 0.3 crop pixels
    gate.reset()
    assert gate.kept(0, tensor, 3.0) is None
    assert (gate.runs, gate.skips) == (2, 2)


def test_a_live_tracker_skips_the_iris_net_on_a_still_face_and_reruns_it_after_a_loss(astronaut):
    """``make_tracker(live=True)``: on a still face the iris net reruns every third frame, the points within a
    fifth of a pixel of refining every frame (the kept outputs are placed by each frame's own eye squares, which
    the tracker's region moves a little); a face-less frame forgets the last runs, so the face found after it runs
    both eyes."""
    frames = [astronaut] * 7
    frames[4] = np.zeros_like(astronaut)
    live, every = make_tracker(live=True), make_tracker()
    assert isinstance(live, MeshTracker) and live.gate is not None and every.gate is None
    for index, frame in enumerate(frames):
        points, reference = live.update(frame), every.update(frame)
        if index == 4:
            assert points is None and live.gate.last == [None, None]
            continue
        assert np.abs(points - reference).max() < 0.2
    # frame 0 detects (no gate), 1 runs both eyes, 2-3 keep them; on 4 the region of the last mesh is tried (a
    # changed crop: both run) and the face is lost; 5 detects afresh, 6 runs both eyes
    assert (live.gate.runs, live.gate.skips) == (6, 4)
