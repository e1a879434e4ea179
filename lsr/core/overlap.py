"""Overlapping the stages of a frame loop on threads with bounded queues (``lsr reenact``'s stages).

The network keeps the calling thread. The frames are made ready on threads ahead of it (``prefetch``: decoding and
tracking on one, smoothing, retargeting and the warps of the shots on the next), each frame's paste-back runs on a
worker behind it (``finish_behind``) and encoding behind that (``Drain``), each at most ``depth`` frames away, so
memory stays bounded and a slow stage only slows its own thread. Video decoding and encoding (PyAV), OpenCV, numpy
and onnxruntime release the GIL, so on two cores the stages really overlap (with ``single_blas_thread``). An error on
a worker thread is raised in the caller, at the next frame or at ``close``; nothing is lost silently.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")
_END = object()
DEPTH = 4  # frames a stage may run ahead of (or behind) the next one


def network_threads(requested: int = 0) -> int:
    """Threads for the network: ``requested`` when > 0, else all usable cores but one, which the decoding, tracking
    and encoding threads take (on 2 cores: 1, which ran ``lsr reenact`` end to end 1.4-1.8x faster than the
    libraries' defaults, whose idle threads spin on the core the other stages need)."""
    import os

    if requested > 0:
        return int(requested)
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, cores - 1)


BLAS_SETTERS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads", "openblas_set_num_threads64_",
                "openblas_set_num_threads")  # numpy's bundled OpenBLAS (numpy 2) and a system one


def single_blas_thread() -> bool:
    """Run numpy's BLAS (OpenBLAS) on one thread, unless OPENBLAS_NUM_THREADS / OMP_NUM_THREADS say otherwise; True
    when a BLAS was set. The frame loop's stages already fill the cores, and OpenBLAS's idle threads spin: on 2 cores
    they burned ~35 ms of CPU a frame in ``lsr reenact`` (onnx, the shared tpsmm_driving.mp4 with paste-back: 86-92
    against 53-57 ms of CPU a frame, 22 against 31-34 fps), and one thread is also faster for the warps' small
    products alone (synthesis-only 26 against 28 ms). Process-wide: the ``lsr`` command calls it; a program
    embedding the runtime may too (``deploy/example_embed.py``). Linux (reads /proc/self/maps); elsewhere False.
    OpenCV's own threads are left as they are: one OpenCV thread was slower end to end (the same run, onnx: 29.4
    and 33.1 against 34.5 and 36.4 fps)."""
    import ctypes
    import os
    import re

    import numpy  # noqa: F401 - loads the BLAS this sets

    if os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS"):
        return False
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            paths = sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", maps.read())))
    except OSError:
        return False
    found = False
    for path in paths:
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(library, name) for name in BLAS_SETTERS if hasattr(library, name)), None)
        if setter is not None:
            setter(1)
            found = True
    return found


class _Failure:
    def __init__(self, error: BaseException) -> None:
        self.error = error


def prefetch(items: Iterable[T], depth: int = DEPTH) -> Iterator[T]:
    """``items`` produced on a thread, up to ``depth`` ahead of the consumer; errors re-raised in order."""
    buffer: queue.Queue = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        buffer.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            buffer.put(_END)
        except BaseException as error:  # noqa: BLE001 - handed to the consumer
            buffer.put(_Failure(error))
        finally:
            _close(items)  # here, where it ran: a nested stage's own thread stops before this one ends

    thread = threading.Thread(target=produce, name="lsr-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item = buffer.get()
            if item is _END:
                return
            if isinstance(item, _Failure):
                raise item.error
            yield item
    finally:
        stop.set()  # the consumer stopped early (an error, a break): let the producer end
        while thread.is_alive():
            try:
                buffer.get_nowait()
            except queue.Empty:
                thread.join(timeout=0.05)


class Drain(Generic[T]):
    """Calls ``consume(item)`` on a thread for each ``put`` item, at most ``depth`` behind; ``close`` waits for the
    rest and re-raises the first error (``put`` raises it as soon as it is known). A context manager."""

    def __init__(self, consume: Callable[[T], None], depth: int = DEPTH) -> None:
        self._consume = consume
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="lsr-drain", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _END:
                return
            if self._error is None:
                try:
                    self._consume(item)
                except BaseException as error:  # noqa: BLE001 - re-raised by put / close
                    self._error = error

    def put(self, item: T) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put(item)

    def close(self) -> None:
        if self._thread.is_alive():
            self._queue.put(_END)
            self._thread.join()
        if self._error is not None:
            raise self._error

    def __enter__(self) -> Drain[T]:
        return self

    def __exit__(self, kind, error, trace) -> None:
        if kind is None:
            self.close()
        else:  # the caller failed: stop the thread, keep the caller's error
            self._error = self._error or error
            if self._thread.is_alive():
                self._queue.put(_END)
                self._thread.join()


def finish_behind(items: Iterable[T | Callable[[], T]], depth: int = 1) -> Iterator[T]:
    """``items`` in order, where a callable item is finished (called) on a worker thread while the producer makes
    the next items, at most ``depth`` of them in flight: a frame's last stage (the paste-back) overlaps the next
    frame's synthesis. Items that are not callable pass through in their place. An error in a finisher is raised
    when its item is due; the producer's own error after the items before it."""
    from collections import deque
    from concurrent.futures import Future, ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="lsr-finish") as pool:
        pending: deque = deque()
        try:
            for item in items:
                pending.append(pool.submit(item) if callable(item) else item)
                while len(pending) > depth:
                    done = pending.popleft()
                    yield done.result() if isinstance(done, Future) else done
            while pending:
                done = pending.popleft()
                yield done.result() if isinstance(done, Future) else done
        finally:  # stopped early (an error, a close): the stages before this one stop too, their threads joined
            _close(items)


def _close(items) -> None:
    """Close a generator (running its ``finally`` blocks: an upstream ``prefetch`` joins its thread); others: nothing."""
    close = getattr(items, "close", None)
    if close is not None:
        close()

