"""The ``lsr`` command. Sub-commands are generated from the dataclasses in ``lsr.config``.

Heavy modules are imported only inside the runner of the chosen sub-command, so
``lsr --help`` is instant. User-facing errors become one line on stderr and exit 2.
"""

from __future__ import annotations

import sys
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

    run_demo(cfg.out)


def _run_bench_landmarks(cfg: config.BenchLandmarksConfig) -> None:
    from lsr.eval.bench_landmarks import run_bench_landmarks

    run_bench_landmarks(cfg)


# name -> (config dataclass, runner). Groups (like "bench") nest one level.
COMMANDS: dict[str, tuple[type, Callable[[Any], None]]] = {
    "landmarks": (config.LandmarksConfig, _run_landmarks),
    "demo": (config.DemoConfig, _run_demo),
}
GROUPS: dict[str, dict[str, tuple[type, Callable[[Any], None]]]] = {
    "bench": {
        "landmarks": (config.BenchLandmarksConfig, _run_bench_landmarks),
    },
}


def _user_errors() -> tuple[type[BaseException], ...]:
    from landmarks.errors import LandmarksError
    from lsr.errors import LsrError

    return (LsrError, LandmarksError)


GROUP_HELP = {"bench": "benchmarks; each prints a markdown table with machine info"}


def _union(table: dict[str, tuple[type, Callable[[Any], None]]]) -> Any:
    """A tyro sub-command union built from a name -> (config, runner) table."""
    from typing import Annotated, Union

    import tyro

    return Union[tuple(Annotated[cls, tyro.conf.subcommand(name)] for name, (cls, _) in table.items())]  # noqa: UP007


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
    cfg = tyro.cli(_union(table), args=args, prog=prog, description=description)
    runners = {cls: run for cls, run in table.values()}
    user_errors = _user_errors()
    try:
        cfg.validate()
        runners[type(cfg)](cfg)
    except user_errors as exc:
        print(f"lsr: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lsr: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
