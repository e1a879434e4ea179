"""All five ablation variants (thesis Table 4.2) through ``lsr eval`` on a synthetic split, incl. ``oracle_seg``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lsr.errors import ConfigError, WeightsError
from lsr.eval import protocol

VARIANTS = ("baseline", "spade_landmarks", "learned_seg", "latent_layout", "oracle_seg")


@pytest.fixture(scope="module")
def ablation_setup(tmp_path_factory):
    pytest.importorskip("lsr.pipeline")
    from models_def import LSRModel
    from models_def.presets import preset_config

    from lsr.data.synth.generate import generate_dataset

    root = tmp_path_factory.mktemp("ablation")
    folders = []
    for variant in VARIANTS:
        folder = root / variant / "weights"  # every run folder ends in weights/: labels must come from the variant
        LSRModel(preset_config("tiny", variant=variant)).save_pretrained(folder)
        folders.append(folder)
    data = root / "synth"
    generate_dataset(data, identities=2, videos_per_identity=1, frames=8, size=64,
                            test_fraction=0.5, progress=False)
    return data, folders


@pytest.mark.slow
def test_load_lsr_split_keeps_holdout_segmentation(ablation_setup):
    data, _ = ablation_setup
    identities = protocol.load_lsr_split(data, "test", inputs=4, holdouts=4)
    assert identities
    for identity in identities:
        assert identity.holdout_segmentations is not None
        assert identity.holdout_segmentations.shape == identity.holdout_frames.shape[:3]
        assert identity.holdout_segmentations.dtype == np.uint8 and identity.holdout_segmentations.max() < 19


@pytest.mark.slow
def test_lsr_eval_scores_every_variant(ablation_setup, tmp_path, monkeypatch, no_face_detector):
    import landmarks.detect.registry

    from lsr.config import EvalConfig
    from lsr.eval import report

    data, folders = ablation_setup
    monkeypatch.setattr(landmarks.detect.registry, "make_detector", no_face_detector)
    cfg = EvalConfig(data=data, out=tmp_path / "out", k=(1,), methods=(), weights=tuple(folders), inputs=4, holdouts=2,
                     progress=False, examples=0)
    cfg.validate()
    summary = report.run_eval(cfg)
    rows = {row["method"]: row for row in summary["rows"]}
    assert set(rows) == {f"lsr:{variant}" for variant in VARIANTS}
    for row in rows.values():
        assert row["frames"] > 0 and np.isfinite(row["psnr"]) and 0 < row["psnr"] < 60
    assert "| lsr:oracle_seg | 1 |" in (tmp_path / "out" / "eval_report.md").read_text()


@pytest.mark.slow
def test_oracle_seg_uses_the_ground_truth_segmentation(ablation_setup):
    from lsr.eval.model_method import LsrModelMethod
    from lsr.pipeline import Reenactor

    data, folders = ablation_setup
    oracle_folder = folders[VARIANTS.index("oracle_seg")]
    with pytest.raises(WeightsError, match="oracle_seg"):  # re-enactment still refuses it: no ground truth there
        Reenactor(oracle_folder)
    identity = protocol.load_lsr_split(data, "test", inputs=4, holdouts=4)[0]
    method = LsrModelMethod(oracle_folder)
    assert method.needs_target_segmentation and method.variant == "oracle_seg"
    shots, shot_landmarks = [identity.input_frames[0]], identity.input_landmarks[:1].astype(np.float64)
    targets = identity.holdout_landmarks[:2].astype(np.float64)
    truth = identity.holdout_segmentations[:2]
    first = method.reenact(shots, shot_landmarks, targets, target_segmentations=truth)
    again = method.reenact(shots, shot_landmarks, targets, target_segmentations=truth.copy())
    other = method.reenact(shots, shot_landmarks, targets, target_segmentations=np.zeros_like(truth))
    assert first.shape == (2, *identity.holdout_frames.shape[1:]) and first.dtype == np.uint8
    np.testing.assert_array_equal(first, again)
    assert np.abs(first.astype(np.int16) - other.astype(np.int16)).max() > 0  # the segmentation reaches G^s
    with pytest.raises(ConfigError, match="uint8"):
        method.reenact(shots, shot_landmarks, targets, target_segmentations=truth[:1])


@pytest.mark.slow
def test_oracle_seg_without_segmentation_is_a_config_error(ablation_setup, no_face_detector):
    from lsr.eval.baselines import NearestShot
    from lsr.eval.model_method import LsrModelMethod

    data, folders = ablation_setup
    identities = [dataclasses.replace(i, holdout_segmentations=None) for i in protocol.load_lsr_split(data, "test", 4, 4)]
    analysis = protocol.FaceAnalysis(no_face_detector())
    # methods that do not need the ground truth are untouched by its absence
    run = protocol.run_protocol([NearestShot(), LsrModelMethod(folders[VARIANTS.index("latent_layout")])], identities,
                                [1], analysis, max_holdouts=1, cross_identity=False, progress=False)
    assert {r["method"] for r in run.records} == {"nearest_shot", "lsr:weights"}
    with pytest.raises(ConfigError, match="segmentation"):
        protocol.run_protocol([LsrModelMethod(folders[VARIANTS.index("oracle_seg")])], identities, [1], analysis,
                              cross_identity=False, progress=False)
