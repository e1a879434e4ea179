"""``lsr bench reenact``: end-to-end fps of ``lsr reenact`` on a real clip, per stage and per runtime.

For each runtime (torch, onnx) the clip's first N frames (a trimmed copy, audio kept) drive a subject encoded
from the same clip, written exactly as ``lsr reenact`` writes (``lsr.commands.reenact.run_job``). Stages: decode,
landmarks (tracking, smoothing, crop transform, retargeting), subject encoding (once), warps (the landmark image
and the nearest shots warped onto the target), network (the generator, its conversions and mouth step),
paste-back, encode (H.264 + audio mux). "synthesis only" times one frame's warps and network one after the other,
what a loop without overlapping stages would get at best. Goals: end-to-end >= 20 fps and >= 0.8x synthesis-only.
Also prints the bf16 error against fp32. The shipped default is timed unless --weights names another model or
--preset a randomly initialised one.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from lsr.config import BenchReenactConfig
from landmarks.io.video import trim_clip
from lsr.bench.bench_landmarks import default_video
from lsr.core.finish import set_parts

LIDS_SAY = {"drawn": "the drawn lids", "driver": "the driver's shut lids"}
"""How the table names each ``--lids`` choice timed against "shots"."""


def reenact_defaults() -> tuple[str, str]:
    """What ``lsr reenact`` runs when told nothing: (runtime, detector), "auto" resolved."""
    from lsr.config import ReenactConfig

    options = ReenactConfig()
    return options.resolved_runtime, options.detector


def _parts(reenactor) -> tuple[str, str, str, str]:
    """A reenactor's mouth, eyes, mouth interior and lids."""
    return reenactor.mouth, reenactor.eyes, reenactor.mouth_interior, reenactor.lids


def synthesis_only_ms(reenactor, repeats: int = 20) -> float:
    """Median ms of one frame's synthesis at the subject's anchor pose (after one warm-up): what ``lsr reenact``
    times as its synthesis stage (the landmark image, a warp-guided model's warps of its nearest shots, the network,
    the conversions), so it works for every variant."""
    target = reenactor.subject.reference_landmarks
    times = []
    for _ in range(repeats + 1):
        started = time.perf_counter()
        reenactor.synthesize_crop(target)
        times.append(time.perf_counter() - started)
    return float(np.median(times[1:]) * 1000)


def _job_options(paste_back: bool, runtime: str):
    """What ``run_job`` reads of a ``ReenactConfig``: its defaults (so a new reenact option is benched at its default)
    with this run's paste-back and runtime, and no progress bar."""
    from lsr.config import ReenactConfig

    options = ReenactConfig()
    options.paste_back, options.runtime, options.progress = paste_back, runtime, False
    return options


