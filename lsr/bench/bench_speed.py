"""``lsr bench speed``: one table that puts speed beside error, per preset x resolution x runtime.

Per row: parameters (subject encoder E / per-frame path G^l + G^s), GFLOP per frame, ms/frame of the per-frame
path (a warp-guided model's also warps its nearest shots in numpy first: ``warp ms``, and the blend runs at the
crop side, twice the resolution; ``total ms`` is both) and ms of subject encoding at K = 1 and K = 32 (medians of warm runs, batch 1), the fraction of this
machine's conv peak measured in the same run (``lsr.bench.bench_models``), and the error of the trained weights
of that preset through the thesis protocol (§4.4, ``lsr.eval.protocol``; meta-learned, no fine-tuning) on a
synthetic test split (and on the FSTH sample with ``--fsth``).

* Runtimes: torch eager / channels-last / torch.compile (fp32; they run the same math, so their error is
  computed once, with the torch pipeline), onnxruntime fp32 and onnxruntime int8 (the frame generator of
  ``lsr export --int8``: the network's convolutions static int8, the composite fp32; calibrated on the test
  identities' *input* frames; its error is computed with the int8 graph, so int8 vs fp32 shows in the table). The
  int8 bundle keeps the fp32 subject encoder.
* Timing uses the trained weights when their resolution matches the row, else a randomly initialised model
  of the same config (speed does not depend on the weights).
* Output: a markdown section between ``<!-- bench:speed:start -->`` / ``<!-- bench:speed:end -->`` in
  ``--out-md`` (replaced in place, the rest of the file kept; atomic), ``bench_speed.json`` beside the plot and a
  PNG of ms/frame against the error with the Pareto front (``lsr.bench.pareto``).
"""

from __future__ import annotations

import datetime
import math
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from lsr.config.shared import check_weights
from lsr.errors import ConfigError
from lsr.eval import sections
from lsr.bench.bench_models import conv_peak_gflops, count_gflop, frame_inputs, median_ms, time_runtime
from lsr.core.inputs import scale_points
from lsr.eval.model_method import LsrModelMethod
from lsr.bench.pareto import pareto_front, plot_speed_error, write_plot
from lsr.eval.machine import shown_path

if TYPE_CHECKING:
    from lsr.config import BenchSpeedConfig

SECTION_START = "<!-- bench:speed:start -->"
SECTION_END = "<!-- bench:speed:end -->"
RUNTIME_LABELS = {
    "eager": "torch eager fp32",
    "channels_last": "torch channels-last fp32",
    "compile": "torch.compile fp32",
    "onnxruntime": "onnxruntime fp32",
    "int8": "onnxruntime int8 (static, convolutions)",
}
TORCH_RUNTIMES = ("eager", "channels_last", "compile")
ENCODER_KS = (1, 32)
# The default synthetic test split: unseen identities (training renders with other seeds), fixed seed. One
# 64-frame video per person, so the 32 inputs and 32 hold-outs share background and light as in FSTH's test set.
SYNTH_SEED, SYNTH_IDENTITIES, SYNTH_VIDEOS, SYNTH_FRAMES = 1234, 12, 1, 64
# name -> (label, higher is better, the plot's smallest y span: about ten times the noise between runtimes of one
# model, so that such differences show as the near-ties they are)
METRICS = {"psnr": ("PSNR", True, 0.5), "ssim": ("SSIM", True, 0.01), "nmke": ("NMKE", False, 0.005)}


# ---- inputs ---------------------------------------------------------------------------------------------


def parse_weights(items: tuple[str, ...] | list[str]) -> dict[str, Path]:
    """``PRESET=DIR`` strings -> {preset: folder}; a bad item raises ConfigError saying what to pass."""
    parsed: dict[str, Path] = {}
    for item in items:
        preset, separator, folder = item.partition("=")
        if not separator or not preset or not folder:
            raise ConfigError(f"--weights takes PRESET=DIR items (e.g. tiny=runs/tiny/weights), got {item!r}")
        check_weights(folder, f"--weights {preset}:")
        parsed[preset] = Path(folder)
    return parsed


