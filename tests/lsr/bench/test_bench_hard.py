"""``lsr bench hard`` on synthetic material with a tiny model: every case ends in ok or one clear line, never a
traceback or a non-finite number, and a traceback inside a case fails the run."""

from __future__ import annotations

import pytest

from lsr.config import BenchHardConfig
from lsr.errors import LsrError
from lsr.bench import bench_hard


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    import torch

    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    return LSRModel(preset_config("tiny")).save_pretrained(tmp_path_factory.mktemp("w") / "tiny")


@pytest.fixture
def synthetic_only(monkeypatch):
    monkeypatch.setattr(BenchHardConfig, "resolved_clips", lambda self: (None, None))


CASES = ("very dark", "1 shot", "driver leaves frame", "1-frame driver", "30 landmarks")  # in the bench's order


def test_cases_end_in_ok_or_one_line_and_the_table_is_finite(tiny_weights, synthetic_only, tmp_path, capsys):
    cfg = BenchHardConfig(weights=tiny_weights, long_frames=30, cases=CASES, out_md=tmp_path / "B.md", progress=False)
    results = bench_hard.run_bench_hard(cfg)
    names = [r.name for r in results]
    assert names == ["easy", "easy_synthetic", *CASES]
    for result in results:
        assert result.traceback is None
        assert result.outcome == "ok" or (result.outcome.startswith("error: ") and "\n" not in result.outcome)
    by_name = {r.name: r for r in results}
    assert by_name["30 landmarks"].frames == 30 and by_name["1-frame driver"].frames == 1
    assert by_name["driver leaves frame"].driver_without_face > 0  # the pan really leaves the face out
    assert all(r.nonfinite_frames == 0 for r in results)
    section = (tmp_path / "B.md").read_text()
    assert "<!-- eval:hard_cases:start -->" in section and "lsr bench hard" in section
    table = section.split("| case |", 1)[1].split("| machine |", 1)[0].lower()
    assert "nan" not in table.replace("nana", "") and " inf" not in table
    assert "/tmp/lsr-bench-hard-" not in section  # case files' temp folder is not shown


def test_a_traceback_in_a_case_is_recorded_and_fails_the_run(tiny_weights, synthetic_only, monkeypatch, capsys):
    original = bench_hard._driver_file

    def broken(case, folder):
        if case.name == "1 shot":
            raise RuntimeError("a bug, not a user error")
        return original(case, folder)

    monkeypatch.setattr(bench_hard, "_driver_file", broken)
    cfg = BenchHardConfig(weights=tiny_weights, long_frames=5, cases=("1 shot",), progress=False)
    with pytest.raises(LsrError, match=r"1 hard case\(s\) ended in a traceback: 1 shot"):
        bench_hard.run_bench_hard(cfg)
    printed = capsys.readouterr().out
    assert "TRACEBACK RuntimeError: a bug, not a user error" in printed and "Traceback (most recent call last)" in printed
