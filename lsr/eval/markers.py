"""The marker pairs that delimit a block of a markdown file (a BENCHMARKS.md section, its summary), and splitting
a text around one: shared by ``lsr.eval.sections`` and ``lsr.eval.summary``."""

from __future__ import annotations

from lsr.errors import ConfigError


def markers(name: str, kind: str = "eval") -> tuple[str, str]:
    """The start / end markers of section ``name`` (``<!-- eval:NAME:start -->``)."""
    return f"<!-- {kind}:{name}:start -->", f"<!-- {kind}:{name}:end -->"


def around_block(text: str, start: str, end: str, fix: str = "one pair") -> tuple[str, str] | None:
    """(the text before the block ``start`` ... ``end``, the text after it without its first newline), or None when
    ``text`` has no such block. Unbalanced, repeated or reversed markers are a ``ConfigError`` that says how to
    ``fix`` them by hand."""
    starts, ends = text.count(start), text.count(end)
    if starts != ends or starts > 1 or (starts and text.index(end) < text.index(start)):
        raise ConfigError(f"the markers {start} / {end} are unbalanced or repeated; fix them by hand ({fix}) and "
                          "re-run")
    if not starts:
        return None
    before, rest = text.split(start, 1)
    return before, rest.split(end, 1)[1].removeprefix("\n")
