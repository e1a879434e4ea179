"""``lsr bench ablation``: the thesis ablation study (§4.4.4, Table 4.2) on this project's data, resumable.

The four variants of Table 4.2 (``baseline``: landmarks into a UNet with AdaIN, FSTH's set-up; ``spade_landmarks``:
+SPADE; ``learned_seg``: +learned segmentation maps; ``latent_layout``: +latent layout, ours) train with one schedule
on one data set, each into OUT/<variant> by ``lsr.train.trainer.run_train``. Each is then scored single-shot (K = 1)
without fine-tuning by ``lsr eval``'s protocol (``lsr.eval.report.run_eval``) on the test split of the training data
(``--data``'s, and held-out synthetic identities) and on the FSTH sample. The tables give, per metric, each variant's
rank beside its rank in the thesis: the ordering is the point, not the absolute numbers (other data, smaller models,
a short schedule).

Resumable across sessions: a variant whose run reached its last step is skipped, a half-trained one continues from
its newest checkpoint (``lsr train --resume``), and OUT/ablation.json keeps the schedule, so that a rerun with other
training flags is refused instead of being mixed into the same table.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lsr.errors import ConfigError
from lsr.eval.machine import shown_path

if TYPE_CHECKING:
    from lsr.config import BenchAblationConfig

SECTION = "ablation"
VARIANTS = ("baseline", "spade_landmarks", "learned_seg", "latent_layout")
# key of an lsr.eval.report row -> (label, higher is better); the columns of Table 4.2
METRICS = {"psnr": ("PSNR", True), "ssim": ("SSIM", True), "lpips": ("LPIPS", False), "idsim": ("ID-SIM", True),
           "nmke": ("NMKE", False), "fid": ("FID", False)}
# Thesis Table 4.2 (VoxCeleb2, FSTH's test set, K = 1, no fine-tuning), values in METRICS order.
THESIS_TABLE_4_2: dict[str, tuple[str, tuple[float, ...]]] = {
    "baseline": ("Baseline", (17.00, 0.574, 0.274, 0.837, 0.044, 67.19)),
    "spade_landmarks": ("+ SPADE", (16.94, 0.575, 0.268, 0.834, 0.043, 56.00)),
    "learned_seg": ("+ learned seg. maps", (16.94, 0.578, 0.265, 0.828, 0.042, 62.78)),
    "latent_layout": ("+ latent layout (ours)", (17.22, 0.592, 0.247, 0.860, 0.042, 54.40)),
}
SCHEDULE_KEYS = ("preset", "steps", "batch_size", "k", "seed", "synthetic_identities")
"""The flags that must not change between the sessions of one OUT (the data is checked by the trainer)."""


# ---- ranks and tables ------------------------------------------------------------------------------------


def competition_ranks(values: dict[str, float | None], higher_is_better: bool) -> dict[str, int | None]:
    """Rank 1 = best; ties share the better rank (1, 2, 2, 4); a missing or NaN value has no rank (None)."""
    valid = {name: value for name, value in values.items() if value is not None and math.isfinite(value)}
    sign = -1.0 if higher_is_better else 1.0
    return {name: 1 + sum(sign * other < sign * valid[name] for other in valid.values()) if name in valid else None
            for name in values}


def thesis_ranks(variants: list[str]) -> dict[str, dict[str, int | None]]:
    """metric -> variant -> the variant's rank in Table 4.2 among ``variants``."""
    return {metric: competition_ranks({v: THESIS_TABLE_4_2[v][1][column] for v in variants}, higher)
            for column, (metric, (_, higher)) in enumerate(METRICS.items())}


def _value(value: float | None, metric: str) -> str:
    if value is None:
        return "–"
    if not math.isfinite(value):
        return "n/a"
    return f"{value:.2f}" if metric in ("psnr", "fid") else f"{value:.3f}"


def _header(extra: tuple[str, ...] = ()) -> list[str]:
    labels = [f"{label} {'↑' if higher else '↓'}" for label, higher in METRICS.values()] + list(extra)
    return [f"| variant | {' | '.join(labels)} |", "|---" * (len(labels) + 1) + "|"]


