"""The LSR-model adapter (lsr.eval.model_method) on a tiny untrained model: shapes and protocol wiring only."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval import protocol


@pytest.mark.slow
def test_tiny_model_runs_through_the_protocol(tmp_path, rng, no_face_detector):
    pytest.importorskip("lsr.pipeline")
    from models_def import LSRModel
    from models_def.presets import preset_config

    from lsr.eval.model_method import LsrModelMethod

    LSRModel(preset_config("tiny")).save_pretrained(tmp_path / "tiny")
    size = 80  # not the model's 64: exercises the resize both ways
    base = rng.uniform(25, 55, size=(68, 2))
    base[36:42], base[42:48] = [28, 35], [52, 35]
    frames = rng.integers(0, 256, size=(6, size, size, 3), dtype=np.uint8)
    points = (base[None] + rng.normal(0, 1, size=(6, 68, 2))).astype(np.float32)
    identity = protocol.EvalIdentity("a", frames[:4], points[:4], frames[4:], points[4:])
    method = LsrModelMethod(tmp_path / "tiny", finetune_steps=1)
    outputs = method.reenact(list(frames[:2]), points[:2].astype(np.float64), points[4:].astype(np.float64))
    assert outputs.shape == (2, size, size, 3) and outputs.dtype == np.uint8
    run = protocol.run_protocol([method], [identity], [2], protocol.FaceAnalysis(no_face_detector()),
                                cross_identity=False, progress=False)
    assert {r["method"] for r in run.records} == {"lsr:tiny", "lsr:tiny+ft"}
