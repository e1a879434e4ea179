"""The README's commands stay true: every `lsr ...` line in its code blocks parses with today's CLI."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_commands() -> list[list[str]]:
    """Arguments after `lsr` (or `-m lsr.cli`) of each command line in the README's bash blocks."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith("#") or not line:
                continue
            tokens = shlex.split(line, comments=True)
            if tokens[:1] == ["lsr"]:
                commands.append(tokens[1:])
            elif "lsr.cli" in tokens:
                commands.append(tokens[tokens.index("lsr.cli") + 1 :])
    return commands


def test_readme_has_exactly_two_setup_commands():
    setup = README.read_text().split("## Set-up on a fresh machine", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"```bash\n(.*?)```", setup, flags=re.S) == ["make demo\n", "make test\n"]


@pytest.mark.parametrize("args", readme_commands(), ids=lambda a: " ".join(a[:2]))
def test_readme_command_parses(args):
    import tyro

    from lsr.cli import COMMANDS, GROUPS

    if args[0] in GROUPS:
        cls, rest = GROUPS[args[0]][args[1]][0], args[2:]
    else:
        cls, rest = COMMANDS[args[0]][0], args[1:]
    tyro.cli(cls, args=rest)  # SystemExit (a failed test) on an unknown or malformed flag


def test_help_shows_metavars_not_none_noise():
    """Optional options read `--weights PATH ... (optional)`, never `{None}|PATH` or `(default: None)`."""
    import contextlib
    import io

    from lsr.cli import COMMANDS, GROUPS, main

    commands = [[name] for name in COMMANDS] + [[group, name] for group, table in GROUPS.items() for name in table]
    for command in commands:
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
            main([*command, "--help"])
        text = out.getvalue()
        assert "usage" in text and "{None}" not in text and "(default: None)" not in text, (command, text[:400])
