"""ONNX export: one wrapper module per graph and one generic ``export_onnx`` helper.

Graphs: the subject encoder (``models_def.SubjectEncoder``, already tensor-only: (shots, shot_landmark_images)
-> (layout_latent, style_latent), dynamic batch and K) and the frame generator (``FrameGeneratorGraph``:
landmark image + latents -> image [, layout], dynamic batch).

Uses the TorchScript exporter (``dynamo=False``): it keeps dynamic axes from ``dynamic_axes`` whatever the
example batch, and handles the shape-derived reshapes of K-shot folding without guards.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from landmarks.io.image_files import atomic_output
from models_def import FrameGenerator


class FrameGeneratorGraph(nn.Module):
    """Per-frame ONNX graph: (landmark_image, layout_latent, style_latent[, oracle_segmentation]
    [, references, reference_masks]) -> image[, layout].

    Variants without G^l (baseline, spade_landmarks, oracle_seg) take no layout_latent; see ``frame_graph_io``.
    A warp_guided graph takes its references at one fixed crop side (the export's ``crop_size``).

    ``with_layout`` adds SPADE's layout input as a second output (for display); it needs a variant that has one.
    ``network_only`` (warp_guided, ``page_composite_sigma``): the graph ends at G^s, its output ``network``
    (B, N + 4, S, S) its image (3) then its blend logits (N + 1); traced with references at the network's side S,
    it takes them pooled (2 x 2 means to S, as the whole graph pools them). The web page composites its outputs over
    the references (deploy/web/src/blend_wasm.ts) as ``models_def.composite.blend_with_reference_detail`` does.
    """

    def __init__(self, frame_generator: FrameGenerator, with_layout: bool = False, network_only: bool = False) -> None:
        super().__init__()
        variant = frame_generator.config.variant
        if with_layout and variant in ("baseline", "spade_landmarks"):
            raise ValueError(f"variant {variant!r} has no layout map; export it with with_layout=False")
        if network_only and (variant != "warp_guided" or frame_generator.config.reference_flow > 0):
            raise ValueError("only a warp_guided model without a residual flow has a network graph")
        self.frame_generator, self.with_layout, self.network_only = frame_generator, with_layout, network_only

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        if not self.frame_generator.config.uses_layout_predictor:
            # No G^l: the graph has no layout_latent input (ONNX would prune it); the style latent fills the
            # unused slot, which only needs the right shape.
            landmark_image, style_latent, *rest = inputs
            inputs = (landmark_image, style_latent, style_latent, *rest)
        if self.frame_generator.config.uses_references:
            landmark_image, layout_latent, style_latent, references, reference_masks = inputs
            outputs = self.frame_generator.synthesize(landmark_image, layout_latent, style_latent,
                                                      references=references, reference_masks=reference_masks)
        else:
            outputs = self.frame_generator.synthesize(*inputs)
        image = torch.cat([outputs.generated, outputs.blend_logits], dim=1) if self.network_only else outputs.image
        return (image, outputs.layout) if self.with_layout else image


def page_composite_sigma(config, crop_size: int) -> float | None:
    """The detail split in pixels (0: none) of the composite the web page runs itself for this model at references
    of ``crop_size`` (deploy/web/src/blend_wasm.ts ``composesInWasm``: 1, 3 or 5 references, no residual flow, the
    crop a power of two times the network's side, a multiple of 4, the detail at half resolution), or None where the
    site keeps the whole frame graph."""
    from models_def.composite import HALF_RESOLUTION_MIN_SIGMA

    sigma, factor = config.reference_detail * crop_size, crop_size // config.resolution
    if (config.variant != "warp_guided" or config.reference_flow > 0 or config.warp_references not in (1, 3, 5)
            or config.resolution % 4 or crop_size != factor * config.resolution or factor < 2 or factor & (factor - 1)
            or 0 < sigma < HALF_RESOLUTION_MIN_SIGMA):
        return None
    return float(sigma)


def frame_graph_io(frame_generator: FrameGenerator, with_layout: bool, network_only: bool = False
                   ) -> tuple[list[str], list[str], dict]:
    """Input names, output names and dynamic axes (batch) of the frame graph of this variant."""
    inputs = ["landmark_image", "layout_latent", "style_latent"]
    if not frame_generator.config.uses_layout_predictor:
        inputs.remove("layout_latent")
    if frame_generator.config.variant == "oracle_seg":
        inputs.append("oracle_segmentation")
    if frame_generator.config.uses_references:
        inputs += ["references", "reference_masks"]
    outputs = ["network" if network_only else "image"] + (["layout"] if with_layout else [])
    return inputs, outputs, {name: {0: "batch"} for name in inputs + outputs}


SUBJECT_GRAPH_IO = (
    ["shots", "shot_landmark_images"],
    ["layout_latent", "style_latent"],
    {
        "shots": {0: "batch", 1: "shots"},
        "shot_landmark_images": {0: "batch", 1: "shots"},
        "layout_latent": {0: "batch"},
        "style_latent": {0: "batch"},
    },
)


def export_onnx(
    module: nn.Module,
    example_inputs: Sequence[torch.Tensor],
    path: str | os.PathLike,
    input_names: Sequence[str],
    output_names: Sequence[str],
    dynamic_axes: dict[str, dict[int, str]],
    opset: int = 17,
) -> Path:
    """Export ``module`` (eval mode, fp32) to ``path`` atomically and check the file with onnx.checker."""
    import onnx

    path = Path(path)
    was_training = module.training
    module.eval()
    try:
        with atomic_output(path) as temp, torch.no_grad(), warnings.catch_warnings():
            temp_name = str(temp)
            # Tracer and exporter chatter (shape checks are constant per trace; instance_norm "train=True" is
            # how InstanceNorm with input statistics exports) would bury the caller's output.
            warnings.simplefilter("ignore")
            torch.onnx.export(
                module,
                tuple(example_inputs),
                temp_name,
                input_names=list(input_names),
                output_names=list(output_names),
                dynamic_axes=dynamic_axes,
                opset_version=opset,
                dynamo=False,
            )
            onnx.checker.check_model(temp_name)
    finally:
        module.train(was_training)
    return path
