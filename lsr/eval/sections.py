"""Sections of BENCHMARKS.md: each is written, between its own markers, by the command it names.

``section_text`` builds one (heading, timestamp, the command that reproduces it, its body); ``replace_section``
puts it in place of the old one (or appends it) and rebuilds the file's summary of headline rows
(``lsr.eval.summary``), in one atomic write; ``command_line`` rebuilds the command from a config.
"""

from __future__ import annotations

import dataclasses
import datetime
import shlex
from pathlib import Path
from typing import Any

from lsr.errors import ConfigError
from lsr.eval.markers import around_block, markers
from lsr.eval.summary import with_summary

HEADER = "# Benchmarks\n\nEvery section is written by the command it names.\n"


def command_line(cfg: Any, prog: str) -> str:
    """The ``prog`` command that reproduces ``cfg`` (the config dataclass' fields that differ from the defaults)."""
    parts = [prog]
    defaults = type(cfg)()
    for field in dataclasses.fields(cfg):
        value = getattr(cfg, field.name)
        if value == getattr(defaults, field.name):
            continue
        flag = "--" + field.name.replace("_", "-")
        if isinstance(value, bool):
            parts.append(flag if value else f"--no-{field.name.replace('_', '-')}")
        elif isinstance(value, (tuple, list)):
            parts.append(" ".join([flag, *(shlex.quote(str(v)) for v in value)]))
        else:
            parts.append(f"{flag} {shlex.quote(str(value))}")
    return " ".join(parts)


def section_text(name: str, title: str, command: str, body: str, note: str | None = None) -> str:
    """A whole section: markers, ``## title``, when and by which command it was written, the note, the body."""
    start, end = markers(name)
    stamp = f"{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}"
    lines = [start, f"## {title}", "", f"_Written by the command below on {stamp}; do not edit the numbers by hand, "
             "re-run it._", "", f"```\n{command}\n```", ""]
    if note:
        lines += [f"**Note:** {note}", ""]
    lines += [body.strip("\n"), "", end]
    return "\n".join(lines) + "\n"


def replace_section(path: Path, section: str, start: str, end: str) -> Path:
    """Put ``section`` (markers included) into ``path`` between the markers ``start`` / ``end``, replacing the old
    one in place and keeping every other line; appended when the file has none. The summary at the top is rebuilt
    from the sections in the same write (``lsr.eval.summary.with_summary``), so every command that writes a section
    refreshes it. Atomic."""
    from landmarks.io.image_files import atomic_output

    path = Path(path)
    text = path.read_text() if path.is_file() else HEADER
    try:
        around = around_block(text, start, end)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    text = around[0] + section + around[1] if around else text.rstrip("\n") + "\n\n" + section
    try:
        updated, failure = with_summary(text), None
    except ConfigError as error:  # the summary's markers need mending by hand: the measured section is kept
        updated, failure = text, ConfigError(f"{path}: {error}")
    with atomic_output(path) as temp:
        temp.write_text(updated)
    if failure is not None:
        raise failure
    return path


def write_section(path: Path, name: str, title: str, command: str, body: str, note: str | None = None) -> Path:
    """``section_text`` put into ``path`` by ``replace_section``."""
    return replace_section(Path(path), section_text(name, title, command, body, note), *markers(name))


def publish(cfg: Any, prog: str, section: str, title: str, text: str) -> Path | None:
    """Print a benchmark's table and, with ``cfg.out_md``, write it as the BENCHMARKS.md section ``section`` under
    ``title`` with the command line that reproduces it (``prog``: e.g. "lsr bench hard"). Returns the file written."""
    print(text)
    if cfg.out_md is None:
        return None
    path = write_section(cfg.out_md, section, title, command_line(cfg, prog), text)
    print(f"section eval:{section} written to {path}")
    return path