def ranks_markdown(scores: dict[str, dict[str, float | None]]) -> str:
    """One row per variant of ``scores`` (variant -> metric -> value; None = not computed): each cell is
    'our value (our rank / the thesis' rank)' among the variants scored, and a last row counts the equal ranks.
    With "no_face" and "frames" in the scores, a last column says how many outputs had no detected face."""
    variants = [v for v in VARIANTS if v in scores]
    ours = {metric: competition_ranks({v: scores[v].get(metric) for v in variants}, higher)
            for metric, (_, higher) in METRICS.items()}
    thesis = thesis_ranks(variants)
    faces = all("frames" in scores[v] for v in variants)
    lines = _header(("no face / frames",) if faces else ())
    for v in variants:
        cells = [f"{_value(scores[v].get(m), m)} ({'–' if ours[m][v] is None else ours[m][v]} / {thesis[m][v]})"
                 for m in METRICS]
        cells += [f"{scores[v]['no_face']} / {scores[v]['frames']}"] if faces else []
        lines.append(f"| {THESIS_TABLE_4_2[v][0]} (`{v}`) | " + " | ".join(cells) + " |")
    same = ["–" if all(ours[m][v] is None for v in variants) else
            f"{sum(ours[m][v] == thesis[m][v] for v in variants)} of {len(variants)}" for m in METRICS]
    lines.append("| same rank as the thesis | " + " | ".join(same + ([""] if faces else [])) + " |")
    return "\n".join(lines)


