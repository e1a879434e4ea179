"""The mesh baselines (lsr.eval.baselines.MeshWarp / MeshMean3) and how meshes travel through the eval."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval import protocol
from lsr.eval.baselines import MeshMean3, MeshWarp, TpsWarp

SIZE = 96


@pytest.fixture(scope="module")
def synthetic_identities() -> list[protocol.EvalIdentity]:
    """Two synthetic people (lsr.data.synth), 5 inputs + 3 hold-outs each at 96 px, with the mesh detector's
    landmarks and meshes (what ``load_fsth_sample`` gives with the default detector)."""
    from landmarks.detect.mediapipe_tracker import MeshDetector
    from lsr.data.synth import render_video

    detector = MeshDetector()
    identities = []
    for seed in (0, 1):
        frames = render_video(seed, 8, SIZE).frames
        landmarks, meshes = protocol.detect_faces(list(frames), detector)
        assert meshes is not None and np.isfinite(meshes[:, 0, 0]).sum() >= 6  # the detector finds these faces
        identities.append(protocol.EvalIdentity(f"synth{seed}", frames[:5], landmarks[:5], frames[5:], landmarks[5:],
                                                input_meshes=meshes[:5], holdout_meshes=meshes[5:]))
    return identities


def _inputs(identity: protocol.EvalIdentity):
    shots_found = np.flatnonzero(np.isfinite(identity.input_landmarks).all(axis=(1, 2)))
    targets_found = np.flatnonzero(np.isfinite(identity.holdout_landmarks).all(axis=(1, 2)))
    shots = [identity.input_frames[i] for i in shots_found]
    return (shots, identity.input_landmarks[shots_found].astype(np.float64),
            identity.holdout_landmarks[targets_found].astype(np.float64),
            identity.input_meshes[shots_found], identity.holdout_meshes[targets_found])


def test_detected_landmarks_are_the_meshes_68_points(synthetic_identities):
    from landmarks.shape.mesh68 import mesh_to_68

    for identity in synthetic_identities:
        found = np.isfinite(identity.input_landmarks).all(axis=(1, 2))
        np.testing.assert_array_equal(identity.input_landmarks[found], mesh_to_68(identity.input_meshes[found]))
        assert np.isnan(identity.input_meshes[~found]).all()


def test_mesh_baselines_give_uint8_frames(synthetic_identities):
    shots, shot_landmarks, targets, shot_meshes, target_meshes = _inputs(synthetic_identities[0])
    single, mean3 = MeshWarp(), MeshMean3()
    outputs = single.reenact(shots, shot_landmarks, targets, shot_meshes=shot_meshes, target_meshes=target_meshes)
    averaged = mean3.reenact(shots, shot_landmarks, targets, shot_meshes=shot_meshes, target_meshes=target_meshes)
    for frames in (outputs, averaged):
        assert frames.shape == (len(targets), SIZE, SIZE, 3) and frames.dtype == np.uint8
        assert 10 < frames.mean() < 245  # an image, not a blank
    assert sum(single.warp_counts.values()) == len(targets) and single.warp_counts["without_mesh"] == 0
    assert sum(mean3.warp_counts.values()) == 3 * len(targets)
    one = MeshMean3().reenact(shots[:1], shot_landmarks[:1], targets, shot_meshes=shot_meshes[:1], target_meshes=target_meshes)
    np.testing.assert_array_equal(one, MeshWarp().reenact(shots[:1], shot_landmarks[:1], targets,
                                                          shot_meshes=shot_meshes[:1], target_meshes=target_meshes))


def test_a_shot_driven_by_its_own_mesh_comes_back(synthetic_identities):
    shots, shot_landmarks, _, shot_meshes, _ = _inputs(synthetic_identities[0])
    outputs = MeshWarp().reenact(shots, shot_landmarks, shot_landmarks, shot_meshes=shot_meshes, target_meshes=shot_meshes)
    assert np.abs(outputs.astype(int) - np.stack(shots)).max() <= 1  # identity map, bicubic rounding


def test_frames_without_a_mesh_take_the_tps_warp(synthetic_identities):
    shots, shot_landmarks, targets, shot_meshes, target_meshes = _inputs(synthetic_identities[0])
    target_meshes = target_meshes.copy()
    target_meshes[0] = np.nan
    method = MeshWarp()
    outputs = method.reenact(shots, shot_landmarks, targets, shot_meshes=shot_meshes, target_meshes=target_meshes)
    np.testing.assert_array_equal(outputs[0], TpsWarp().reenact(shots, shot_landmarks, targets[:1])[0])
    assert method.warp_counts["without_mesh"] == 1
    with pytest.raises(ValueError, match="target_meshes"):
        method.reenact(shots, shot_landmarks, targets, shot_meshes=shot_meshes, target_meshes=target_meshes[:, :68])


def test_runner_passes_meshes_self_and_cross_and_skips_identities_without(synthetic_identities, no_face_detector,
                                                                          monkeypatch):
    import dataclasses

    from lsr.eval import idsim

    monkeypatch.setattr(idsim, "face_embedding", lambda image, points: np.ones(128) / np.sqrt(128))  # dlib's: slow
    identities = list(synthetic_identities) + [dataclasses.replace(synthetic_identities[0], name="plain",
                                                                   input_meshes=None, holdout_meshes=None)]
    run = protocol.run_protocol([TpsWarp(), MeshWarp(), MeshMean3()], identities, [2],
                                protocol.FaceAnalysis(no_face_detector()), max_holdouts=2, progress=False)
    for name in ("mesh", "mesh_mean3"):
        records = [r for r in run.records if r["method"] == name]
        assert {r["identity"] for r in records} == {"synth0", "synth1"} and all(np.isfinite(r["psnr"]) for r in records)
        crossed = [r for r in run.cross_records if r["method"] == name]
        assert {r["identity"] for r in crossed} == {"synth0", "synth1"}  # driven by the next identity's meshes
        assert run.counts["skipped_without_meshes"][name] == ["K=2 plain"]
    assert {r["identity"] for r in run.records if r["method"] == "tps"} == {"synth0", "synth1", "plain"}
    # synth0 is driven by synth1's meshes; synth1 by "plain", which has none: those frames take the TPS alone
    driven_by_plain = sum(1 for r in run.cross_records if r["method"] == "mesh" and r["driver"] == "plain")
    assert driven_by_plain > 0
    assert run.counts["warp_methods"]["mesh"]["K=2 cross"]["without_mesh"] == driven_by_plain


def test_retargeted_meshes_follow_the_sequence_targets(synthetic_identities):
    from landmarks.shape.mesh68 import mesh_to_68
    from lsr.eval import cross

    source, driver = synthetic_identities
    shots, shot_landmarks, _, shot_meshes, _ = _inputs(source)
    rows = np.flatnonzero(np.isfinite(driver.holdout_landmarks).all(axis=(1, 2)))
    sequences = {}
    for retarget in ("2d", "3d"):
        sequence = sequences[retarget] = cross.prepare_sequence(len(shots), source.name, driver.name, rows, shots, shot_landmarks,
                                          driver.holdout_frames[rows], driver.holdout_landmarks[rows], np.zeros(128),
                                          shot_meshes=shot_meshes, driver_meshes=driver.holdout_meshes[rows],
                                          retarget=retarget)
        meshes = sequence.target_meshes
        assert meshes is not None and meshes.shape == (len(rows), 468, 3) and np.isfinite(meshes).all()
        eyes = np.linalg.norm(sequence.targets[:, 36:42].mean(1) - sequence.targets[:, 42:48].mean(1), axis=-1)
        error = np.linalg.norm(mesh_to_68(meshes) - sequence.targets, axis=-1)  # (T, 68)
        # the meshes and the 68-point targets drive the same face (the jaw, mapped with the yaw, a little apart)
        assert np.all(error[:, 17:].max(axis=1) < 0.05 * eyes) and np.all(error[:, :17].max(axis=1) < 0.1 * eyes)
    without = cross.prepare_sequence(len(shots), source.name, driver.name, rows, shots, shot_landmarks,
                                     driver.holdout_frames[rows], driver.holdout_landmarks[rows], np.zeros(128))
    assert without.target_meshes is None  # in 2D the 68 points do not depend on the meshes
    np.testing.assert_allclose(without.targets, sequences["2d"].targets)


def test_lsr_eval_with_a_detector_without_meshes_skips_the_mesh_baselines(tmp_path, monkeypatch, no_face_detector):
    import landmarks.detect.registry

    from lsr.config import EvalConfig
    from lsr.data.synth.generate import generate_dataset
    from lsr.eval import report

    root = tmp_path / "synth"
    generate_dataset(root, identities=2, videos_per_identity=1, frames=6, size=64, test_fraction=0.5, progress=False)
    monkeypatch.setattr(landmarks.detect.registry, "make_detector", no_face_detector)  # like dlib's: 68 points, no mesh
    cfg = EvalConfig(data=root, out=tmp_path / "out", k=(1,), inputs=3, holdouts=2, progress=False, examples=0,
                     cross_identity=False)
    cfg.validate()
    assert "mesh" in cfg.methods and "mesh_mean3" in cfg.methods  # in the default list
    summary = report.run_eval(cfg)
    assert {row["method"] for row in summary["rows"]} == {"nearest_shot", "tps", "tps_mean3"}
    written = (tmp_path / "out" / "eval_report.md").read_text()
    assert "- mesh: skipped, needs face meshes" in written and "- mesh_mean3: skipped, needs face meshes" in written
    only_mesh = EvalConfig(data=root, out=tmp_path / "out2", k=(1,), methods=("mesh",), inputs=3, holdouts=2,
                           progress=False, examples=0)
    from lsr.errors import ConfigError

    with pytest.raises(ConfigError, match="--detector mesh"):
        report.run_eval(only_mesh)


def test_lsr_eval_adds_a_row_per_extra_expression_gain_and_refuses_one_out_of_range(tmp_path, monkeypatch):
    import lsr.eval.protocol as protocol
    from lsr.config import EvalConfig
    from lsr.errors import ConfigError
    from lsr.eval import report
    from models_def import LSRModel, preset_config

    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "w")
    with pytest.raises(ConfigError, match="--expression-gains"):
        EvalConfig(weights=(weights,), expression_gains=(1.25, 0.5)).validate()
    seen = []

    def stop(methods, *args, **kwargs):  # the methods the runner is given; they need not run
        seen.extend((m.name, getattr(getattr(m, "reenactor", None), "expression_gain", None)) for m in methods)
        raise RuntimeError("stop")

    monkeypatch.setattr(protocol, "run_protocol", stop)
    monkeypatch.setattr(protocol, "detect_layout", lambda data: "lsr")
    monkeypatch.setattr(protocol, "load_lsr_split", lambda *args, **kwargs: [])
    cfg = EvalConfig(data=tmp_path, weights=(weights,), expression_gains=(1.25, 1.0), methods=("tps",),
                     cross_identity=False, progress=False)
    cfg.validate()
    with pytest.raises(RuntimeError, match="stop"):
        report.run_eval(cfg)
    assert seen == [("tps", None), ("lsr:warp_guided", 1.25), ("lsr:warp_guided+gain1", 1.0)]  # labelled by variant