def training_provenance(weights: Path) -> str:
    """'N steps, ~M min' of the `lsr train` run that wrote ``weights`` (RUN/weights), from its newest checkpoint
    and its TensorBoard start time; '' when the run folder is not beside the weights."""
    from lsr.train.checkpoint import latest_checkpoint

    newest = latest_checkpoint(weights.parent / "checkpoints")
    if newest is None:
        return ""
    steps = int(re.findall("[0-9]+", newest.name)[-1])
    text = f"{steps} steps"
    events = sorted((weights.parent / "tensorboard").glob("events.out.tfevents.*"))
    if events:
        started = float(events[0].name.split(".")[3])
        text += f", ~{(newest.stat().st_mtime - started) / 60:.1f} min"
    return text


def synthetic_split(cfg: BenchSpeedConfig, size: int) -> Path:
    """``cfg.synthetic_root``, or a small fixed-seed synthetic dataset rendered once into the cache folder."""
    if cfg.synthetic_root is not None:
        if not (Path(cfg.synthetic_root) / "manifest.json").is_file():
            raise ConfigError(f"--synthetic-root {cfg.synthetic_root} has no manifest.json; make one with `lsr synth`")
        return Path(cfg.synthetic_root)
    cache = Path(cfg.cache_dir) if cfg.cache_dir is not None else Path.home() / ".cache" / "lsr" / "bench_speed"
    return held_out_synthetic_split(cache, size, SYNTH_VIDEOS, SYNTH_FRAMES, progress=cfg.progress)


def held_out_synthetic_split(folder: Path, size: int, videos: int, frames: int, *, progress: bool = False) -> Path:
    """SYNTH_IDENTITIES procedural people of the fixed SYNTH_SEED (never a training seed), half of them 'test',
    rendered once into ``folder`` (lsr synth's default, aligned framing) and reused after; the dataset root."""
    from lsr.data.synth import generate_dataset

    root = Path(folder) / f"synth_test_{size}_seed{SYNTH_SEED}_{SYNTH_IDENTITIES}x{videos}x{frames}_aligned"
    if not (root / "manifest.json").is_file():
        generate_dataset(root, SYNTH_IDENTITIES, videos, frames, size=size, seed=SYNTH_SEED, test_fraction=0.5,
                         progress=progress, overwrite=True)
    return root


# ---- speed ----------------------------------------------------------------------------------------------