def thesis_markdown() -> str:
    """Table 4.2's four rows, each value with its rank among them."""
    ranks = thesis_ranks(list(VARIANTS))
    lines = _header()
    for v, (label, values) in THESIS_TABLE_4_2.items():
        cells = [f"{_value(value, m)} ({ranks[m][v]})" for m, value in zip(METRICS, values, strict=True)]
        lines.append(f"| {label} (`{v}`) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ablation_markdown(results: dict[str, dict[str, dict[str, float | None]]], notes: list[str], machine: str) -> str:
    """results: split title -> variant -> metric -> value. The section body (also printed)."""
    lines = [*notes, "", "Each cell: our value (our rank / the thesis' rank); rank 1 = best of the four variants, "
             "ties share a rank. The ordering is the point: the thesis trained paper-sized models on VoxCeleb2. "
             "NMKE is over the outputs with a detected face; ID-SIM aligns the others with the ground truth.", "",
             "### Thesis Table 4.2 (value (rank))", "", thesis_markdown()]
    for title, scores in results.items():
        lines += ["", f"### {title}", "", ranks_markdown(scores)]
    lines += ["", machine]
    return "\n".join(lines)


# ---- training ----------------------------------------------------------------------------------------------


def schedule(steps: int) -> dict[str, int]:
    """Steps of stages 1-3 and of the final lr decay, in the proportions of `lsr train`'s default epochs
    (2 : 4 : 9; the lr decays over the last of the 15 epochs, thesis §4.6)."""
    from lsr.config import StagesConfig

    default = StagesConfig()
    epochs = default.pretrain_epochs + default.full_epochs + default.latent_epochs
    pretrain = max(1, round(steps * default.pretrain_epochs / epochs))
    full = max(1, round(steps * default.full_epochs / epochs))
    latent, decay = steps - pretrain - full, max(1, round(steps / epochs))
    return {"pretrain": pretrain, "full": full, "latent": latent, "decay": decay}


def train_config(cfg: BenchAblationConfig, variant: str, resume: bool):
    """The `lsr train` config of one variant: the same steps for every variant (stage 1's go to stage 2 without G^l)."""
    from lsr.config import StagesConfig, TrainConfig
    from lsr.train.steps import stages_for_variant

    steps = schedule(cfg.steps)
    has_layout_predictor = any(plan.stage == 1 for plan in stages_for_variant(variant))  # G^l pre-trains in stage 1
    full = steps["full"] + (0 if has_layout_predictor else steps["pretrain"])
    # steps_per_epoch 1: every stage budget is a step count
    stages = StagesConfig(pretrain_epochs=steps["pretrain"], full_epochs=full, latent_epochs=steps["latent"],
                          steps_per_epoch=1, lr_decay_steps=steps["decay"])
    data = (cfg.data,) if cfg.data is not None else ()
    return TrainConfig(data=data, synthetic_identities=cfg.synthetic_identities, out=Path(cfg.out) / variant,
                       preset=cfg.preset, variant=variant, k=cfg.k, batch_size=cfg.batch_size, workers=cfg.workers,
                       seed=cfg.seed, stages=stages, device=cfg.device, threads=cfg.threads,
                       checkpoint_every=cfg.checkpoint_every, resume=resume, progress=cfg.progress)


def trained_step(run: Path) -> int | None:
    """Step of the newest checkpoint of an `lsr train` run folder; None when it has none."""
    from lsr.train.checkpoint import CHECKPOINT_PATTERN, latest_checkpoint

    newest = latest_checkpoint(Path(run) / "checkpoints")
    return None if newest is None else int(CHECKPOINT_PATTERN.match(newest.name).group(1))


def load_state(cfg: BenchAblationConfig) -> dict[str, Any]:
    """OUT/ablation.json: the schedule this OUT was started with and the timings. ConfigError when a training flag
    differs from it while a variant has checkpoints (before any, the new flags simply replace the old)."""
    from landmarks.io.image_files import write_json

    path = Path(cfg.out) / "ablation.json"
    wanted = {key: getattr(cfg, key) for key in SCHEDULE_KEYS}
    state = json.loads(path.read_text()) if path.is_file() else {"schedule": wanted, "seconds_per_step": {}}
    changed = [f"--{key.replace('_', '-')} {state['schedule'].get(key)}" for key in SCHEDULE_KEYS
               if state["schedule"].get(key) != wanted[key]]
    if changed and any(trained_step(Path(cfg.out) / variant) is not None for variant in VARIANTS):
        raise ConfigError(f"{cfg.out} was started with {', '.join(changed)}: rerun with those flags to resume, "
                          "or use a new --out")
    state["schedule"] = wanted
    write_json(path, state)
    return state


def train_variants(cfg: BenchAblationConfig, state: dict[str, Any]) -> dict[str, Path]:
    """Train (or resume, or skip) every variant; returns variant -> weights folder."""
    from landmarks.io.image_files import write_json
    from lsr.train.trainer import run_train

    folders = {}
    for number, variant in enumerate(VARIANTS, 1):
        run = Path(cfg.out) / variant
        step, has_weights = trained_step(run), (run / "weights" / "model.safetensors").is_file()
        tag = f"ablation {number}/{len(VARIANTS)} {variant}"
        if has_weights and (step is None or step >= cfg.steps):  # stage ends export weights too: check the step
            trained = "weights without checkpoints" if step is None else f"{step} steps"
            print(f"{tag}: already trained ({trained}), skipped")
            folders[variant] = run / "weights"
            continue
        begin = "training" if step is None else f"resuming at step {step}"
        print(f"{tag}: {begin} to step {cfg.steps} in {run}", flush=True)
        started = time.perf_counter()
        train_cfg = train_config(cfg, variant, resume=step is not None)
        train_cfg.validate()
        summary = run_train(train_cfg)
        state["seconds_per_step"][variant] = (time.perf_counter() - started) / max(1, summary["steps"] - (step or 0))
        write_json(Path(cfg.out) / "ablation.json", state)
        folders[variant] = run / "weights"
    return folders


# ---- evaluation --------------------------------------------------------------------------------------------


def synthetic_test_split(cfg: BenchAblationConfig, resolution: int) -> Path:
    """Held-out procedural identities at the model's resolution, rendered once into OUT: `lsr bench speed`'s fixed
    seed (never a training seed), one video of --inputs + --holdouts frames per identity, half of them 'test'."""
    from lsr.bench.bench_speed import SYNTH_SEED, held_out_synthetic_split

    if cfg.synthetic_identities and cfg.seed == SYNTH_SEED:
        raise ConfigError(f"--seed {SYNTH_SEED} renders the held-out synthetic identities; train with another --seed")
    return held_out_synthetic_split(Path(cfg.out), resolution, 1, cfg.inputs + cfg.holdouts, progress=cfg.progress)


def evaluation_splits(cfg: BenchAblationConfig, resolution: int) -> tuple[dict[str, tuple[str, Path]], list[str]]:
    """{folder name: (title, dataset root)} to score, and one line per split skipped, with the reason."""
    from lsr.config.shared import evaluation_data
    from lsr.data.format import read_manifest

    splits, skipped = {}, []
    if cfg.data is not None:
        if read_manifest(cfg.data)["splits"].get("test"):
            splits["data_test"] = (f"Test split of `{shown_path(cfg.data)}`", Path(cfg.data))
        else:
            skipped.append(f"- `{shown_path(cfg.data)}` has no test identities: its split was not scored")
    if cfg.synthetic_identities or not splits:
        splits["synthetic_test"] = ("Held-out synthetic identities", synthetic_test_split(cfg, resolution))
    if cfg.fsth:
        try:
            splits["fsth"] = ("FSTH sample (VoxCeleb2, the thesis' test people)", evaluation_data(cfg.fsth_root))
        except ConfigError:
            skipped.append("- FSTH sample: skipped, the shared ../shared/data/fsth_eval_sample (or "
                           "$LSR_SHARED_DATA/fsth_eval_sample) is absent; pass --fsth-root FOLDER to score it")
    return splits, skipped


def evaluate(cfg: BenchAblationConfig, name: str, root: Path, weights: dict[str, Path], device: str) -> dict[str, dict[str, Any]]:
    """`lsr eval` of the variants at K = 1, no fine-tuning (report and a side-by-side picture in OUT/eval/NAME);
    variant -> metric (and "no_face", "frames") -> value."""
    from lsr.config.eval_options import EvalConfig
    from lsr.eval.report import run_eval

    folder = Path(cfg.out) / "eval" / name
    eval_cfg = EvalConfig(data=root, out=folder, k=(1,), methods=(), weights=tuple(weights.values()), finetune_steps=0,
                          device=device, inputs=cfg.inputs, holdouts=cfg.holdouts, max_holdouts=cfg.max_holdouts,
                          max_identities=cfg.max_identities, examples=0, figure=folder / "variants_k1.png", figure_k=1,
                          lpips_weights=cfg.lpips_weights, fid_weights=cfg.fid_weights, progress=cfg.progress)
    eval_cfg.validate()
    rows = {row["method"]: row for row in run_eval(eval_cfg)["rows"] if row["k"] == 1}
    keys = (*METRICS, "no_face", "frames")
    return {variant: {key: rows[f"lsr:{variant}"][key] for key in keys} for variant in weights}


def setting_notes(cfg: BenchAblationConfig, state: dict[str, Any], skipped: list[str]) -> list[str]:
    """The lines above the tables: schedule, data, protocol, the splits skipped and the measured s/step."""
    steps = schedule(cfg.steps)
    data = " + ".join(([f"`{shown_path(cfg.data)}` (train split)"] if cfg.data else [])
                      + ([f"{cfg.synthetic_identities} synthetic identities"] if cfg.synthetic_identities else []))
    notes = [f"Preset `{cfg.preset}`, {cfg.steps} training steps per variant (stages 1 / 2 / 3: {steps['pretrain']} / "
             f"{steps['full']} / {steps['latent']}; without G^l: – / {steps['pretrain'] + steps['full']} / "
             f"{steps['latent']}), batch {cfg.batch_size}, K = {cfg.k}, seed {cfg.seed}, on {data}. Scored with "
             f"`lsr eval`'s protocol at K = 1 without fine-tuning; reports in `{Path(cfg.out) / 'eval'}`. LPIPS / FID: "
             "'–' unless --lpips-weights / --fid-weights are given."]
    notes += ["", *skipped] if skipped else []
    timed = state["seconds_per_step"]
    if timed:
        speed = ", ".join(f"{variant} {timed[variant]:.2f}" for variant in VARIANTS if variant in timed)
        notes += ["", f"Training s/step (the session that finished each variant, set-up included): {speed}."]
    return notes


def run_bench_ablation(cfg: BenchAblationConfig) -> dict[str, dict[str, dict[str, float | None]]]:
    """Entry point of ``lsr bench ablation``: train what is missing, evaluate, print the tables (and write the section).
    Returns split title -> variant -> metric -> value."""
    import torch

    from lsr.devices import resolve_device
    from lsr.eval.sections import publish
    from lsr.eval.machine import machine_markdown
    from models_def import preset_config

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    state = load_state(cfg)
    weights = train_variants(cfg, state)
    splits, skipped = evaluation_splits(cfg, preset_config(cfg.preset).resolution)
    for line in skipped:
        print(line.removeprefix("- "))
    device = resolve_device(cfg.device).type
    results = {title: evaluate(cfg, name, root, weights, device) for name, (title, root) in splits.items()}
    text = ablation_markdown(results, setting_notes(cfg, state, skipped), machine_markdown())
    publish(cfg, "lsr bench ablation", SECTION, "Ablation, thesis Table 4.2: our ranks beside the thesis' (`lsr bench ablation`)", text)
    return results
