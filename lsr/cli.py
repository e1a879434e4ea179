"""The ``lsr`` command. Sub-commands are generated from the dataclasses in ``lsr.config``.

Heavy modules are imported only inside the runner of the chosen sub-command, so
``lsr --help`` is instant. User-facing errors become one line on stderr and exit 2.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any

from lsr import config


def _run_landmarks(cfg: config.LandmarksConfig) -> None:
    from landmarks.annotate import annotate_path

    annotate_path(
        cfg.input,
        cfg.out,
        detector=cfg.detector,
        face_index=cfg.face_index,
        smooth=cfg.smooth,
        min_cutoff=cfg.min_cutoff,
        beta=cfg.beta,
        overlay=cfg.overlay,
    )


def _run_demo(cfg: config.DemoConfig) -> None:
    from lsr.demo import run_demo

    run_demo(cfg.out, weights=cfg.weights, frames=cfg.frames, k=cfg.k, finetune_steps=cfg.finetune_steps,
             threads=cfg.threads, progress=cfg.progress)


def _run_bench_landmarks(cfg: config.BenchLandmarksConfig) -> None:
    from lsr.eval.bench_landmarks import run_bench_landmarks

    run_bench_landmarks(cfg)


def _run_prepare(cfg: config.PrepareConfig) -> None:
    import os

    from lsr.data.prepare import PrepareOptions, prepare_dataset

    options = PrepareOptions(size=cfg.size, frames_per_clip=cfg.frames_per_clip, framing=cfg.framing,
                             detector=cfg.detector, official_segmaps=cfg.official_segmaps)
    workers = min(2, os.cpu_count() or 1) if cfg.workers == -1 else cfg.workers
    summary = prepare_dataset(cfg.input, cfg.out, options, workers=workers, test_fraction=cfg.test_fraction,
                              test_identities=cfg.test_identities,
                              split_all=None if cfg.split_all == "auto" else cfg.split_all)
    print(summary.table())
    print(f"dataset written to {cfg.out} (manifest.json, prepare_summary.json)")


def _run_synth(cfg: config.SynthConfig) -> None:
    import os

    from lsr.data.synth import generate_dataset, write_preview
    from lsr.data.synth.generate import print_benchmark

    if cfg.bench:
        print_benchmark(preset=cfg.preset)
        return
    if cfg.preview is not None:
        path = write_preview(cfg.preview, size=cfg.size, seed=cfg.seed, preset=cfg.preset)
        print(f"preview written to {path}")
        return
    workers = min(2, os.cpu_count() or 1) if cfg.workers == -1 else cfg.workers
    manifest = generate_dataset(cfg.out, cfg.identities, cfg.videos_per_identity, cfg.frames, size=cfg.size, seed=cfg.seed,
                                preset=cfg.preset, test_fraction=cfg.test_fraction, fps=cfg.fps, overwrite=cfg.overwrite,
                                workers=workers, framing=cfg.framing)
    print(f"dataset written to {cfg.out} ({manifest.name})")


def _run_train(cfg: config.TrainConfig) -> None:
    from lsr.train.trainer import run_train

    run_train(cfg)


def _run_finetune(cfg: config.FinetuneConfig) -> None:
    from lsr.train.finetune import run_finetune

    run_finetune(cfg)


def _run_eval(cfg: config.EvalConfig) -> None:
    from lsr.eval.report import run_eval

    run_eval(cfg)


def _run_bench_train(cfg: config.BenchTrainConfig) -> None:
    from lsr.train.bench import run_bench_train

    run_bench_train(cfg)


def _run_bench_models(cfg: config.BenchModelsConfig) -> None:
    from lsr.eval.bench_models import run_bench_models

    run_bench_models(cfg)


def _run_bench_speed(cfg: config.BenchSpeedConfig) -> None:
    from lsr.eval.bench_speed import run_bench_speed

    run_bench_speed(cfg)


def _run_reenact(cfg: config.ReenactConfig) -> None:
    from lsr.reenact import run_reenact

    run_reenact(cfg)


def _run_export(cfg: config.ExportConfig) -> None:
    from lsr.export_bundle import run_export

    run_export(cfg)


def _run_app(cfg: config.AppConfig) -> None:
    from app.ui import run_app

    run_app(cfg)


def _run_bench_reenact(cfg: config.BenchReenactConfig) -> None:
    from lsr.eval.bench_reenact import run_bench_reenact

    run_bench_reenact(cfg)


def _run_bench_finetune(cfg: config.BenchFinetuneConfig) -> None:
    from lsr.eval.bench_finetune import run_bench_finetune

    run_bench_finetune(cfg)


def _run_bench_hard(cfg: config.BenchHardConfig) -> None:
    from lsr.eval.bench_hard import run_bench_hard

    run_bench_hard(cfg)


# name -> (config dataclass, runner). Groups (like "bench") nest one level.
COMMANDS: dict[str, tuple[type, Callable[[Any], None]]] = {
    "landmarks": (config.LandmarksConfig, _run_landmarks),
    "demo": (config.DemoConfig, _run_demo),
    "train": (config.TrainConfig, _run_train),
    "finetune": (config.FinetuneConfig, _run_finetune),
    "prepare": (config.PrepareConfig, _run_prepare),
    "eval": (config.EvalConfig, _run_eval),
    "synth": (config.SynthConfig, _run_synth),
    "reenact": (config.ReenactConfig, _run_reenact),
    "export": (config.ExportConfig, _run_export),
    "app": (config.AppConfig, _run_app),
}
GROUPS: dict[str, dict[str, tuple[type, Callable[[Any], None]]]] = {
    "bench": {
        "landmarks": (config.BenchLandmarksConfig, _run_bench_landmarks),
        "train": (config.BenchTrainConfig, _run_bench_train),
        "reenact": (config.BenchReenactConfig, _run_bench_reenact),
        "models": (config.BenchModelsConfig, _run_bench_models),
        "speed": (config.BenchSpeedConfig, _run_bench_speed),
        "finetune": (config.BenchFinetuneConfig, _run_bench_finetune),
        "hard": (config.BenchHardConfig, _run_bench_hard),
    },
}


def _user_errors() -> tuple[type[BaseException], ...]:
    from landmarks.errors import LandmarksError
    from lsr.errors import LsrError

    return (LsrError, LandmarksError)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the process is: temp files are removed and checkpoints kept as for Ctrl-C."""


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated()