def run_bench_reenact(cfg: BenchReenactConfig) -> str:
    from lsr.export.bundle import export_graphs
    from lsr.core.overlap import network_threads
    from lsr.eval.machine import machine_markdown, shown_path, usable_cores
    from lsr.pipeline import Reenactor, load_mouth
    from lsr.weights import resolve_weights
    from lsr.devices import resolve_device
    from lsr.commands.reenact import Job, run_job
    from models_def import LSRModel, preset_config

    video = cfg.video or default_video()
    device = resolve_device(cfg.device)
    rows, notes = [], []
    with tempfile.TemporaryDirectory(prefix="lsr-bench-reenact-") as temp:
        temp = Path(temp)
        if cfg.preset is not None:
            weights = LSRModel(preset_config(cfg.preset, resolution=cfg.resolution)).save_pretrained(temp / "weights")
            label = f"{cfg.preset} (random init) at {cfg.resolution}^2"
        else:
            weights = resolve_weights(cfg.weights)
            label = "the shipped default" if cfg.weights is None else f"`{shown_path(weights)}`"
        clip = trim_clip(video, temp / "driving.mp4", cfg.frames)
        synthesis_ms: dict[tuple[str, str], dict[str, float]] = {}
        fps: dict[tuple[str, str, str], dict[str, float]] = {}  # end to end, per eyes choice
        inside_fps: dict[tuple[str, str, str, str], dict[str, float]] = {}  # end to end, per mouth interior
        lids_fps: dict[tuple[str, str, str, str, str], dict[str, float]] = {}  # end to end, per lids choice
        mouths, eyes_choices = cfg.mouths or (None,), cfg.eyes or (None,)
        interiors, lids_choices = cfg.mouth_interiors or (None,), cfg.lids or (None,)
        warmed: set[tuple[str, str]] = set()
        default_fps: dict[str, float] = {}  # end to end, per runtime, with everything else as lsr reenact runs it
        default_runtime, default_detector = reenact_defaults()
        for runtime, detector, mouth, eyes, interior, lids in [
                (r, d, m, e, i, s) for r in cfg.runtimes for d in cfg.detectors for m in mouths
                for e in eyes_choices for i in interiors for s in lids_choices]:
            threads = network_threads(cfg.threads)  # as lsr reenact chooses them
            if runtime == "onnx":
                from deploy.runtime import OnnxReenactor

                if not (temp / "onnx").is_dir():
                    export_graphs(Reenactor(weights).model, temp / "onnx", mouth_generator=load_mouth(weights))
                reenactor = OnnxReenactor(temp / "onnx", threads=threads, detector=detector)
            else:
                import torch

                torch.set_num_threads(threads)
                reenactor = Reenactor(weights, device=device, detector=detector)
            model_parts = _parts(reenactor)
            set_parts(reenactor, mouth=mouth, eyes=eyes, mouth_interior=interior, lids=lids)
            as_default = detector == default_detector and _parts(reenactor) == model_parts  # lsr reenact told nothing
            started = time.perf_counter()
            reenactor.encode_subject(clip, k=cfg.k)
            encode_subject_s = time.perf_counter() - started
            if (runtime, detector) not in warmed:  # a runtime's first job (imports, allocations, caches): untimed,
                warmed.add((runtime, detector))  # or the first of rows compared in one run starts slower
                run_job(reenactor, Job(clip, clip, temp / f"warm_{runtime}_{detector}.mp4"),
                        _job_options(cfg.paste_back, runtime))
            synth_ms = synthesis_only_ms(reenactor)
            started, cpu_started = time.perf_counter(), time.process_time()
            synthesis_ms.setdefault((runtime, detector), {})[reenactor.mouth] = synth_ms
            name = (f"out_{runtime}_{detector}_{reenactor.mouth}_{reenactor.eyes}_{reenactor.mouth_interior}_"
                    f"{reenactor.lids}.mp4")
            stats = run_job(reenactor, Job(clip, clip, temp / name), _job_options(cfg.paste_back, runtime))
            wall = time.perf_counter() - started
            cores = (time.process_time() - cpu_started) / wall  # the process's CPU time, every thread's, over the job
            rate = stats.frames / wall  # end to end: the rows and every ratio below read this one number
            fps.setdefault((runtime, detector, reenactor.mouth), {})[reenactor.eyes] = rate
            inside_fps.setdefault((runtime, detector, reenactor.mouth, reenactor.eyes), {})[reenactor.mouth_interior] = rate
            lids_fps.setdefault((runtime, detector, reenactor.mouth, reenactor.eyes, reenactor.mouth_interior),
                                {})[reenactor.lids] = rate
            if as_default:
                default_fps[runtime] = rate
            per_frame = {stage: 1000 * stats.seconds.get(stage, 0.0) / max(1, stats.frames)
                         for stage in ("decode", "landmarks", "warps", "synthesis", "paste_back", "encode")}
            rows.append(
                f"| {runtime} | {detector} | {reenactor.mouth} | {reenactor.eyes} | {reenactor.mouth_interior} | "
                f"{reenactor.lids} | "
                f"{stats.frames} | {stats.no_face} | {per_frame['decode']:.1f} | {per_frame['landmarks']:.1f} | "
                f"{encode_subject_s:.2f} | {per_frame['warps']:.1f} | {per_frame['synthesis']:.1f} | {per_frame['paste_back']:.1f} | "
                f"{per_frame['encode']:.1f} | {rate:.2f} | {synth_ms:.1f} ({1000 / synth_ms:.2f} fps) | "
                f"{rate * synth_ms / 1000:.2f} | {cores:.2f} |"
            )
            if (runtime == "torch" and detector == cfg.detectors[0] and mouth == mouths[0] and eyes == eyes_choices[0]
                    and interior == interiors[0] and lids == lids_choices[0]):
                lm = reenactor.subject.shots.landmarks
                notes.append(f"bf16 (torch, {device}): {reenactor.precision_error(list(lm), 'bf16')}")
    table = "\n".join([
        f"Model {label}, {cfg.frames} frames of {video.name}, paste-back {cfg.paste_back}, device {device}, "
        f"network threads {network_threads(cfg.threads)}",
        "",
        "| runtime | detector | mouth | eyes | mouth interior | lids | frames | no face | decode ms | landmarks ms "
        "| subject encoding s | warps ms | network ms | paste-back ms | encode ms | end-to-end fps | synthesis only ms "
        "| end-to-end / synthesis-only | cores busy |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        *[f"Synthesis only, {runtime} / {detector}: the drawn mouth costs {times['drawn'] / times['nearest']:.2f}x "
          f"the per-frame path without it ({times['drawn']:.1f} against {times['nearest']:.1f} ms, same run)."
          for (runtime, detector), times in synthesis_ms.items() if {"drawn", "nearest"} <= set(times)],
        *[f"End to end, {runtime} / {detector} / {mouth} mouth: {eyes} eyes run at {rates[eyes] / rates['blend']:.2f}x "
          f"the frame rate of blended ones ({rates[eyes]:.2f} against {rates['blend']:.2f} fps, same run)."
          for (runtime, detector, mouth), rates in fps.items() for eyes in ("drawn", "warped") if {eyes, "blend"} <= set(rates)],
        *[f"End to end, {runtime} / {detector} / {mouth} mouth / {eyes} eyes: the driver's mouth interior runs at "
          f"{rates['driver'] / rates['shots']:.2f}x the frame rate without it ({rates['driver']:.2f} against "
          f"{rates['shots']:.2f} fps, same run)."
          for (runtime, detector, mouth, eyes), rates in inside_fps.items() if {"driver", "shots"} <= set(rates)],
        *[f"End to end, {runtime} / {detector} / {mouth} mouth / {eyes} eyes / {interior} interior: {LIDS_SAY[lids]} "
          f"run at {rates[lids] / rates['shots']:.2f}x the frame rate without them ({rates[lids]:.2f} "
          f"against {rates['shots']:.2f} fps, same run)."
          for (runtime, detector, mouth, eyes, interior), rates in lids_fps.items() for lids in LIDS_SAY
          if {lids, "shots"} <= set(rates)],
        *([f"`lsr reenact` as it runs when told nothing (--runtime auto = {default_runtime}, the {default_detector} "
           f"tracker, the model's parts): {default_fps[default_runtime]:.2f} fps end to end, "
           f"{default_fps[default_runtime] / default_fps['torch']:.2f}x the same with --runtime torch "
           f"({default_fps['torch']:.2f} fps, same run)."]
          if default_runtime != "torch" and {default_runtime, "torch"} <= set(default_fps) else []),
        "",
        "Stages overlap (lsr.core.overlap), each ms its time on its own thread, sharing the cores: decoding and "
        "tracking on one thread, smoothing, retargeting and the warps of the nearest shots on a second (landmarks ms "
        "= tracking plus smoothing and retargeting; warps ms = the landmark image and the warps), the network on the "
        "calling thread with all cores but one (network ms = the network and its mouth step; decode ms = what it "
        "waited for), each frame's paste-back on a worker behind it and encoding behind that. numpy's BLAS runs on "
        "one thread (lsr.core.overlap.single_blas_thread). Synthesis only = the warps and the network of one frame, "
        "one after the other. Cores busy = the process's CPU time over the job's wall time (every thread's): near the "
        f"machine's {usable_cores()}, the job is bound by the CPU; well under, by its stages' waits.",
        "Goals: end-to-end >= 20 fps and >= 0.8 x synthesis-only; the per-frame path <= 25 ms at 256^2.",
        *notes,
        "",
        machine_markdown(),
    ])
    from lsr.eval import sections

    sections.publish(cfg, "lsr bench reenact", "reenact", "End to end: `lsr reenact` per stage (`lsr bench reenact`)",
                     table)
    return table
