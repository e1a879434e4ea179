"""Sections of BENCHMARKS.md: each is written, between its own markers, by the command it names.

``section_text`` builds one (heading, timestamp, the command that reproduces it, its body); ``replace_section``
puts it in place of the old one (or appends it), atomically, then rebuilds the file's summary of headline rows
(``lsr.eval.summary.write_summary``); ``command_line`` rebuilds the command from a config.
"""

from __future__ import annotations

import dataclasses
import datetime
import shlex
from pathlib import Path
from typing import Any

from lsr.errors import ConfigError
from lsr.eval.summary import write_summary

HEADER = "# Benchmarks\n\nEvery section is written by the command it names.\n"


def markers(name: str, kind: str = "eval") -> tuple[str, str]:
    """The start / end markers of section ``name`` (``<!-- eval:NAME:start -->``)."""
    return f"<!-- {kind}:{name}:start -->", f"<!-- {kind}:{name}:end -->"


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
    one in place and keeping every other line; appended when the file has none. Atomic. Then the summary at the
    top is rebuilt from the sections (``write_summary``), so every command that writes a section refreshes it."""
    from landmarks.io.image_files import atomic_output

    path = Path(path)
    text = path.read_text() if path.is_file() else HEADER
    starts, ends = text.count(start), text.count(end)
    if starts != ends or starts > 1:
        raise ConfigError(f"{path}: the markers {start} / {end} are unbalanced or repeated; "
                          "fix them by hand (one pair) and re-run")
    if starts:
        before, rest = text.split(start, 1)
        _, after = rest.split(end, 1)
        after = after[1:] if after.startswith("\n") else after
        text = before + section + after
    else:
        text = text.rstrip("\n") + "\n\n" + section
    with atomic_output(path) as temp:
        temp.write_text(text)
    # a second write: the section is on disk even if the summary's markers need mending by hand
    return write_summary(path)


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
