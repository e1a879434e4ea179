"""ONNX export of the two graphs (subject encoder, frame generator): onnxruntime fp32 vs PyTorch <= 1e-4,
with dynamic batch (and K for the encoder) exercised at sizes different from the export example."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lsr.export.graphs import SUBJECT_GRAPH_IO, FrameGeneratorGraph, export_onnx, frame_graph_io
from models_def import LSRModel, preset_config

ort = pytest.importorskip("onnxruntime")
pytestmark = pytest.mark.slow  # each export traces a model (seconds on a loaded 2-core machine)


def _session(path):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def _model(variant: str) -> LSRModel:
    torch.manual_seed(0)
    return LSRModel(preset_config("tiny", variant=variant)).eval()


def test_subject_encoder_parity_dynamic_batch_and_k(tmp_path):
    model = _model("latent_layout")
    g = torch.Generator().manual_seed(0)
    example = (torch.rand(2, 2, 3, 64, 64, generator=g) * 2 - 1, torch.rand(2, 2, 3, 64, 64, generator=g) * 2 - 1)
    names_in, names_out, axes = SUBJECT_GRAPH_IO
    path = export_onnx(model.subject_encoder, example, tmp_path / "subject.onnx", names_in, names_out, axes)
    session = _session(path)
    for batch, shots in ((1, 1), (3, 4)):
        inputs = (torch.rand(batch, shots, 3, 64, 64, generator=g) * 2 - 1,) * 2
        with torch.no_grad():
            expected = model.subject_encoder(*inputs)
        got = session.run(names_out, {n: t.numpy() for n, t in zip(names_in, inputs)})
        for want, have in zip(expected, got):
            assert have.shape == (batch, model.config.latent_dim)
            np.testing.assert_allclose(have, want.numpy(), atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize(
    ("variant", "with_layout"), [("latent_layout", True), ("latent_layout", False), ("oracle_seg", True), ("baseline", False)]
)
def test_frame_generator_parity_dynamic_batch(tmp_path, variant, with_layout):
    model = _model(variant)
    config = model.config
    graph = FrameGeneratorGraph(model.frame_generator, with_layout=with_layout)
    names_in, names_out, axes = frame_graph_io(model.frame_generator, with_layout)
    g = torch.Generator().manual_seed(1)

    def inputs(batch: int) -> tuple[torch.Tensor, ...]:
        tensors = [torch.rand(batch, 3, 64, 64, generator=g) * 2 - 1]
        tensors += [torch.randn(batch, config.latent_dim, generator=g) for _ in names_in if "latent" in _]
        if variant == "oracle_seg":
            labels = torch.randint(0, 19, (batch, 64, 64), generator=g)
            tensors.append(torch.nn.functional.one_hot(labels, 19).permute(0, 3, 1, 2).float())
        return tuple(tensors)

    path = export_onnx(graph, inputs(2), tmp_path / "frame.onnx", names_in, names_out, axes)
    onnx = pytest.importorskip("onnx")
    # a Softmax over the channels runs through transposes in ONNX Runtime (15 % of the default's frame time)
    assert not any(node.op_type == "Softmax" for node in onnx.load(str(path)).graph.node)
    session = _session(path)
    for batch in (1, 3):
        example = inputs(batch)
        with torch.no_grad():
            expected = graph(*example)
        expected = expected if isinstance(expected, tuple) else (expected,)
        got = session.run(names_out, {n: t.numpy() for n, t in zip(names_in, example)})
        assert len(got) == len(names_out) == (2 if with_layout else 1)
        for want, have in zip(expected, got):
            np.testing.assert_allclose(have, want.numpy(), atol=1e-4, rtol=1e-4)


def test_layout_output_needs_a_layout_variant():
    with pytest.raises(ValueError, match="no layout map"):
        FrameGeneratorGraph(_model("baseline").frame_generator, with_layout=True)


def test_int8_export_of_a_warp_guided_model_calibrates_with_its_warped_shots(tmp_path):
    """`lsr export --int8` feeds the calibration the references a warp-guided frame graph needs (it failed on
    'references' missing from the feed before)."""
    from landmarks.io.video import VideoWriter
    from lsr.cli import main
    from lsr.data.synth import render_video

    weights = _model("warp_guided").save_pretrained(tmp_path / "w")
    clip = tmp_path / "person.mp4"
    with VideoWriter(clip, 25) as writer:
        for frame in render_video(5, 6, 128).frames:
            writer.write(frame)
    out = tmp_path / "onnx"
    assert main(["export", "--weights", str(weights), "--out", str(out), "--int8", "--calibration-source", str(clip),
                 "--calibration-frames", "3", "--calibration-k", "2"]) == 0
    assert (out / "frame_generator.int8.onnx").is_file()
    inputs = {i.name for i in _session(out / "frame_generator.int8.onnx").get_inputs()}
    assert {"references", "reference_masks"} <= inputs
