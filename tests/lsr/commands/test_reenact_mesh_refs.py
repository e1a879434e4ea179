"""A warp-guided model's references warped over the face mesh (``reference_warp = "mesh"``): the meshes travel
from the detector through the shots and the driver to ``landmarks.warp.piecewise_affine.warp_references_mesh``."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.warp.piecewise_affine import warp_references_mesh
from landmarks.warp.tps import warp_references


@pytest.fixture(scope="module")
def reenactor(tmp_path_factory):
    import torch

    from lsr.pipeline import Reenactor
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    folder = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path_factory.mktemp("w") / "w")
    return Reenactor(folder)


@pytest.fixture(scope="module")
def people(tmp_path_factory):
    from landmarks.io.video import VideoWriter
    from lsr.data.synth import render_video

    folder = tmp_path_factory.mktemp("people")
    paths = {}
    for name, seed, frames in (("source", 3, 8), ("driver", 4, 6)):
        with VideoWriter(folder / f"{name}.mp4", 25) as writer:
            for frame in render_video(seed, frames, 192).frames:
                writer.write(frame)
        paths[name] = folder / f"{name}.mp4"
    return paths


def test_mesh_references_of_the_shots_own_pose_are_the_shots(reenactor, people):
    subject = reenactor.encode_subject(people["source"], k=4)
    shots = subject.shots
    assert shots.meshes is not None and shots.meshes.shape == (len(shots.frames), 468, 3)
    # the mesh follows the crop: its 68 points sit on the shots' landmarks
    from landmarks.shape.mesh68 import mesh_to_68

    assert np.abs(mesh_to_68(shots.meshes) - shots.landmarks).max() < 1.0
    warped, masks, indices = warp_references_mesh(shots.frames, shots.meshes, shots.landmarks, shots.meshes[1],
                                                  shots.landmarks[1], 3)
    assert indices[0] == 1 and warped.shape == (3, *shots.frames.shape[1:]) and masks.shape == warped.shape[:3]
    difference = np.abs(warped[0].astype(float) - shots.frames[1]).mean()
    assert difference < 2.0  # the shot onto its own mesh: itself, up to resampling
    tps_warped, _, tps_indices = warp_references(shots.frames, shots.landmarks, shots.landmarks[1], 3)
    np.testing.assert_array_equal(indices, tps_indices)  # the same nearest shots as the TPS references


@pytest.mark.parametrize("warp", ["mesh", "tps"])
def test_reenact_drives_with_either_reference_warp(reenactor, people, warp, monkeypatch):
    import landmarks.warp.piecewise_affine as mesh_warp

    calls = []
    original = mesh_warp.warp_references_mesh
    monkeypatch.setattr(mesh_warp, "warp_references_mesh", lambda *a, **k: calls.append(1) or original(*a, **k))
    reenactor.reference_warp = warp
    reenactor.encode_subject(people["source"], k=4)
    frames = list(reenactor.reenact(people["driver"], paste_back=True))
    assert len(frames) == 6 and all(f.has_face for f in frames)
    assert all(np.isfinite(f.image.astype(float)).all() for f in frames)
    assert (len(calls) == 6) == (warp == "mesh")  # one mesh-warped reference set per frame, none with "tps"
    reenactor.reference_warp = "mesh"


def test_dlib_shots_have_no_meshes_and_fall_back_to_tps(reenactor, people):
    from lsr.core.inputs import load_subject_shots
    from landmarks.detect.registry import make_detector

    shots = load_subject_shots(people["source"], reenactor.crop_size, k=4, detector=make_detector("hog"))
    assert shots.meshes is None


def test_reenact_retargets_in_3d_on_the_sources_own_mesh(reenactor, people, monkeypatch):
    """--retarget 3d: the driver's meshes move the source's mesh (retarget_mesh_3d) and the 68 points are mapped
    from it; the first driver frame still gives the source's own face; 2d is the 68 points' relative motion."""
    import landmarks.motion.retarget_mesh as mesh_retarget
    from landmarks.exceptions import InputFileError

    calls = []
    original = mesh_retarget.retarget_mesh_3d
    monkeypatch.setattr(mesh_retarget, "retarget_mesh_3d", lambda *a, **k: calls.append(1) or original(*a, **k))
    subject = reenactor.encode_subject(people["source"], k=4)
    targets = {}
    for retarget in ("2d", "3d"):
        frames = list(reenactor.reenact(people["driver"], retarget=retarget))
        assert len(frames) == 6 and all(f.has_face for f in frames)
        targets[retarget] = np.stack([f.landmarks for f in frames])
    assert len(calls) == 6  # one per frame, 3d only
    eyes = np.linalg.norm(subject.reference_landmarks[36:42].mean(0) - subject.reference_landmarks[42:48].mean(0))
    # the driver's first face maps onto the source's own (its mouth aside, which takes the driver's opening)
    np.testing.assert_allclose(targets["3d"][0, :48], subject.reference_landmarks[:48], atol=0.05 * eyes)
    assert np.isfinite(targets["3d"]).all()
    assert 0 < np.abs(targets["3d"] - targets["2d"]).max() < 0.5 * eyes  # another motion model, the same drive
    with pytest.raises(InputFileError, match="retarget"):
        reenactor.reenact(people["driver"], retarget="4d")


def test_reenact_reads_a_driver_files_lids_ahead(reenactor, people, monkeypatch):
    """A driver file's first LOOK_AHEAD faces (here all 6) set its reference lids before the first is driven
    (``DriverReference.look_ahead``, 68 points and meshes as detected), so each frame's reference lids are what
    ``lsr eval`` computes for the whole driver at once (``running_reference_gaps``)."""
    from landmarks.parts.eyes.lids import running_reference_gaps
    from landmarks.motion.retarget_mesh import DriverReference

    ahead, driven = [], []
    look_ahead, lids = DriverReference.look_ahead, DriverReference.lids

    def spy_ahead(self, landmarks, meshes):
        ahead.append((len(landmarks), sum(mesh is not None for mesh in meshes), len(driven)))
        return look_ahead(self, landmarks, meshes)

    def spy_lids(self, landmarks, mesh=None):
        driven.append((landmarks, mesh, *lids(self, landmarks, mesh)))
        return driven[-1][2:]

    monkeypatch.setattr(DriverReference, "look_ahead", spy_ahead)
    monkeypatch.setattr(DriverReference, "lids", spy_lids)
    reenactor.encode_subject(people["source"], k=4)
    assert len(list(reenactor.reenact(people["driver"]))) == 6
    assert ahead == [(6, 6, 0)] and len(driven) == 6  # all six seen before the first was driven
    landmarks, meshes, gaps, mesh_gaps = (np.stack(column) for column in zip(*driven))
    np.testing.assert_allclose(gaps, running_reference_gaps(landmarks))
    np.testing.assert_allclose(mesh_gaps, running_reference_gaps(meshes))


def test_the_mouth_comes_from_the_nearest_reference_unless_told_to_blend(reenactor, people, monkeypatch):
    """``mouth`` "nearest": where the target opens wider than its shots, the synthesis' mouth region is the first
    (nearest) warped shot's (``landmarks.parts.mouth.nearest_mouth``), the rest the network's; "blend": the network's alone."""
    from landmarks.parts.mouth.nearest_mouth import mouth_weight

    import landmarks.parts.mouth.nearest_mouth as nearest_mouth

    monkeypatch.setattr(nearest_mouth, "MISMATCH", (1e6, 2e6))  # the random net draws no skin like a shot's
    subject = reenactor.encode_subject(people["source"], k=4)
    from landmarks.shape.expression import mouth_opening, set_mouth_opening
    from landmarks.parts.mouth.nearest_mouth import mouth_strength

    closed = int(np.argmin(mouth_opening(subject.shots.landmarks)))
    target = subject.shots.landmarks[closed] + np.array([1.5, -1.0])  # near the most closed shot, not on it
    assert mouth_strength(target, subject.shots.landmarks, reenactor.warp_references) == 0.0  # no wider than its shots
    reenactor.mouth = "nearest"
    unchanged, _, _ = reenactor.synthesize_crop(target)
    reenactor.mouth = "blend"
    np.testing.assert_array_equal(unchanged, reenactor.synthesize_crop(target)[0])  # their blend is kept
    target = set_mouth_opening(target, 0.5)  # wider than any shot's
    assert mouth_strength(target, subject.shots.landmarks, reenactor.warp_references) == 1.0
    _, inputs = reenactor.network_inputs(target)
    nearest = np.clip(np.rint((np.moveaxis(inputs["references"][0, 0], 0, -1) + 1) * 127.5), 0, 255)
    reenactor.mouth = "blend"
    blended, _, _ = reenactor.synthesize_crop(target)
    reenactor.mouth = "nearest"
    kept, _, _ = reenactor.synthesize_crop(target)
    weight, (x0, y0, x1, y1) = mouth_weight(target, blended.shape[:2])
    full = np.zeros(blended.shape[:2], np.float32)
    full[y0:y1, x0:x1] = weight * inputs["reference_masks"][0, 0, 0, y0:y1, x0:x1]
    inside, outside = full > 0.999, full == 0
    assert inside.sum() > 50 and outside.mean() > 0.8
    assert np.abs(kept[inside].astype(float) - nearest[inside]).max() <= 1.0
    np.testing.assert_array_equal(kept[outside], blended[outside])
    assert np.abs(blended[inside].astype(float) - nearest[inside]).mean() > 2.0  # the tiny net's own mouth differs


