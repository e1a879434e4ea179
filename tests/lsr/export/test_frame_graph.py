"""The exported per-frame graph of a warp-guided model shaped like the shipped one (5 references, a crop 4x the
network's side, the reference detail): parity with torch, the ops issue 65 put in it, the int8 graph that
quantises only the network's dense convolutions, and the graph ending at G^s that the web page composites."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lsr.export.bundle import (
    FRAME_GENERATOR_FILE,
    FRAME_NETWORK_FILE,
    INT8_QUANTIZATION,
    export_graphs,
    graph_error,
    quantize_frame_generator,
    quantized_convolutions,
)
from lsr.export.graphs import page_composite_sigma
from models_def import LSRModel, preset_config
from models_def.composite import CHANNEL_BLOCK
from models_def.norms import SPADE, AdaIN

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytestmark = pytest.mark.slow  # traces and quantises a model (seconds on a loaded 2-core machine)

COUNT = 5


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    config = preset_config("tiny", variant="warp_guided", warp_references=COUNT, crop_scale=4, reference_detail=0.0117)
    model = LSRModel(config).eval()
    with torch.no_grad():  # blend logits that differ between the references
        model.frame_generator.image_generator.to_rgb.bias[3:].uniform_(-1.0, 1.0)
    folder = export_graphs(model, tmp_path_factory.mktemp("bundle")).folder
    return model, folder


def _feeds(model: LSRModel, count: int, seed: int) -> list[dict[str, np.ndarray]]:
    config, generator = model.config, torch.Generator().manual_seed(seed)
    size, crop = config.resolution, config.resolution * config.crop_scale
    feeds = []
    for _ in range(count):
        feeds.append({
            "landmark_image": (torch.rand(1, 3, size, size, generator=generator) * 2 - 1).numpy(),
            "layout_latent": torch.randn(1, config.latent_dim, generator=generator).numpy(),
            "style_latent": torch.randn(1, config.latent_dim, generator=generator).numpy(),
            "references": (torch.rand(1, COUNT, 3, crop, crop, generator=generator) * 2 - 1).numpy(),
            "reference_masks": (torch.rand(1, COUNT, 1, crop, crop, generator=generator) > 0.1).float().numpy(),
        })
    return feeds


def _session(path):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def test_frame_graph_matches_torch_eager(exported):
    """The graph runs the fused composite and InstanceNormalization; eager the reference math: same image."""
    model, folder = exported
    session = _session(folder / FRAME_GENERATOR_FILE)
    for feed in _feeds(model, 2, seed=1):
        with torch.no_grad():
            expected = model.frame_generator(*(torch.from_numpy(feed[name]) for name in
                                               ("landmark_image", "layout_latent", "style_latent")),
                                             references=torch.from_numpy(feed["references"]),
                                             reference_masks=torch.from_numpy(feed["reference_masks"]))
        image = session.run(["image"], feed)[0]
        assert image.shape == (1, 3, 256, 256)
        assert np.abs(image - expected.numpy()).max() <= 1e-4


def test_the_network_graph_is_g_s_on_the_pooled_references(exported):
    """frame_network.onnx: the same G^s, its image then its blend logits, from the references pooled to its side."""
    import torch.nn.functional as F

    model, folder = exported
    session = _session(folder / FRAME_NETWORK_FILE)
    size = model.config.resolution
    assert [o.name for o in session.get_outputs()] == ["network", "layout"]
    for feed in _feeds(model, 2, seed=2):
        references, masks = torch.from_numpy(feed["references"]), torch.from_numpy(feed["reference_masks"])
        with torch.no_grad():
            outputs = model.frame_generator.synthesize(*(torch.from_numpy(feed[name]) for name in
                                                         ("landmark_image", "layout_latent", "style_latent")),
                                                       references=references, reference_masks=masks)
        factor = references.shape[-1] // size
        pooled = {**feed, "references": F.avg_pool2d(references.flatten(1, 2), factor).view(1, COUNT, 3, size, size).numpy(),
                  "reference_masks": F.avg_pool2d(masks.flatten(1, 2), factor).view(1, COUNT, 1, size, size).numpy()}
        network = session.run(["network"], pooled)[0]
        assert network.shape == (1, COUNT + 4, size, size)
        assert np.abs(network[:, :3] - outputs.generated.numpy()).max() <= 1e-4
        assert np.abs(network[:, 3:] - outputs.blend_logits.numpy()).max() <= 1e-4


def test_the_page_composites_only_what_its_kernel_runs():
    config = preset_config("tiny", variant="warp_guided", warp_references=5, crop_scale=4, reference_detail=0.0117)
    assert page_composite_sigma(config, 256) == pytest.approx(2.9952)
    assert page_composite_sigma(config.replace(reference_detail=0.0), 256) == 0.0
    for other, crop in [(config.replace(warp_references=4), 256), (config.replace(reference_flow=0.02), 256),
                        (config.replace(reference_detail=0.005), 256), (config, 192), (config, 64),
                        (preset_config("tiny"), 256)]:
        assert page_composite_sigma(other, crop) is None


def test_frame_graph_holds_the_ops_onnxruntime_runs_well(exported):
    model, folder = exported
    nodes = onnx.load(str(folder / FRAME_GENERATOR_FILE)).graph.node
    kinds = [node.op_type for node in nodes]
    norms = sum(isinstance(module, (AdaIN, SPADE)) for module in model.frame_generator.modules())
    # one node per norm, not eight (a block's main and shortcut norms of the same input trace to one)
    assert 0 < kinds.count("InstanceNormalization") <= norms
    assert "ReduceMean" not in kinds
    # the references' low band is blurred in blocks of CHANNEL_BLOCK channels (onnxruntime's NCHWc kernels)
    def attribute(node, name, default):
        return next((onnx.helper.get_attribute_value(a) for a in node.attribute if a.name == name), default)

    separable_blurs = [attribute(node, "group", 1) for node in nodes
                       if node.op_type == "Conv" and 1 in attribute(node, "kernel_shape", [])]  # (1, k) and (k, 1)
    reference_blurs = [group for group in separable_blurs if group > 3]  # not the blend's own 3-channel low band
    assert reference_blurs and all(group % CHANNEL_BLOCK == 0 for group in reference_blurs)
    # no multiply-and-ReduceSum over the (B, N, 3, H, W) references: the only ReduceSum left is the layout's softmax
    assert kinds.count("ReduceSum") == 1


def test_int8_graph_quantises_the_network_convolutions_only(exported, tmp_path):
    model, folder = exported
    fp32_path = folder / FRAME_GENERATOR_FILE
    calibration, held_out = _feeds(model, 4, seed=2), _feeds(model, 2, seed=3)
    int8_path = quantize_frame_generator(fp32_path, tmp_path / "frame_generator.int8.onnx", calibration)
    quantised = onnx.load(str(int8_path))
    kinds = [node.op_type for node in quantised.graph.node]
    chosen = quantized_convolutions(fp32_path)
    convolutions = [node for node in onnx.load(str(fp32_path)).graph.node if node.op_type == "Conv"]
    spade_heads = sum(isinstance(module, SPADE) for module in model.frame_generator.modules())
    # every dense convolution but the SPADE heads (one per SPADE; a block's shortcut norm shares its input's head)
    dense = [node for node in convolutions if all(a.i == 1 for a in node.attribute if a.name == "group")]
    assert 0 < len(dense) - spade_heads <= len(chosen) < len(dense)
    assert kinds.count("QLinearConv") == len(chosen)
    # the composite stays fp32: its depthwise blurs and the heads are plain Convs, no element-wise node is quantised
    assert kinds.count("Conv") == len(convolutions) - len(chosen)
    assert not [kind for kind in kinds if kind.startswith("QLinear") and kind != "QLinearConv"]
    assert {p.key: p.value for p in quantised.metadata_props}["quantization"] == INT8_QUANTIZATION
    for feeds, bound in ((calibration, 0.02), (held_out, 0.05)):  # mean abs error of images in [-1, 1]
        max_abs, mean_abs = graph_error(fp32_path, int8_path, feeds)
        assert 0 < mean_abs <= min(bound, max_abs)


def test_the_torch_free_bundle_cache_names_the_mouth_folder_as_the_model_does():
    """``lsr.export.bundle_cache`` keys a cached bundle by the mouth generator's files without importing torch, so it
    names their folder itself: the same as ``models_def.part_generator``."""
    from lsr.export.bundle_cache import MOUTH_FOLDER
    from models_def.part_generator import MOUTH_FOLDER as MODEL_MOUTH_FOLDER

    assert MOUTH_FOLDER == MODEL_MOUTH_FOLDER
