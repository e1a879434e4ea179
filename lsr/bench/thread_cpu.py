"""Where a browser's CPU time goes, thread by thread, over a measured window (Linux ``/proc``).

``lsr bench web`` reads every Chromium thread's CPU time before and after its window. The page's loop is bound
either by the CPU (the cores busy) or by its own waits (cores left idle while frames wait), and only this tells
the two apart: it is how the page's tracker was found waiting for the camera's next frame (issue 65,
``docs/decisions/2026-12-07-live-pipelines.md``). Threads are grouped as the page uses them:

* ``workers``: Chromium's ``DedicatedWorker`` threads (the page's tracker and onnxruntime's proxy worker);
* ``main thread``: each renderer process's main thread (the page's own JavaScript, its canvases);
* ``the rest``: every other Chromium thread (compositor, GPU process, camera capture, network, the browser).

``lsr bench live`` reads Chromium the same way beside the app (its own process, by ``time.process_time``, which
also counts the threads that ended within the window: an ended thread's time leaves ``/proc/PID/task``).
Elsewhere than Linux, or where ``/proc`` cannot be read, a snapshot is empty and no shares are given.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

ThreadKey = tuple[int, int, str, str]
"""(pid, tid, process type, thread name)."""

GROUPS = ("workers", "main thread", "the rest")


def _process(pid_dir: Path) -> tuple[str, str] | None:
    """(the executable's file name, Chromium's ``--type=`` or "browser") of a process, or None if unreadable.
    Chromium rewrites its command line into one space-separated string, so the arguments are split on spaces too."""
    try:
        raw = (pid_dir / "cmdline").read_bytes()
    except OSError:
        return None
    words = raw.replace(b"\0", b" ").decode(errors="replace").split()
    if not words:
        return None
    kind = next((word.split("=", 1)[1] for word in words if word.startswith("--type=")), "browser")
    return os.path.basename(words[0]), kind


def thread_times(program: str | Callable[[str], bool], proc: Path = Path("/proc")) -> dict[ThreadKey, float]:
    """CPU seconds (user + system) of every thread of every process whose executable's file name is ``program``
    (or for which it returns True): {(pid, tid, process type, thread name): seconds}. Empty where ``proc`` cannot be
    read."""
    matches = (lambda name: name == program) if isinstance(program, str) else program
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    times: dict[ThreadKey, float] = {}
    try:
        folders = [entry for entry in proc.iterdir() if entry.name.isdigit()]
    except OSError:
        return times
    for pid_dir in folders:
        process = _process(pid_dir)
        if process is None or not matches(process[0]):
            continue
        try:
            tasks = list((pid_dir / "task").iterdir())
        except OSError:
            continue
        for task in tasks:
            try:
                stat = (task / "stat").read_text()
            except OSError:
                continue
            name = stat[stat.index("(") + 1: stat.rindex(")")]
            fields = stat[stat.rindex(")") + 2:].split()  # from the state, field 3 of proc(5)
            times[(int(pid_dir.name), int(task.name), process[1], name)] = (int(fields[11]) + int(fields[12])) / ticks
    return times


def group_of(key: ThreadKey) -> str:
    """The ``GROUPS`` entry of one Chromium thread."""
    pid, tid, kind, name = key
    if name.startswith("DedicatedWorker"):
        return "workers"
    if kind == "renderer" and pid == tid:
        return "main thread"
    return "the rest"


def core_shares(before: dict[ThreadKey, float], after: dict[ThreadKey, float], seconds: float) -> dict[str, float]:
    """Cores each of ``GROUPS`` kept busy between two snapshots ``seconds`` apart (a thread born in between counts
    from 0; one that ended in between is not counted: its time leaves ``/proc``), in ``GROUPS`` order, with "all"
    last; {} when either snapshot is empty or ``seconds`` is not positive."""
    if not before or not after or not seconds > 0:
        return {}
    shares = dict.fromkeys(GROUPS, 0.0)
    for key, spent in after.items():
        used = spent - before.get(key, 0.0)
        if used > 0:
            shares[group_of(key)] += used / seconds
    shares["all"] = sum(shares.values())
    return shares


def shares_line(shares: dict[str, float], cores: int | None) -> str:
    """One sentence for a bench's section: the cores Chromium kept busy over the window, by group; "" without
    shares."""
    if not shares:
        return ""
    of = f" of {cores}" if cores else ""
    parts = ", ".join(f"{name} {shares[name]:.2f}" for name in GROUPS if name in shares)
    return (f"Chromium kept {shares['all']:.2f} cores{of} busy over the window ({parts}; per-thread CPU time from "
            "/proc): near all of them, the page is bound by the CPU; well under, by its own waits.")