GROUP_HELP = {"bench": "benchmarks; each prints a markdown table with machine info"}


def main(argv: Sequence[str] | None = None) -> int:
    import tyro

    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in GROUPS:
        group = args[0]
        table, prog, args = GROUPS[group], f"lsr {group}", args[1:]
        description = GROUP_HELP.get(group, "")
    else:
        table, prog = COMMANDS, "lsr"
        groups = "; ".join(f"'lsr {g} {{{','.join(t)}}}': {GROUP_HELP.get(g, '')}" for g, t in GROUPS.items())
        description = f"Few-shot talking-head synthesis (LSR). Also: {groups}."
    # subcommand_cli_from_dict keeps the sub-command name even for a one-member group.
    choices = {name: cls for name, (cls, _) in table.items()}
    cfg = tyro.extras.subcommand_cli_from_dict(choices, args=args, prog=prog, description=description)
    runners = {cls: run for cls, run in table.values()}
    user_errors = _user_errors()
    previous = None
    if threading.current_thread() is threading.main_thread():  # SIGTERM cleans up as Ctrl-C does
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        cfg.validate()
        runners[type(cfg)](cfg)
    except user_errors as exc:
        print(f"lsr: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system refused (disk full, permissions changed mid-run): one line, not a traceback
        print(f"lsr: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print("lsr: terminated" if terminated else "lsr: interrupted", file=sys.stderr)
        return 128 + (signal.SIGTERM if terminated else signal.SIGINT)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


if __name__ == "__main__":
    sys.exit(main())
