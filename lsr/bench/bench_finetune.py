"""``lsr bench finetune``: the steps-vs-error curve of subject fine-tuning (thesis §4.3.5), to choose its default.

For each fine-tuning budget, every identity of the evaluation data is fine-tuned on its K shots (drawn as in
``lsr eval``: ``protocol.sample_shots``) and scored on its hold-out frames: PSNR, SSIM and sharpness (the metrics of
``lsr.eval.metrics``), with the median wall time of one fine-tuning. The no-learning ``tps`` and ``tps_mean3``
baselines run on the same shots and frames, so every row compares with them in the same run. No face detection on
the outputs (NMKE / ID-SIM stay with ``lsr eval``): the curve is cheap enough to run on a CPU.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lsr.eval.machine import shown_path

if TYPE_CHECKING:
    from lsr.config import BenchFinetuneConfig

SECTION = "finetune_curve"


@dataclasses.dataclass
class CurveRow:
    method: str
    steps: int | None
    psnr: float
    ssim: float
    sharpness: float
    seconds: float | None
    """Median wall time of one subject's fine-tuning (None for the baselines)."""


def _score(outputs: np.ndarray, targets: np.ndarray) -> dict[str, np.ndarray]:
    from lsr.eval.metrics import mse, psnr_from_mse, sharpness, ssim

    return {"psnr": psnr_from_mse(mse(outputs, targets)), "ssim": ssim(outputs, targets), "sharpness": sharpness(outputs, targets)}


def _row(method: str, steps: int | None, scores: list[dict[str, np.ndarray]], seconds: list[float]) -> CurveRow:
    joined = {key: np.concatenate([s[key] for s in scores]) for key in ("psnr", "ssim", "sharpness")}
    finite = joined["psnr"][np.isfinite(joined["psnr"])]
    return CurveRow(method, steps, float(finite.mean()), float(joined["ssim"].mean()), float(np.nanmedian(joined["sharpness"])),
                    float(np.median(seconds)) if seconds else None)


def finetune_curve(cfg: BenchFinetuneConfig) -> tuple[list[CurveRow], dict[str, Any]]:
    """Rows: tps, tps_mean3, then the model at each budget of ``cfg.steps`` (0 = not fine-tuned)."""
    import torch
    from tqdm import tqdm

    from landmarks.detect.registry import make_detector
    from lsr.eval.baselines import TpsMean3, TpsWarp
    from lsr.eval.model_method import LsrModelMethod
    from lsr.eval.protocol import detect_layout, load_fsth_sample, load_lsr_split, sample_shots
    from lsr.weights import resolve_weights

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    data = cfg.resolved_data()
    if detect_layout(data) == "fsth":
        identities = load_fsth_sample(data, make_detector(), cache_dir=Path(cfg.out) / "cache", progress=cfg.progress)
    else:
        identities = load_lsr_split(data, "test")
    identities = identities[: cfg.max_identities] if cfg.max_identities else identities
    weights = resolve_weights(cfg.weights)
    model = LsrModelMethod(weights, device="cpu", finetune_steps=max(cfg.steps, default=0) or 1, finetune_lr=cfg.finetune_lr)
    scores: dict[tuple[str, int | None], list] = {}
    seconds: dict[int, list[float]] = {}
    bar = tqdm(total=len(identities) * (2 + len(cfg.steps)), desc="bench finetune", disable=not cfg.progress)
    for identity in identities:
        candidates = np.flatnonzero(np.isfinite(identity.input_landmarks).all(axis=(1, 2)))
        chosen = sample_shots(candidates, min(cfg.k, len(candidates)), cfg.seed, identity.name)
        shots = [identity.input_frames[i] for i in chosen]
        shot_landmarks = identity.input_landmarks[chosen].astype(np.float64)
        rows = np.flatnonzero(np.isfinite(identity.holdout_landmarks).all(axis=(1, 2)))
        rows = rows[: cfg.max_holdouts] if cfg.max_holdouts else rows
        targets, target_landmarks = identity.holdout_frames[rows], identity.holdout_landmarks[rows].astype(np.float64)
        for baseline in (TpsWarp(), TpsMean3()):
            scores.setdefault((baseline.name, None), []).append(_score(baseline.reenact(shots, shot_landmarks, target_landmarks), targets))
            bar.update(1)
        for steps in cfg.steps:
            method = model
            if steps:
                model.finetune_steps = steps
                started = time.perf_counter()
                method = model.finetune(shots, shot_landmarks)
                seconds.setdefault(steps, []).append(time.perf_counter() - started)
            scores.setdefault((model.name, steps), []).append(_score(method.reenact(shots, shot_landmarks, target_landmarks), targets))
            bar.update(1)
    bar.close()
    rows = [_row(name, steps, values, seconds.get(steps or 0, [])) for (name, steps), values in scores.items()]
    settings = {"data": str(data), "identities": [i.name for i in identities], "k": cfg.k, "seed": cfg.seed,
                "weights": str(weights), "finetune_lr": cfg.finetune_lr}
    return rows, settings


def curve_markdown(rows: list[CurveRow], settings: dict[str, Any], machine: str) -> str:
    lines = [f"K = {settings['k']} shots per identity ({len(settings['identities'])} identities of `{shown_path(settings['data'])}`, "
             f"seed {settings['seed']}); model `{shown_path(settings['weights'])}`, Adam lr {settings['finetune_lr']:g}.", "",
             "| method | fine-tuning steps | PSNR ↑ | SSIM ↑ | sharpness →1 | fine-tuning s (median per subject) |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        steps = "–" if row.steps is None else str(row.steps)
        spent = "–" if row.seconds is None else f"{row.seconds:.1f}"
        lines.append(f"| {row.method} | {steps} | {row.psnr:.2f} | {row.ssim:.3f} | {row.sharpness:.2f} | {spent} |")
    lines += ["", "PSNR: mean over hold-out frames (uint8, peak 255); SSIM: kornia 11x11 Gaussian; sharpness: median "
              "var(Laplacian(grey output)) / var(Laplacian(grey ground truth)), 1 = as sharp as the real frame.", "", machine]
    return "\n".join(lines)


def run_bench_finetune(cfg: BenchFinetuneConfig) -> list[CurveRow]:
    """Entry point of ``lsr bench finetune``: print the table (and write its BENCHMARKS.md section with --out-md)."""
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown

    rows, settings = finetune_curve(cfg)
    text = curve_markdown(rows, settings, machine_markdown())
    publish(cfg, "lsr bench finetune", SECTION, "Subject fine-tuning: steps against error (`lsr bench finetune`)", text)
    return rows
