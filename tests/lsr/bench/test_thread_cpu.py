import os
import sys
import threading
import time
from pathlib import Path

import pytest

from lsr.bench.bench_live import LiveMeasure
from lsr.bench.bench_web import web_markdown
from lsr.bench.thread_cpu import GROUPS, core_shares, group_of, shares_line, thread_times

LINUX = Path("/proc/self/task").is_dir()


def _fake_thread(proc: Path, pid: int, tid: int, cmdline: bytes, name: str, user: int, system: int) -> None:
    (proc / str(pid)).mkdir(exist_ok=True)
    if cmdline:  # a process's first thread writes it
        (proc / str(pid) / "cmdline").write_bytes(cmdline)
    task = proc / str(pid) / "task" / str(tid)
    task.mkdir(parents=True)
    # proc(5): pid (comm) state ppid pgrp session tty_nr tpgid flags minflt cminflt majflt cmajflt utime stime ...
    (task / "stat").write_text(f"{tid} ({name}) S 1 1 1 0 -1 0 0 0 0 0 {user} {system} 0 0 20 0 1 0\n")


def test_a_chromium_rewritten_command_line_and_a_thread_name_with_spaces_are_read(tmp_path):
    ticks = os.sysconf("SC_CLK_TCK")
    # Chromium rewrites its command line into one space-separated string; a thread name may hold spaces and ")"
    _fake_thread(tmp_path, 40, 40, b"/usr/lib/chromium/chromium --type=renderer --lang=en-US", "chromium", ticks, 0)
    _fake_thread(tmp_path, 40, 41, b"", "DedicatedWorker (x)", 2 * ticks, ticks)
    _fake_thread(tmp_path, 50, 50, b"/usr/bin/python3\0-m\0pytest\0", "python3", 5 * ticks, 0)
    (tmp_path / "self").mkdir()  # not a process
    times = thread_times("chromium", tmp_path)
    assert times == {(40, 40, "renderer", "chromium"): 1.0, (40, 41, "renderer", "DedicatedWorker (x)"): 3.0}
    assert thread_times("python3", tmp_path) == {(50, 50, "browser", "python3"): 5.0}
    assert thread_times("chromium", tmp_path / "missing") == {}


@pytest.mark.skipif(not LINUX, reason="reads /proc")
def test_a_busy_thread_of_this_process_shows_its_cpu_time():
    native: list[int] = []
    go, spun, leave = threading.Event(), threading.Event(), threading.Event()

    def spin() -> None:
        native.append(threading.get_native_id())
        go.wait()
        end = time.thread_time() + 0.3
        while time.thread_time() < end:
            pass
        spun.set()
        leave.wait()  # alive while it is read: an ended thread's time leaves /proc/PID/task

    every = lambda name: True  # every process's threads; this one's are picked out by its pid below
    worker = threading.Thread(target=spin)
    worker.start()
    try:
        while not native:
            time.sleep(0.01)
        before = thread_times(every)
        go.set()
        spun.wait()
        after = thread_times(every)
    finally:
        go.set()
        leave.set()
        worker.join()
    mine = {key: seconds for key, seconds in after.items() if key[:2] == (os.getpid(), native[0])}
    assert len(mine) == 1, f"the thread of this process ({sys.executable}) was not read"
    key, seconds = mine.popitem()
    assert seconds - before.get(key, 0.0) >= 0.2


def test_threads_are_grouped_as_the_page_uses_them():
    assert group_of((7, 9, "renderer", "DedicatedWorker thread")) == "workers"
    assert group_of((7, 7, "renderer", "chromium")) == "main thread"
    assert group_of((7, 8, "renderer", "Compositor")) == "the rest"
    assert group_of((3, 3, "gpu-process", "chromium")) == "the rest"  # another process's main thread
    assert group_of((1, 1, "browser", "chromium")) == "the rest"


def test_core_shares_are_the_time_spent_over_the_window_by_group():
    before = {(7, 7, "renderer", "chromium"): 10.0, (7, 9, "renderer", "DedicatedWorker thread"): 4.0,
              (3, 3, "gpu-process", "chromium"): 1.0}
    after = {(7, 7, "renderer", "chromium"): 11.0, (7, 9, "renderer", "DedicatedWorker thread"): 6.0,
             (7, 12, "renderer", "DedicatedWorker thread"): 1.0,  # born in the window
             (3, 3, "gpu-process", "chromium"): 1.5}
    shares = core_shares(before, after, 2.0)
    assert list(shares) == [*GROUPS, "all"]
    assert shares == pytest.approx({"workers": 1.5, "main thread": 0.5, "the rest": 0.25, "all": 2.25})
    assert core_shares({}, after, 2.0) == {} and core_shares(before, after, 0.0) == {}


def test_the_web_section_says_where_the_cores_went_only_when_it_knows():
    measure = LiveMeasure(100, 5.0, 20.0, [120.0] * 100, [90.0] * 100)
    args = (measure, measure, {"track": 20.0, "network": 40.0}, 1, "WASM", "`camera.mp4`", 56.0, "| machine |")
    shares = {"workers": 0.8, "main thread": 0.6, "the rest": 0.3, "all": 1.7}
    text = web_markdown(*args, shares, 2)
    assert "Chromium kept 1.70 cores of 2 busy over the window (workers 0.80, main thread 0.60, the rest 0.30" in text
    assert text.rstrip().endswith("| machine |")
    assert "cores" not in web_markdown(*args).split("| machine |")[0].split("threads)")[-1]
    assert shares_line({}, 2) == ""
    assert "showed 100 of the 125 frames the camera sent over its window (80%): the camera's 25 fps" in web_markdown(
        *args, camera_fps=25, offered=125)
    assert "camera sent" not in web_markdown(*args)
