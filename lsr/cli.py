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
    from landmarks.io.annotate import annotate_path

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
    from lsr.commands.demo import run_demo

    run_demo(cfg.out, weights=cfg.weights, frames=cfg.frames, k=cfg.k, finetune_steps=cfg.finetune_steps, synthetic=cfg.synthetic,
             threads=cfg.threads, progress=cfg.progress)


def _run_prepare(cfg: config.PrepareConfig) -> None:
    import os

    from lsr.data.prepare import PrepareOptions, prepare_dataset

    options = PrepareOptions(size=cfg.resolution, frames_per_clip=cfg.frames_per_clip, framing=cfg.framing,
                             detector=cfg.detector, official_segmaps=cfg.official_segmaps)
    workers = min(2, os.cpu_count() or 1) if cfg.workers == -1 else cfg.workers
    summary = prepare_dataset(cfg.input, cfg.out, options, workers=workers, test_fraction=cfg.test_fraction,
                              test_identities=cfg.test_identities,
                              split_all=None if cfg.split_all == "auto" else cfg.split_all, progress=cfg.progress)
    print(summary.table())
    print(f"dataset written to {cfg.out} (manifest.json, prepare_summary.json)")


def _run_bench_synth(cfg: config.BenchSynthConfig) -> None:
    from lsr.data.synth.generate import print_benchmark

    print_benchmark(preset=cfg.preset)


def _run_synth(cfg: config.SynthConfig) -> None:
    import os

    from lsr.data.synth import generate_dataset, write_preview

    if cfg.preview is not None:
        path = write_preview(cfg.preview, size=cfg.resolution, seed=cfg.seed, preset=cfg.preset)
        print(f"preview written to {path}")
        return
    workers = min(2, os.cpu_count() or 1) if cfg.workers == -1 else cfg.workers
    manifest = generate_dataset(cfg.out, cfg.identities, cfg.videos_per_identity, cfg.frames, size=cfg.resolution, seed=cfg.seed,
                                preset=cfg.preset, test_fraction=cfg.test_fraction, fps=cfg.fps, overwrite=cfg.overwrite,
                                workers=workers, framing=cfg.framing)
    print(f"dataset written to {cfg.out} ({manifest.name})")


Runner = Callable[[Any], None] | str
"""A function of the config, or "module:function" imported only when that sub-command runs (``lsr --help`` stays instant)."""


def _resolve(runner: Runner) -> Callable[[Any], None]:
    if callable(runner):
        return runner
    import importlib

    module, function = runner.split(":")
    return getattr(importlib.import_module(module), function)


