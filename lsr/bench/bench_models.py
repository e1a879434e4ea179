"""``lsr bench models``: cost of the per-frame path (layout UNet G^l + SPADE generator G^s) per preset/variant.

Columns: parameters (subject encoder / frame generator), GFLOP per frame, and ms/frame (median of warm runs,
batch 1, fp32, random weights) in each runtime with its fraction of this machine's conv peak.

* GFLOP: ``torch.utils.flop_counter.FlopCounterMode``, which counts 2 FLOPs per multiply-accumulate of
  convolutions and matrix products only (element-wise ops, norms and the softmax are not counted).
* Peak: a 256->256 3x3 channels-last fp32 convolution at 64x64, measured in the same run (median).
* Runtimes: eager (NCHW), channels_last (eager, channels-last tensors and weights), compile
  (torch.compile of the channels-last module; a failure prints "failed: reason"), onnxruntime (fp32 CPU).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode
from tqdm import tqdm

from lsr.config import BenchModelsConfig
from lsr.export.graphs import FrameGeneratorGraph, export_onnx, frame_graph_io
from models_def import PRESET_NAMES, VARIANTS, LSRModel, ModelConfig, preset_config

TARGET_MS = 33.0  # per-frame budget at 256^2 on the 2-core reference CPU (25-30 fps)


def median_ms(run: Callable[[], object], runs: int, warmup: int) -> float:
    for _ in range(warmup):
        run()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def conv_peak_gflops(runs: int) -> float:
    """Throughput (GFLOP/s, median) of a large channels-last 3x3 conv: what this machine's convs can reach."""
    conv = torch.nn.Conv2d(256, 256, 3, padding=1, bias=False).to(memory_format=torch.channels_last)
    x = torch.randn(1, 256, 64, 64).contiguous(memory_format=torch.channels_last)
    flops = 2 * 256 * 256 * 9 * 64 * 64
    with torch.inference_mode():
        ms = median_ms(lambda: conv(x), max(runs, 5), warmup=3)
    return flops / (ms / 1e3) / 1e9


def frame_inputs(config: ModelConfig, names: list[str]) -> tuple[torch.Tensor, ...]:
    generator = torch.Generator().manual_seed(0)
    size = config.resolution
    crop = config.crop_scale * size  # warp_guided: the warped shots at the default crop side
    tensors = []
    for name in names:
        if name == "landmark_image":
            tensors.append(torch.rand(1, config.landmark_channels, size, size, generator=generator) * 2 - 1)
        elif name.endswith("latent"):
            tensors.append(torch.randn(1, config.latent_dim, generator=generator))
        elif name == "references":
            tensors.append(torch.rand(1, config.warp_references, 3, crop, crop, generator=generator) * 2 - 1)
        elif name == "reference_masks":
            tensors.append(torch.ones(1, config.warp_references, 1, crop, crop))
        else:  # oracle_segmentation: one-hot
            labels = torch.randint(0, 19, (1, size, size), generator=generator)
            tensors.append(torch.nn.functional.one_hot(labels, 19).permute(0, 3, 1, 2).float())
    return tuple(tensors)


def count_gflop(graph: torch.nn.Module, inputs: tuple[torch.Tensor, ...]) -> float:
    with torch.inference_mode(), FlopCounterMode(display=False) as counter:
        graph(*inputs)
    return counter.get_total_flops() / 1e9


