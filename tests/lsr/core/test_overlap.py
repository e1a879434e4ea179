"""``lsr.core.overlap``: stages on threads keep order, stay bounded and never swallow an error."""

from __future__ import annotations

import threading
import time

import pytest

from lsr.core.overlap import Drain, prefetch


def test_prefetch_keeps_order_runs_ahead_boundedly_and_raises_in_place():
    produced = []

    def items():
        for index in range(20):
            produced.append(index)
            yield index

    stream = prefetch(items(), depth=3)
    assert next(stream) == 0
    time.sleep(0.2)
    assert 2 <= len(produced) <= 6  # ahead of the consumer, but bounded
    assert list(stream) == list(range(1, 20))

    def failing():
        yield 1
        raise ValueError("bad frame 2")

    stream = prefetch(failing())
    assert next(stream) == 1
    with pytest.raises(ValueError, match="bad frame 2"):
        next(stream)


def test_prefetch_stops_its_thread_when_the_consumer_stops():
    def endless():
        index = 0
        while True:
            index += 1
            yield index

    before = threading.active_count()
    stream = prefetch(endless(), depth=2)
    assert next(stream) == 1
    stream.close()
    deadline = time.time() + 5
    while threading.active_count() > before and time.time() < deadline:
        time.sleep(0.01)
    assert threading.active_count() == before


def test_drain_consumes_in_order_and_reraises():
    seen = []
    with Drain(lambda item: (time.sleep(0.001), seen.append(item)), depth=2) as drain:
        for index in range(10):
            drain.put(index)
    assert seen == list(range(10))

    def explode(item):
        if item == 3:
            raise OSError("disk full")

    drain = Drain(explode, depth=1)
    with pytest.raises(OSError, match="disk full"):
        for index in range(10):
            drain.put(index)
            time.sleep(0.01)
        drain.close()
    with pytest.raises(RuntimeError, match="caller"), Drain(lambda item: None) as failing:  # the caller's error wins
        failing.put(1)
        raise RuntimeError("caller")


def test_finish_behind_keeps_order_overlaps_the_producer_and_raises_when_due():
    from lsr.core.overlap import finish_behind

    started = threading.Event()
    threads = []

    def slow(value):
        def finish():
            threads.append(threading.current_thread().name)
            started.set()
            time.sleep(0.02)
            return value
        return finish

    def produce():
        yield slow(0)
        assert started.wait(5.0)  # the first finisher runs while the producer makes the next item
        yield 1  # a plain item passes through in its place
        yield slow(2)
        yield slow(3)

    assert list(finish_behind(produce())) == [0, 1, 2, 3]
    assert threads and all(name.startswith("lsr-finish") for name in threads)

    def failing():
        raise ValueError("composite failed")

    results = finish_behind(iter([0, failing, 2]))
    assert next(results) == 0
    with pytest.raises(ValueError, match="composite failed"):
        next(results)


def test_single_blas_thread_sets_numpys_openblas_to_one_thread_unless_the_environment_says():
    """In a fresh process (the setting is process-wide): numpy's OpenBLAS is set to one thread, and left alone when
    OPENBLAS_NUM_THREADS is given."""
    import os
    import subprocess
    import sys

    probe = ("import ctypes, re; from lsr.core.overlap import single_blas_thread, BLAS_SETTERS; "
             "done = single_blas_thread(); "
             "paths = sorted(set(re.findall(r'(/\\S*openblas\\S*\\.so\\S*)', open('/proc/self/maps').read()))); "
             "lib = ctypes.CDLL(paths[0]) if paths else None; "
             "get = next((getattr(lib, n.replace('set_', 'get_')) for n in BLAS_SETTERS if lib is not None and hasattr(lib, n)), None); "
             "print(done, get() if get else 'none')")
    env = {key: value for key, value in os.environ.items() if key not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True)
    done, threads = result.stdout.split()
    if threads == "none":
        pytest.skip("numpy here does not use OpenBLAS")
    assert done == "True" and threads == "1"
    env["OPENBLAS_NUM_THREADS"] = "2"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True)
    assert result.stdout.split()[0] == "False"