# name -> (config dataclass, runner). Groups (like "bench") nest one level.
COMMANDS: dict[str, tuple[type, Runner]] = {
    "landmarks": (config.LandmarksConfig, _run_landmarks),
    "demo": (config.DemoConfig, _run_demo),
    "train": (config.TrainConfig, "lsr.train.trainer:run_train"),
    "finetune": (config.FinetuneConfig, "lsr.train.finetune:run_finetune"),
    "prepare": (config.PrepareConfig, _run_prepare),
    "eval": (config.EvalConfig, "lsr.eval.report:run_eval"),
    "synth": (config.SynthConfig, _run_synth),
    "reenact": (config.ReenactConfig, "lsr.commands.reenact:run_reenact"),
    "batch": (config.BatchConfig, "lsr.commands.reenact:run_reenact"),
    "export": (config.ExportConfig, "lsr.export.web_site:run_export"),
    "app": (config.AppConfig, "app.ui:run_app"),
    "ship": (config.ShipConfig, "lsr.weights.ship:run_ship"),
    "curves": (config.CurvesConfig, "lsr.train.visualize:run_curves"),
}
GROUPS: dict[str, dict[str, tuple[type, Runner]]] = {
    "bench": {
        "landmarks": (config.BenchLandmarksConfig, "lsr.bench.bench_landmarks:run_bench_landmarks"),
        "train": (config.BenchTrainConfig, "lsr.bench.bench_train:run_bench_train"),
        "reenact": (config.BenchReenactConfig, "lsr.bench.bench_reenact:run_bench_reenact"),
        "live": (config.BenchLiveConfig, "lsr.bench.bench_live:run_bench_live"),
        "web": (config.BenchWebConfig, "lsr.bench.bench_web:run_bench_web"),
        "soak": (config.BenchSoakConfig, "lsr.bench.bench_soak:run_bench_soak"),
        "models": (config.BenchModelsConfig, "lsr.bench.bench_models:run_bench_models"),
        "speed": (config.BenchSpeedConfig, "lsr.bench.bench_speed:run_bench_speed"),
        "finetune": (config.BenchFinetuneConfig, "lsr.bench.bench_finetune:run_bench_finetune"),
        "hard": (config.BenchHardConfig, "lsr.bench.bench_hard:run_bench_hard"),
        "lids": (config.BenchLidsConfig, "lsr.bench.bench_lids:run_bench_lids"),
        "plate": (config.BenchPlateConfig, "lsr.bench.bench_plate:run_bench_plate"),
        "eyes": (config.BenchEyesConfig, "lsr.bench.bench_eyes:run_bench_eyes"),
        "ablation": (config.BenchAblationConfig, "lsr.bench.bench_ablation:run_bench_ablation"),
        "synth": (config.BenchSynthConfig, _run_bench_synth),
        "oracle-seg": (config.BenchOracleSegConfig, "lsr.data.oracle_seg:run_bench_oracle_seg"),
        "layout-legend": (config.BenchLayoutLegendConfig, "lsr.bench.layout_legend:run_bench_layout_legend"),
        "walk": (config.BenchWalkConfig, "lsr.bench.bench_walk:run_bench_walk"),
    },
    "parts": {
        "pairs": (config.PartPairsConfig, "lsr.train.part_training:run_pairs"),
        "train": (config.PartTrainConfig, "lsr.train.part_training:run_train"),
    },
    "face-models": {
        "convert": (config.FaceModelsConvertConfig, "landmarks.detect.rebuild_mediapipe:run_convert"),
        "fit": (config.FaceModelsFitConfig, "landmarks.shape.mesh68:run_fit"),
        "lids": (config.FaceModelsLidsConfig, "landmarks.parts.eyes.lids_survey:run_survey"),
    },
}


def _user_errors() -> tuple[type[BaseException], ...]:
    from landmarks.exceptions import LandmarksError
    from lsr.errors import LsrError

    return (LsrError, LandmarksError)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the process is: temp files are removed and checkpoints kept as for Ctrl-C."""


_terminated = threading.Event()
"""Set by SIGTERM. Python drops an exception raised inside a weakref callback or ``__del__`` ("Exception
ignored in ..."), so a SIGTERM that lands while the garbage collector runs one would be lost and the run
would end with status 0; ``main`` reads this flag after the run as well."""


def _raise_terminated(signum: int, frame: Any) -> None:
    _terminated.set()
    raise Terminated()


GROUP_HELP = {
    "bench": "benchmarks; each prints a markdown table with machine info",
    "parts": "train a mouth generator (the mouth drawn from the driven lips, not blended from shots)",
    "face-models": "rebuild the shipped face models (MediaPipe -> ONNX) and the 68-point mapping",
}


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
    _terminated.clear()
    if threading.current_thread() is threading.main_thread():  # SIGTERM cleans up as Ctrl-C does
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        cfg.validate()
        from lsr.core.overlap import single_blas_thread

        single_blas_thread()  # the frame loops' stages fill the cores; OpenBLAS's spinning threads only take them
        _resolve(runners[type(cfg)])(cfg)
        if _terminated.is_set():  # the signal's exception was swallowed where it landed (see _terminated)
            raise Terminated()
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
