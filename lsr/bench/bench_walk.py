"""lsr bench walk: the path of one frame through ``lsr reenact --paste-back``, as the modules each stage enters.

A newcomer reads the house by following one frame. The frame loop (``lsr.core.engine``) runs its stages on threads
(``lsr.core.overlap``): the driver frame is decoded, tracked, cropped, driven and its shots warped on one thread, the
networks and the parts' finishing run on the loop's, the paste-back on a worker behind it. For each thread the
command lists, in order, the modules the loop's own code (``ORCHESTRATORS``) calls into while one frame passes
(each thread's stages of one frame: the threads work on neighbouring frames at once). A module
listed twice for one frame is a room the frame left and came back to: the count is the table's last column.
Calls a room makes inside itself (its helpers) are its own business and not listed.
"""

from __future__ import annotations

import collections
import sys
import threading
from pathlib import Path

from lsr.config.bench_options import BenchWalkConfig

SECTION = "walk"
PACKAGES = ("landmarks", "lsr", "deploy", "models_def")
ORCHESTRATORS = ("lsr.core.engine", "lsr.core.overlap", "lsr.writer")
"""The loop's own modules: what they call into is a stage's room."""
FRAME = "|"
"""Marks where a thread's next frame starts in its record."""
FRAME_STARTS = {("lsr.core.engine", "_frame_driver"), ("lsr.core.engine", "_landmark_driver"),
                ("lsr.core.engine", "_synthesized"), ("lsr.core.inputs", "tracked")}
"""The loop's generators (and the driver's decoding and tracking, on its own thread): each resumption is the next
frame of that thread's stages."""
MACHINERY = frozenset({"__get__", "__set__", "__set_name__", "__getattr__", "__getattribute__", "__init__",
                       "__post_init__", "__eq__", "__hash__", "__len__", "__iter__", "__bool__", "__enter__", "__exit__",
                       "<genexpr>", "<listcomp>", "<dictcomp>", "<lambda>"})
"""Calls that are attribute and construction machinery, not a stage's work."""
STAGE_OF_THREAD = {"lsr-prefetch#2": "decode, landmarks", "lsr-prefetch": "crop, drive, warps", "MainThread": "networks, parts",
                   "lsr-finish": "paste back", "lsr-drain": "encode"}
"""Thread name prefix -> the stages that thread runs (``lsr.core.overlap``)."""


def _project_caller(frame) -> tuple[str, str] | None:
    """(module, function) of ``frame``, or of the nearest project frame below it (a call through a decorator of
    torch or functools belongs to the project code that made it); None below a worker thread's first project call."""
    while frame is not None:
        name = frame.f_globals.get("__name__", "")
        if name.split(".")[0] in PACKAGES:
            return name, frame.f_code.co_name
        frame = frame.f_back
    return None


def _thread_labels():
    """A function giving the current thread's name, numbered where several share it (a nested prefetch stage has
    its own thread of the same name)."""
    labels: dict[int, str] = {}

    def label() -> str:
        thread = threading.current_thread()
        if thread.ident not in labels:
            same = sum(known.split("#")[0] == thread.name for known in labels.values())
            labels[thread.ident] = thread.name if not same else f"{thread.name}#{same + 1}"
        return labels[thread.ident]

    return label


def walk(source: Path, driver: Path, *, frame: int = 10, runtime: str = "torch") -> dict[str, list[str]]:
    """thread name -> the modules the loop called into for driver frame ``frame`` (consecutive calls into one
    module merged), re-enacted as ``lsr reenact --paste-back`` does with the shipped default."""
    from lsr.commands.reenact import make_reenactor
    from lsr.config import ReenactConfig

    cfg = ReenactConfig(source=source, driver=driver, out=Path("walk.mp4"), paste_back=True, runtime=runtime,
                        threads=1, progress=False)
    reenactor = make_reenactor(cfg)
    reenactor.encode_subject(source)
    calls: dict[str, list[str]] = collections.defaultdict(list)
    thread_label = _thread_labels()
    recording = threading.Event()

    def profile(code_frame, event, arg) -> None:
        if event != "call" or not recording.is_set() or code_frame.f_code.co_name in MACHINERY:
            return
        module = code_frame.f_globals.get("__name__", "")
        entered = calls[thread_label()]
        if (module, code_frame.f_code.co_name) in FRAME_STARTS:
            entered.append(FRAME)  # the loop's generator resumed: this thread's next frame starts
            return
        caller = _project_caller(code_frame.f_back)  # None: a worker thread's first project call, the loop's
        if (module.split(".")[0] in PACKAGES and module not in ORCHESTRATORS
                and (caller is None or caller[0] in ORCHESTRATORS or caller in FRAME_STARTS)):
            if caller is None:
                entered.append(FRAME)  # a worker's finisher: one call per frame
            if not entered or entered[-1] != module:
                entered.append(module)

    # the loop's threads start with the stream and inherit the profile; it records from ``frame`` on until each
    # thread has a whole frame, and keeps each thread's first (the threads work on neighbouring frames at once)
    sys.setprofile(profile), threading.setprofile(profile)
    stream = reenactor.reenact(driver, paste_back=True)
    try:
        for index, _ in enumerate(stream):
            if index == frame:
                recording.set()
            elif index > frame + 1 and (index >= frame + 40 or all(
                    entered.count(FRAME) >= 2 for entered in list(calls.values()) if FRAME in entered)):
                break  # every thread has recorded a whole frame (a thread ahead may wait on a full queue a while)
    finally:
        recording.clear()
        sys.setprofile(None), threading.setprofile(None)
        stream.close()
    return {thread: _one_frame(entered) for thread, entered in calls.items() if FRAME in entered}


def _one_frame(entered: list[str]) -> list[str]:
    """The modules between a thread's first two frame starts (the first whole frame it recorded)."""
    starts = [index for index, module in enumerate(entered) if module == FRAME]
    segment = entered[starts[0] + 1:starts[1]] if len(starts) > 1 else entered[starts[0] + 1:]
    return [module for index, module in enumerate(segment) if index == 0 or module != segment[index - 1]]


def walk_markdown(walked: dict[str, list[str]]) -> str:
    rows = ["| thread (stages) | modules entered, in order | modules | re-entries |", "|---|---|---|---|"]
    for thread, modules in walked.items():
        stage = next((s for prefix, s in STAGE_OF_THREAD.items() if thread.startswith(prefix)), thread)
        rows.append(f"| {thread} ({stage}) | {' → '.join(f'`{m}`' for m in modules)} | {len(set(modules))} | "
                    f"{len(modules) - len(set(modules))} |")
    return "\n".join(rows)


def run_bench_walk(cfg: BenchWalkConfig) -> str:
    from lsr.eval import sections
    from lsr.eval.machine import machine_markdown
    from lsr.examples import REAL_DRIVER, REAL_SOURCE

    source, driver = (Path(cfg.source or REAL_SOURCE), Path(cfg.driver or REAL_DRIVER))
    walked = walk(source, driver, frame=cfg.frame, runtime=cfg.runtime)
    note = (f"Driver frame {cfg.frame} of {driver.name} re-enacting {source.name} (`lsr reenact --paste-back`, "
            f"--runtime {cfg.runtime}); each row the modules the frame loop's own code calls into on one thread, "
            "a module entered again after the frame left it counted as a re-entry.")
    text = f"{machine_markdown()}\n\n{note}\n\n{walk_markdown(walked)}"
    sections.publish(cfg, "lsr bench walk", SECTION, "One frame's walk through the house (`lsr bench walk`)", text)
    return text
