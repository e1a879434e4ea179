"""Every command that writes refuses an output it cannot write before any work, in one line with exit 2."""

from __future__ import annotations

import pytest

from lsr.cli import main


@pytest.mark.parametrize(
    "command",
    [
        ["prepare", "{here}"],
        ["eval", "--k", "1"],
        ["finetune", "{here}/shot.png"],
        ["export"],
        ["landmarks", "{here}/shot.png"],
        ["reenact", "--source", "{here}/shot.png", "--driver", "{here}/shot.png"],
        ["curves", "{here}"],
    ],
    ids=lambda command: command[0],
)
def test_an_output_under_a_file_is_one_line_and_exit_2(tmp_path, capsys, command):
    (tmp_path / "shot.png").write_bytes(b"never read: the output is checked first")
    (tmp_path / "blocker").write_text("a file where a folder would have to be")
    out = tmp_path / "blocker" / ("out.mp4" if command[0] == "reenact" else "out")
    args = [part.format(here=tmp_path) for part in command] + ["--out", str(out)]
    assert main(args) == 2
    error = capsys.readouterr().err
    assert error.startswith("lsr: error: --out") and error.count("\n") == 1, error
    assert str(tmp_path / "blocker") in error and "choose another folder" in error


def test_side_commands_fail_in_one_line(tmp_path, capsys):
    """The former `python -m` entry points are sub-commands with the CLI's errors."""
    assert main(["curves", str(tmp_path), "--out", str(tmp_path / "c.png")]) == 2  # a folder without scalars
    assert "no TensorBoard scalars" in capsys.readouterr().err
    assert main(["bench", "oracle-seg", str(tmp_path)]) == 2
    assert "no *_segmap_merged.png" in capsys.readouterr().err
    assert main(["ship", str(tmp_path / "missing")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert main(["ship", str(tmp_path)]) == 2  # a folder that is not a model
    assert "not a model folder" in capsys.readouterr().err