def time_runtime(
    runtime: str, graph: FrameGeneratorGraph, inputs: tuple[torch.Tensor, ...], names: list[str], cfg: BenchModelsConfig
) -> float | str:
    """Median ms/frame of ``graph`` in ``runtime``, or "failed: reason"."""
    try:
        if runtime == "eager":
            with torch.inference_mode():
                return median_ms(lambda: graph(*inputs), cfg.runs, cfg.warmup)
        if runtime in ("channels_last", "compile"):
            module = graph.to(memory_format=torch.channels_last)
            cl_inputs = tuple(t.contiguous(memory_format=torch.channels_last) if t.dim() == 4 else t for t in inputs)
            if runtime == "compile":
                module = torch.compile(module)
            with torch.inference_mode():
                return median_ms(lambda: module(*cl_inputs), cfg.runs, max(cfg.warmup, 1))
        if runtime == "onnxruntime":
            import onnxruntime

            with tempfile.TemporaryDirectory() as folder:
                path = export_onnx(graph, inputs, Path(folder) / "frame.onnx", names, ["image"], {})
                options = onnxruntime.SessionOptions()
                if cfg.threads:
                    options.intra_op_num_threads = cfg.threads
                session = onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
            feed = {name: tensor.numpy() for name, tensor in zip(names, inputs)}
            return median_ms(lambda: session.run(None, feed), cfg.runs, cfg.warmup)
    except Exception as exc:  # a runtime that cannot run this graph is a table entry, not a crash
        reason = str(exc).strip().splitlines()[0][:80] if str(exc).strip() else ""
        return f"failed: {type(exc).__name__}: {reason}"
    finally:
        graph.to(memory_format=torch.contiguous_format)
    raise ValueError(f"unknown runtime {runtime!r}")


def run_bench_models(cfg: BenchModelsConfig) -> list[dict]:
    """Print the machine, its conv peak and one table row per (preset, variant); return the rows."""
    try:
        from lsr.eval.machine import machine_markdown

        print(machine_markdown())
    except ImportError:  # lsr.eval.machine is optional here
        import platform

        print(f"machine: {platform.processor() or platform.machine()}, {torch.get_num_threads()} torch threads")
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    presets = PRESET_NAMES if "all" in cfg.presets else cfg.presets
    variants = VARIANTS if "all" in cfg.variants else cfg.variants
    peak = conv_peak_gflops(cfg.runs)
    print(f"\nconv peak (256->256 3x3, channels-last, fp32, 64x64): {peak:.0f} GFLOP/s, {torch.get_num_threads()} threads")
    print("GFLOP = 2 x multiply-accumulates of convs/matmuls (FlopCounterMode); ms = median, batch 1, fp32\n")

    header = ["preset", "variant", "res", "params E / frame", "GFLOP/frame"] + [f"{r} ms (% peak)" for r in cfg.runtimes]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    rows = []
    for preset, variant in tqdm([(p, v) for p in presets for v in variants], desc="bench models", leave=False):
        overrides = {"variant": variant}
        if cfg.resolution:
            overrides["resolution"] = cfg.resolution
        config = preset_config(preset, **overrides)
        torch.manual_seed(0)
        model = LSRModel(config).eval()
        graph = FrameGeneratorGraph(model.frame_generator, with_layout=False).eval()
        names = frame_graph_io(model.frame_generator, with_layout=False)[0]
        inputs = frame_inputs(config, names)
        gflop = count_gflop(graph, inputs)
        row = {
            "preset": preset,
            "variant": variant,
            "resolution": config.resolution,
            "params_encoder": sum(p.numel() for p in model.subject_encoder.parameters()),
            "params_frame": sum(p.numel() for p in model.frame_generator.parameters()),
            "gflop": gflop,
        }
        cells = []
        for runtime in cfg.runtimes:
            result = time_runtime(runtime, graph, inputs, names, cfg)
            row[runtime] = result
            if isinstance(result, str):
                cells.append(result)
            else:
                cells.append(f"{result:.1f} ({100 * gflop / (result / 1e3) / peak:.0f}%)")
        rows.append(row)
        params = f"{row['params_encoder'] / 1e6:.2f}M / {row['params_frame'] / 1e6:.2f}M"
        print(f"| {preset} | {variant} | {config.resolution} | {params} | {gflop:.2f} | " + " | ".join(cells) + " |")
    timed = [
        (min(v for k, v in row.items() if k in cfg.runtimes and isinstance(v, float)), row)
        for row in rows
        if any(isinstance(row.get(r), float) for r in cfg.runtimes)
    ]
    meeting = [f"{row['preset']}/{row['variant']} ({ms:.1f} ms)" for ms, row in timed if row["resolution"] == 256 and ms <= TARGET_MS]
    print(f"\n<= {TARGET_MS:.0f} ms/frame at 256^2 on this machine: {', '.join(meeting) if meeting else 'none'}")
    return rows