def test_the_stages_overlap_on_threads_and_give_the_frames_of_the_sequential_path(reenactor, people, monkeypatch):
    """``reenact`` prepares each frame (the shots warped onto its target) on a thread ahead of the network, which runs
    on the calling thread; the frames are those of ``synthesize_crop`` one at a time, in order."""
    import threading

    subject = reenactor.encode_subject(people["source"], k=4)
    targets = subject.shots.landmarks[[2, 0, 3, 1]] + np.array([1.5, -0.5])
    threads = {"warps": set(), "network": set()}
    inputs, synthesize = reenactor.network_inputs, reenactor.backend.synthesize
    monkeypatch.setattr(reenactor, "network_inputs", lambda *a, **k: threads["warps"].add(threading.get_ident())
                        or inputs(*a, **k))
    monkeypatch.setattr(reenactor.backend, "synthesize", lambda *a, **k: threads["network"].add(threading.get_ident())
                        or synthesize(*a, **k))
    frames = list(reenactor.reenact(targets, landmark_space="crop", landmark_size=reenactor.crop_size, mode="absolute",
                                    smooth=False))
    assert threads["network"] == {threading.get_ident()} and threading.get_ident() not in threads["warps"]
    assert [frame.index for frame in frames] == [0, 1, 2, 3]
    for frame, target in zip(frames, targets):
        np.testing.assert_allclose(frame.landmarks, target, atol=1e-4)  # read as float32
        np.testing.assert_array_equal(frame.image, reenactor.synthesize_crop(  # with the eyes its bank chose
            frame.landmarks, eye_choice=frame.eye_choice, mouth_choice=frame.mouth_choice)[0])
    stages = reenactor.last_stats.seconds
    assert stages["warps"] > 0 and stages["synthesis"] > 0


