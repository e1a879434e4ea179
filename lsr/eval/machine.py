"""Machine description printed above benchmark tables (numbers mean little without it)."""

from __future__ import annotations

import datetime
import importlib.metadata
import os
import platform
from pathlib import Path


def cpu_fields() -> dict[str, str]:
    """The first processor's fields of /proc/cpuinfo ("model name", "vendor_id", "cpu family", "model", ...); {}
    where it cannot be read (not Linux)."""
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return {}
    fields: dict[str, str] = {}
    for line in text.split("\n\n", 1)[0].splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip().lower(), value.strip())
    return fields


def cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (Linux), else what ``platform`` knows."""
    return cpu_fields().get("model name") or platform.processor() or platform.machine() or "unknown"


def _version(distribution: str) -> str | None:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


def _load_average() -> tuple[float, ...]:
    try:
        return os.getloadavg()
    except (AttributeError, OSError):  # not available on this OS
        return ()


def usable_cores() -> int:
    """The cores this process may run on (its affinity on Linux), else the logical CPU count (0: unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 0


def machine_info() -> dict[str, str]:
    """CPU, cores, OS, Python and library versions, date. Versions come from package metadata
    (no heavy imports); libraries that are not installed are left out."""
    info = {
        "date": datetime.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"),
        "cpu": cpu_model(),
        "cores": f"{usable_cores()} usable / {os.cpu_count()} logical",
        "os": f"{platform.system()} {platform.release()}",
        # Timings on a shared machine scale with its load: quote it beside them.
        "load average (1/5/15 min)": " / ".join(f"{load:.1f}" for load in _load_average()),
        "python": platform.python_version(),
    }
    for label, distribution in (
        ("numpy", "numpy"),
        ("opencv", "opencv-contrib-python-headless"),
        ("dlib", "dlib-bin"),
        ("av", "av"),
        ("torch", "torch"),
        ("onnxruntime", "onnxruntime"),
    ):
        version = _version(distribution)
        if version is not None:
            info[label] = version
    return info


def machine_markdown() -> str:
    """``machine_info`` as a two-column markdown table."""
    lines = ["| machine | |", "|---|---|"]
    lines += [f"| {key} | {value} |" for key, value in machine_info().items()]
    return "\n".join(lines)


REPO_ROOT = Path(__file__).resolve().parents[2]


def shown_path(path: str | os.PathLike[str], root: Path = REPO_ROOT, home: Path | None = None) -> str:
    """A path as benchmark tables print it: relative to the repository (``lsr/weights/default``,
    ``../shared/data/...`` beside it), else under ``~``, else as given; never this machine's absolute layout."""
    home = Path.home() if home is None else home
    resolved = Path(os.path.abspath(os.path.expanduser(str(path))))
    if resolved == root or root in resolved.parents or root.parent in resolved.parents:
        return os.path.relpath(resolved, root)
    if home in resolved.parents:
        return str(Path("~") / resolved.relative_to(home))
    return str(path)