def onnx_session(path: Path, threads: int):
    import onnxruntime

    options = onnxruntime.SessionOptions()
    if threads:
        options.intra_op_num_threads = threads
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def encoder_inputs(config, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(shots, shot_landmark_images): (1, K, 3, S, S) each in [-1, 1], seeded."""
    generator = torch.Generator().manual_seed(k)
    shape = (1, k, 3, config.resolution, config.resolution)
    return torch.rand(shape, generator=generator) * 2 - 1, torch.rand(shape, generator=generator) * 2 - 1


def time_encoder(runtime: str, model, k: int, runs: int, warmup: int, session=None) -> float | str:
    """Median ms of encoding K shots (batch 1) in ``runtime`` (``session``: the ONNX subject encoder), or 'failed: ...'."""
    shots, landmark_images = encoder_inputs(model.config, k)
    try:
        if runtime in ("onnxruntime", "int8"):
            feed = {"shots": shots.numpy(), "shot_landmark_images": landmark_images.numpy()}
            return median_ms(lambda: session.run(None, feed), runs, warmup)
        encoder = model.subject_encoder
        if runtime in ("channels_last", "compile"):
            encoder = encoder.to(memory_format=torch.channels_last)
            if runtime == "compile":
                encoder = torch.compile(encoder)
        with torch.inference_mode():
            return median_ms(lambda: encoder(shots, landmark_images), runs, max(warmup, 1 if runtime == "compile" else 0))
    except Exception as exc:  # a runtime that cannot run this graph is a table entry, not a crash
        return f"failed: {type(exc).__name__}: {str(exc).strip()[:80]}"
    finally:
        model.subject_encoder.to(memory_format=torch.contiguous_format)


def time_onnx_frame(path: Path, config, threads: int, runs: int, warmup: int) -> float | str:
    try:
        session = onnx_session(path, threads)
        names = [i.name for i in session.get_inputs()]
        feed = {name: tensor.numpy() for name, tensor in zip(names, frame_inputs(config, names))}
        return median_ms(lambda: session.run(["image"], feed), runs, warmup)
    except Exception as exc:  # as time_runtime: a failing runtime is a table entry
        return f"failed: {type(exc).__name__}: {str(exc).strip()[:80]}"


def build_bundle(model, folder: Path, calibration: list[dict[str, np.ndarray]] | None) -> Path:
    """fp32 ONNX bundle of ``model`` in ``folder`` (+ int8 frame generator when ``calibration`` is given)."""
    from lsr.export.bundle import FRAME_GENERATOR_FILE, FRAME_GENERATOR_INT8_FILE, export_graphs, quantize_frame_generator

    export_graphs(model, folder)
    if calibration is not None:
        import logging

        root_logger = logging.getLogger()
        level = root_logger.level
        root_logger.setLevel(logging.ERROR)  # onnxruntime's "consider pre-processing" advice, once per graph, would bury the table
        try:
            quantize_frame_generator(folder / FRAME_GENERATOR_FILE, folder / FRAME_GENERATOR_INT8_FILE, calibration)
        finally:
            root_logger.setLevel(level)
    return folder


def random_calibration(model, count: int = 8) -> list[dict[str, np.ndarray]]:
    """Seeded random frame-graph inputs (speed-only rows: no trained weights, no error to protect)."""
    from lsr.export.graphs import frame_graph_io

    names = frame_graph_io(model.frame_generator, with_layout=False)[0]
    feeds = []
    for seed in range(count):
        torch.manual_seed(seed)
        landmark_image, *latents = frame_inputs(model.config, names)
        feeds.append({name: t.numpy() for name, t in zip(names, (landmark_image, *[x * (1 + seed / count) for x in latents]))})
    return feeds


def time_warps(config, identities, runs: int, warmup: int) -> float | None:
    """Median ms of ``landmarks.warp.tps.warp_references`` for one frame of a warp-guided model at its default crop side:
    the nearest of 8 input shots of the first identity warped onto its other input frames (None for other models)."""
    import time

    import cv2

    from landmarks.warp.tps import warp_references

    if not config.uses_references or not identities:
        return None
    identity, crop = identities[0], config.crop_scale * config.resolution
    usable = np.flatnonzero(np.isfinite(identity.input_landmarks).all(axis=(1, 2)))
    scale = crop / identity.input_frames.shape[1]
    shots = np.stack([cv2.resize(identity.input_frames[i], (crop, crop), interpolation=cv2.INTER_LINEAR) for i in usable[:8]])
    points = scale_points(identity.input_landmarks[usable], scale)
    targets = points[8:] if len(points) > 8 else points
    times = []
    for index in range(warmup + runs):
        started = time.perf_counter()
        warp_references(shots, points[:8], targets[index % len(targets)], config.warp_references)
        times.append((time.perf_counter() - started) * 1e3)
    return float(np.median(times[warmup:]))


# ---- error ----------------------------------------------------------------------------------------------


class OnnxModelMethod(LsrModelMethod):
    """``LsrModelMethod`` whose re-enactor is ``deploy.runtime.OnnxReenactor`` over an ONNX bundle (fp32 or int8).

    Same resizing and shot encoding as the torch method (only the backend differs); no fine-tuning."""

    def __init__(self, bundle: Path, *, int8: bool, name: str, threads: int = 0) -> None:  # noqa: D107
        from deploy.runtime import OnnxReenactor

        reenactor = OnnxReenactor(bundle, int8=int8, providers=["CPUExecutionProvider"], threads=threads)
        super().__init__(bundle, name=name, reenactor=reenactor)


def identity_calibration(method: LsrModelMethod, identities, frames: int = 32, k: int = 8) -> list[dict[str, np.ndarray]]:
    """Frame-graph inputs from the identities' *input* frames (never the hold-outs that are scored), as
    ``ReenactorBase.network_inputs`` makes them for ``lsr reenact`` at the exported graph's crop side
    (``default_crop_size``): each identity's latents from its first K inputs, landmark images of its inputs and, for
    a warp-guided model, its shots warped onto them."""
    from lsr.core.engine import default_crop_size
    from lsr.core.inputs import resize_shots
    from lsr.pipeline import subject_shots_from_training

    reenactor = method.reenactor
    previous, crop = reenactor.crop_size, default_crop_size(reenactor.backend)
    reenactor.crop_size = crop
    feeds: list[dict[str, np.ndarray]] = []
    per_identity = max(1, math.ceil(frames / max(1, len(identities))))
    try:
        for identity in identities:
            usable = np.flatnonzero(np.isfinite(identity.input_landmarks).all(axis=(1, 2)))
            if not len(usable):
                continue
            shots = np.stack([identity.input_frames[i] for i in usable[:k]])
            reenactor.encode_subject(resize_shots(subject_shots_from_training(shots, identity.input_landmarks[usable[:k]]),
                                                  crop))
            points = scale_points(identity.input_landmarks[usable].astype(np.float64), crop / shots.shape[1])
            for target in points[:per_identity]:
                _, inputs = reenactor.network_inputs(target)
                feeds.append({name: np.asarray(value, np.float32) for name, value in inputs.items()})
    finally:  # the method encodes its own shots again at its own side
        reenactor.crop_size = previous
        method._encoded = None
    return feeds[:frames]


def protocol_errors(methods: list, identities, ks: tuple[int, ...], detector, max_holdouts: int, progress: bool) -> dict[str, dict]:
    """{method name: {K: {psnr, ssim, nmke, idsim, no_face, frames}}} through ``run_protocol`` (meta-learned only)."""
    from lsr.eval.analysis import FaceAnalysis
    from lsr.eval.protocol import run_protocol
    from lsr.eval.report import summarise

    run = run_protocol(methods, identities, ks, FaceAnalysis(detector), max_holdouts=max_holdouts,
                       cross_identity=False, finetune=False, progress=progress)
    errors: dict[str, dict] = {}
    for row in summarise(run)["rows"]:
        errors.setdefault(row["method"], {})[int(row["k"])] = {
            key: row[key] for key in ("psnr", "ssim", "nmke", "idsim", "no_face", "frames")
        }
    return errors


# ---- the run --------------------------------------------------------------------------------------------


def _ms(value: Any) -> str:
    return f"{value:.1f}" if isinstance(value, float) else str(value)


def _error_cell(errors: Any, k: int) -> str:
    if isinstance(errors, str):
        return errors
    at_k = errors.get(k)
    if at_k is None:
        return "–"
    nmke = "–" if not math.isfinite(at_k["nmke"]) else f"{at_k['nmke']:.3f}"
    return f"{at_k['psnr']:.2f} / {at_k['ssim']:.3f} / {nmke}"


def not_computed(preset: str, weights: Path | None, weights_resolution: int | None, resolution: int) -> str:
    if weights is None:
        return f"not computed (no trained weights for {preset}; train with lsr train --preset {preset} ...)"
    return f"not computed (weights of {preset} are {weights_resolution}²; train at --resolution {resolution})"


def bench_rows(cfg: BenchSpeedConfig, weights: dict[str, Path], splits: dict[str, list], detector, peak: float, temp: Path) -> list[dict]:
    """Time every (preset, resolution, runtime) and attach the errors; returns the rows."""
    from tqdm import tqdm

    from lsr.export.graphs import FrameGeneratorGraph, frame_graph_io
    from lsr.pipeline import load_model
    from models_def import LSRModel, preset_config

    rows = []
    combos = [(p, r) for p in cfg.presets for r in cfg.resolutions]
    for preset, resolution in tqdm(combos, desc="bench speed", disable=not cfg.progress):
        trained = load_model(weights[preset]) if preset in weights else None
        matches = trained is not None and trained.config.resolution == resolution
        if matches:
            model = trained
        else:
            torch.manual_seed(0)
            if trained is not None:  # the trained model's widths at another network side, blending at its crop side
                crop = trained.config.crop_scale * trained.config.resolution
                config = trained.config.replace(resolution=resolution, crop_scale=min(8, max(1, crop // resolution)))
            else:
                config = preset_config(preset, resolution=resolution)
            model = LSRModel(config).eval().requires_grad_(False)
        graph = FrameGeneratorGraph(model.frame_generator, with_layout=False).eval()
        names = frame_graph_io(model.frame_generator, with_layout=False)[0]
        gflop = count_gflop(graph, frame_inputs(model.config, names))
        base = {"preset": preset, "resolution": resolution, "weights": str(weights[preset]) if matches else None,
                "params_encoder": sum(p.numel() for p in model.subject_encoder.parameters()),
                "params_frame": sum(p.numel() for p in model.frame_generator.parameters()), "gflop": gflop}

        torch_method = LsrModelMethod(weights[preset], name=f"{preset}@{resolution}:torch") if matches else None
        bundle = None
        if {"onnxruntime", "int8"} & set(cfg.runtimes):
            calibration = None
            if "int8" in cfg.runtimes:
                calibration = identity_calibration(torch_method, splits["synthetic"]) if matches else random_calibration(model)
            bundle = build_bundle(model, temp / f"{preset}_{resolution}", calibration)
        errors: dict[str, Any] = {}
        if matches:
            methods = []
            if set(TORCH_RUNTIMES) & set(cfg.runtimes):
                methods.append(torch_method)
            if "onnxruntime" in cfg.runtimes:
                methods.append(OnnxModelMethod(bundle, int8=False, name=f"{preset}@{resolution}:onnxruntime", threads=cfg.threads))
            if "int8" in cfg.runtimes:
                methods.append(OnnxModelMethod(bundle, int8=True, name=f"{preset}@{resolution}:int8", threads=cfg.threads))
            for split, identities in splits.items():
                errors[split] = protocol_errors(methods, identities, cfg.k, detector, cfg.max_holdouts, cfg.progress)
        encoder_session = None
        base["warp_ms"] = time_warps(model.config, splits["synthetic"], cfg.runs, cfg.warmup)
        for runtime in cfg.runtimes:
            row = {**base, "runtime": runtime, "runtime_label": RUNTIME_LABELS[runtime]}
            if runtime in TORCH_RUNTIMES:
                row["frame_ms"] = time_runtime(runtime, graph, frame_inputs(model.config, names), names, cfg)
            else:
                frame_file = "frame_generator.int8.onnx" if runtime == "int8" else "frame_generator.onnx"
                row["frame_ms"] = time_onnx_frame(bundle / frame_file, model.config, cfg.threads, cfg.runs, cfg.warmup)
                encoder_session = encoder_session or onnx_session(bundle / "subject_encoder.onnx", cfg.threads)
            row["peak_fraction"] = gflop / (row["frame_ms"] / 1e3) / peak if isinstance(row["frame_ms"], float) else None
            row["total_ms"] = row["frame_ms"] + (row["warp_ms"] or 0.0) if isinstance(row["frame_ms"], float) else row["frame_ms"]
            row["encode_ms"] = {}
            for k in ENCODER_KS:
                previous = next((r for r in rows if r["preset"] == preset and r["resolution"] == resolution
                                 and r["runtime"] == "onnxruntime"), None)
                if runtime == "int8" and previous is not None:  # the int8 bundle runs the same fp32 encoder graph
                    row["encode_ms"][k] = previous["encode_ms"][k]
                else:
                    row["encode_ms"][k] = time_encoder(runtime, model, k, cfg.runs if k == 1 else cfg.encoder_runs,
                                                       cfg.warmup if k == 1 else 1, encoder_session)
            method_key = f"{preset}@{resolution}:{'torch' if runtime in TORCH_RUNTIMES else runtime}"
            for split in ("synthetic", "fsth"):
                if split not in splits:
                    continue
                reason = not_computed(preset, weights.get(preset), trained.config.resolution if trained else None, resolution)
                row[f"error_{split}"] = errors[split].get(method_key, reason) if matches else reason
            rows.append(row)
    return rows


def pareto_points(rows: list[dict], metric: str, k: int) -> tuple[list[tuple[float, float]], list[str], list[str], list[int]]:
    """(ms/frame, metric at K on the synthetic split) per row that has both; labels, groups, row indices."""
    points, labels, groups, indices = [], [], [], []
    for index, row in enumerate(rows):
        errors = row.get("error_synthetic")
        if isinstance(row["total_ms"], float) and isinstance(errors, dict) and k in errors:
            value = errors[k][metric]
            if value is not None and math.isfinite(value):
                points.append((row["total_ms"], float(value)))
                labels.append(f"{row['preset']}/{row['resolution']}/{row['runtime']}")
                groups.append(row["runtime_label"])
                indices.append(index)
    return points, labels, groups, indices


def section_markdown(cfg: BenchSpeedConfig, rows: list[dict], peak: float, provenance: dict[str, str], plot_link: str,
                     front_labels: list[str], machine: str, command: str) -> str:
    """The BENCHMARKS.md section (markers included)."""
    splits = [s for s in ("synthetic", "fsth") if any(f"error_{s}" in r for r in rows)]
    header = ["preset", "res", "runtime", "params E / G", "GFLOP/frame", "ms/frame", "% conv peak", "warp ms", "total ms",
              "encode K=1 ms", "encode K=32 ms"]
    header += [f"{'synthetic' if s == 'synthetic' else 'FSTH'} K={k}: PSNR / SSIM / NMKE" for s in splits for k in cfg.k]
    lines = [SECTION_START, "## Speed vs error (`lsr bench speed`)", "",
             f"_Written by the command below on {datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}; "
             "do not edit the numbers by hand, re-run it._", "", f"```\n{command}\n```", ""]
    if cfg.note:
        lines += [f"**Note:** {cfg.note}", ""]
    for name, text in provenance.items():
        lines.append(f"- {name}: {text}")
    lines += [
        f"- ms: median of {cfg.runs} warm runs, batch 1 (encode K=32: median of {cfg.encoder_runs}); the per-frame path is "
        "G^l + G^s (``FrameGeneratorGraph``; warp_guided: with the blend at the crop side, crop_scale x the resolution); warp ms: "
        "a warp-guided model's TPS warps of its nearest shots (numpy, one thread); total = both; % conv peak = GFLOP/frame ÷ time ÷ the fp32 conv peak "
        f"measured in this run ({peak:.0f} GFLOP/s; int8 rows against the same fp32 peak).",
        "- GFLOP = 2 × multiply-accumulates of convs/matmuls (``FlopCounterMode``).",
        f"- error: thesis protocol (§4.4), meta-learned (no fine-tuning), K = {', '.join(map(str, cfg.k))}; PSNR / SSIM "
        "/ NMKE (NMKE: – when no face was detected in any output). The torch runtimes share one error (same fp32 math); "
        "int8 is scored with the int8 graph.",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for row in rows:
        peak_cell = f"{100 * row['peak_fraction']:.0f}%" if row["peak_fraction"] is not None else "–"
        cells = [row["preset"], str(row["resolution"]), row["runtime_label"],
                 f"{row['params_encoder'] / 1e6:.2f}M / {row['params_frame'] / 1e6:.2f}M", f"{row['gflop']:.2f}",
                 _ms(row["frame_ms"]), peak_cell, "–" if row["warp_ms"] is None else _ms(row["warp_ms"]),
                 _ms(row["total_ms"]), _ms(row["encode_ms"][1]), _ms(row["encode_ms"][32])]
        cells += [_error_cell(row.get(f"error_{s}"), k) for s in splits for k in cfg.k]
        lines.append("| " + " | ".join(cells) + " |")
    label, _, _ = METRICS[cfg.pareto_metric]
    lines += ["", f"Pareto front (ms/frame vs synthetic {label} at K={max(cfg.k)}): "
              + (", ".join(front_labels) if front_labels else "no row has both a time and an error"), "",
              f"![ms/frame vs {label}]({plot_link})", "", machine, "", SECTION_END]
    return "\n".join(lines) + "\n"


def replace_section(path: Path, section: str, start: str = SECTION_START, end: str = SECTION_END) -> Path:
    """``lsr.eval.sections.replace_section`` with this command's markers as the default."""
    return sections.replace_section(path, section, start, end)


def command_line(cfg: BenchSpeedConfig, prog: str = "lsr bench speed") -> str:
    return sections.command_line(cfg, prog)


def _json_ready(rows: list[dict]) -> list[dict]:
    from lsr.eval.report import json_safe

    return json_safe([{k: ({str(kk): vv for kk, vv in v.items()} if isinstance(v, dict) else v) for k, v in row.items()} for row in rows])


def run_bench_speed(cfg: BenchSpeedConfig) -> dict[str, Any]:
    """Entry point of ``lsr bench speed`` (``lsr.config.BenchSpeedConfig``): print and write the table, JSON, plot."""
    from landmarks.detect.registry import make_detector
    from landmarks.io.image_files import write_json
    from lsr.eval.protocol import load_fsth_sample, load_lsr_split
    from lsr.eval.machine import machine_info, machine_markdown

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    weights = parse_weights(cfg.weights)
    unknown = sorted(set(weights) - set(cfg.presets))
    if unknown:
        raise ConfigError(f"--weights for {', '.join(unknown)} but --presets is {' '.join(cfg.presets)}; add them to --presets")
    from lsr.pipeline import load_model

    weight_sizes = {p: load_model(w).config.resolution for p, w in weights.items()}
    out_md = Path(cfg.out_md)
    plot_path = Path(cfg.plot) if cfg.plot is not None else out_md.parent / "docs" / "bench_speed.png"
    detector = make_detector()
    split_root = synthetic_split(cfg, max(weight_sizes.values(), default=min(cfg.resolutions)))
    splits = {"synthetic": load_lsr_split(split_root, "test", cfg.inputs, cfg.holdouts)}
    first = splits["synthetic"][0]
    provenance = {"synthetic split": f"`{shown_path(split_root)}` (test identities {', '.join(i.name for i in splits['synthetic'])}; "
                                     f"{len(first.input_frames)} input + {len(first.holdout_frames)} hold-out frames each)"}
    if cfg.fsth:
        shared = Path(os.environ.get("LSR_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
        fsth_root = Path(cfg.fsth_root) if cfg.fsth_root is not None else shared / "fsth_eval_sample"
        if not fsth_root.is_dir():
            raise ConfigError(f"--fsth: {fsth_root} not found; pass --fsth-root FOLDER or drop --fsth")
        cache = (Path(cfg.cache_dir) if cfg.cache_dir else Path.home() / ".cache" / "lsr" / "bench_speed") / "fsth_landmarks"
        splits["fsth"] = load_fsth_sample(fsth_root, detector, cache_dir=cache, progress=cfg.progress)
    for preset, folder in weights.items():
        trained = training_provenance(folder)
        provenance[f"weights `{preset}`"] = f"`{folder}` ({weight_sizes[preset]}²" + (f"; {trained} of `lsr train`" if trained else "") + ")"
    peak = conv_peak_gflops(cfg.runs)
    with tempfile.TemporaryDirectory(prefix="lsr-bench-speed-") as temp:
        rows = bench_rows(cfg, weights, splits, detector, peak, Path(temp))

    metric_label, higher, min_span = METRICS[cfg.pareto_metric]
    points, labels, groups, indices = pareto_points(rows, cfg.pareto_metric, max(cfg.k))
    front = pareto_front(points, higher_y_is_better=higher)
    for position, index in enumerate(indices):
        rows[index]["pareto"] = position in front
    title = f"lsr bench speed: ms/frame vs synthetic {metric_label} (K={max(cfg.k)}), {machine_info()['cpu']}"
    write_plot(plot_path, plot_speed_error(points, labels, groups, y_label=f"{metric_label} (synthetic, K={max(cfg.k)})",
                                           higher_y_is_better=higher, title=title,
                                           min_y_span=min_span))
    command = command_line(cfg)
    section = section_markdown(cfg, rows, peak, provenance,
                               os.path.relpath(plot_path, out_md.parent), [labels[i] for i in front],
                               machine_markdown(), command)
    replace_section(out_md, section)
    json_path = plot_path.with_suffix(".json")  # the numbers beside their plot
    result = {"command": command, "machine": machine_info(), "conv_peak_gflops": peak, "note": cfg.note,
              "ks": list(cfg.k), "pareto_metric": cfg.pareto_metric, "provenance": provenance,
              "plot": str(plot_path), "rows": _json_ready(rows)}
    write_json(json_path, result)
    print(section)
    print(f"wrote the section to {out_md}, {json_path} and {plot_path}")
    return result