def test_warped_eyes_carry_the_references_irises_to_the_gaze_and_change_nothing_else(reenactor, people):
    from landmarks.shape.measures import eye_axes
    from landmarks.parts.eyes.iris_shift import BAND, REACH

    subject = reenactor.encode_subject(people["source"], k=4)
    irises = subject.shot_irises
    assert irises.shape == (len(subject.shots.frames), 2, 2) and np.isfinite(irises).all()
    target, mesh = subject.shots.landmarks[1] + np.array([1.0, 0.5]), subject.shots.meshes[1] + [1.0, 0.5, 0.0]
    gaze = np.array([[0.12, 0.0], [0.12, 0.0]])
    assert reenactor.eyes == "warped"  # the default
    reenactor.eyes = "blend"
    blend = reenactor.network_inputs(target, crop_mesh=mesh, gaze=gaze)[1]["references"]
    np.testing.assert_array_equal(blend, reenactor.network_inputs(target, crop_mesh=mesh)[1]["references"])
    reenactor.eyes = "warped"
    try:
        warped = reenactor.network_inputs(target, crop_mesh=mesh, gaze=gaze)[1]["references"]
        agreed = reenactor.network_inputs(target, crop_mesh=mesh)[1]["references"]  # no gaze: the nearest shot's
    finally:
        reenactor.eyes = "warped"
    eyes = np.zeros(blend.shape[-2:], bool)
    for eye in range(2):
        centre, axis, width = eye_axes(target, eye)
        reach = np.ceil(width * np.hypot(REACH, BAND[1])) + 2
        x0, y0 = np.floor(centre - reach).astype(int)
        x1, y1 = np.ceil(centre + reach).astype(int)
        eyes[max(y0, 0):y1, max(x0, 0):x1] = True
    changed = np.abs(warped - blend).max(axis=(0, 1, 2)) > 0
    assert changed[eyes].any() and not changed[~eyes].any()
    np.testing.assert_array_equal(agreed[0, 0], blend[0, 0])  # the nearest shot is the one the others move to
    assert not np.array_equal(agreed, blend)


def test_the_expression_gain_reaches_the_mesh_references_where_the_target_opens_wider(reenactor, people):
    from landmarks.parts.mouth.opening_gain import EXPRESSION_GAIN, mouth_weights
    from landmarks.shape.mesh68 import mesh_to_68
    from landmarks.motion.mesh_rotation import canonical

    subject = reenactor.encode_subject(people["source"], k=4)
    shots = subject.shots
    mesh = shots.meshes[1].astype(np.float64)
    jaw = (mesh[:, 1] > mesh_to_68(mesh)[60:68, 1].mean()) & ~canonical()[1]  # below the lips, not rigid
    opened = mesh.copy()
    opened[:, 1] += 0.06 * reenactor.crop_size * jaw * mouth_weights()  # a mouth wider than every shot's

    def references(target_mesh: np.ndarray, gain: float) -> np.ndarray:
        reenactor.expression_gain = gain
        try:
            return reenactor.network_inputs(mesh_to_68(target_mesh), crop_mesh=target_mesh)[1]["references"]
        finally:
            reenactor.expression_gain = EXPRESSION_GAIN

    assert reenactor.expression_gain == EXPRESSION_GAIN  # the default
    assert not np.array_equal(references(opened, EXPRESSION_GAIN), references(opened, 1.0))
    # where the target's mouth is the shot's own, the gain has nothing to carry
    np.testing.assert_array_equal(references(mesh, EXPRESSION_GAIN), references(mesh, 1.0))
    for wrong in (0.5, 3.0):
        with pytest.raises(ValueError, match="expression_gain"):
            reenactor.expression_gain = wrong
