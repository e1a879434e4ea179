"""The summary at the top of BENCHMARKS.md (lsr.eval.summary): headline rows copied out of the sections' tables,
rebuilt by every command that writes a section, never a made-up value."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from lsr.errors import ConfigError
from lsr.eval import sections, summary
from lsr.eval.summary import (SUMMARY_END, SUMMARY_START, headlines, shipped, with_summary,
                               write_summary)

REPO = Path(__file__).resolve().parents[3]
SELF_HEADER = "| method | K | frames | PSNR ↑ | SSIM ↑ | sharpness →1 |\n|---|---|---|---|---|---|\n"


def protocol_body(rows: str) -> str:
    return f"data: made up\n\n### Self re-enactment (hold-out frames)\n\n{SELF_HEADER}{rows}\n### Notes\n\n- none\n"


def live_body(fps: str) -> str:
    return ("Model the default.\n\n| where | frames shown | seconds | fps | latency ms, median |\n"
            "|---|---|---|---|---|\n"
            f"| browser and app on these 2 cores (loopback) | 500 | 30.0 | {fps} | 170 (camera grab to picture) |\n")


def eyes_body(bank: str) -> str:
    head = "| pair | eyes from | eye r | realism ↓ (x floor) | switches |\n|---|---|---|---|---|\n"
    pairs = [(0.8, 0.30, 0.010), (0.6, 0.50, 0.020), (0.9, 0.70, 0.030)]
    rows = "".join(f"| p{i} ← p{i + 1} | agreement / floor | {agree} | 0.010 | |\n"
                   f"| | {bank} | {ours} (0.5) | {floor * 2:.3f} ({2 + i}.00) | 3 |\n"
                   f"| | none | 0.10 (0.1) | 0.090 ({9 + i}.00) | |\n" for i, (agree, ours, floor) in enumerate(pairs))
    return head + rows


def benchmarks(*parts: tuple[str, str]) -> str:
    """A small BENCHMARKS.md: the header, a hand-written line, then ``(name, body)`` sections."""
    text = sections.HEADER + "\nHand-written intro line.\n"
    for name, body in parts:
        text += "\n" + sections.section_text(name, f"Title of {name} (`lsr x`)", f"lsr x --{name}", body)
    return text


K = shipped()["k"]
DEFAULT = f"| lsr:warp_guided | {K} | 9 | 19.00 | 0.650 | 0.70 |\n"
BASELINES = (f"| tps | {K} | 9 | 17.50 | 0.660 | 1.02 |\n| tps_mean3 | {K} | 9 | 18.50 | 0.640 | 0.45 |\n"
             f"| lsr:warp_guided+blend-eyes | {K} | 9 | 25.00 | 0.900 | 1.00 |\n"
             "| nearest_shot | 1 | 9 | 30.00 | 0.99 | 1.00 |\n")


def rows_of(text: str) -> dict[str, tuple[str, str]]:
    return {row.measure: (row.default, row.baseline) for row in headlines(text)}


class TestExtractors:
    def test_a_section_gives_its_rows_with_the_best_baseline_by_the_arrow(self):
        found = rows_of(benchmarks(("fsth_warp_guided", protocol_body(BASELINES + DEFAULT))))
        assert found[f"FSTH sample, K = {K}, self: PSNR ↑"] == ("19.00", "18.50 (tps_mean3)")
        assert found[f"FSTH sample, K = {K}, self: SSIM ↑"] == ("0.650", "0.660 (tps)")  # a baseline may win
        assert found[f"FSTH sample, K = {K}, self: sharpness →1"] == ("0.70", "1.02 (tps)")  # nearest 1
        # the variants (+...) and other K are neither the default nor baselines; absent tables give no row
        assert len(found) == 3

    def test_absent_sections_and_rows_give_no_row(self):
        assert headlines(benchmarks()) == []
        assert headlines(benchmarks(("fsth", protocol_body(BASELINES + DEFAULT)))) == []  # not a chosen section
        assert headlines(benchmarks(("fsth_warp_guided", protocol_body(BASELINES)))) == []  # no default row
        other_k = DEFAULT.replace(f"| {K} |", "| 32 |")
        assert headlines(benchmarks(("fsth_warp_guided", protocol_body(BASELINES + other_k)))) == []
        missing = DEFAULT.replace("19.00", "–")
        assert f"FSTH sample, K = {K}, self: PSNR ↑" not in rows_of(benchmarks(("fsth_warp_guided",
                                                                              protocol_body(BASELINES + missing))))
        assert headlines(benchmarks(("live", live_body("–")))) == []  # a cell without a number
        assert headlines(benchmarks(("eyes_set", eyes_body("not_the_default_bank")))) == []
        no_end = benchmarks(("live", live_body("17.4"))).replace("<!-- eval:live:end -->", "")
        assert headlines(no_end) == []  # half a section is no section

    def test_without_baselines_the_baseline_cell_is_a_dash(self):
        found = rows_of(benchmarks(("clips_cross", protocol_body(DEFAULT))))
        assert found == {f"shared clips, K = {K}, self: PSNR ↑": ("19.00", "–")}

    def test_eyes_medians_over_the_pairs_beside_the_synthesis_eyes(self):
        bank = shipped()["bank"]
        (row,) = headlines(benchmarks(("eyes_mine", eyes_body(bank))))
        assert row.measure.startswith("eyes over whole clips, mine (3 pairs; medians)")
        assert "(the detectors agree: 0.80)" in row.measure
        assert row.default == f"eye r 0.50, realism 3.00x floor (bank {bank})"
        assert row.baseline == "eye r 0.10, realism 10.00x floor (the synthesis' eyes)"

    def test_live_takes_the_numbers_as_printed(self):
        (row,) = headlines(benchmarks(("live", live_body("17.4"))))
        assert row.default == "17.4 fps, 170 ms" and row.baseline == "–" and row.section.program == "lsr x"

    def test_slugs_follow_github_and_count_repeats(self):
        assert summary.slug("Speed vs error (`lsr bench speed`)") == "speed-vs-error-lsr-bench-speed"
        assert summary.slug("Ablation, Table 4.2: the thesis'") == "ablation-table-42-the-thesis"
        where = summary.anchors("# A\n\n## Self\n\n```\n# not a heading\n```\n\n## B\n\n### Self\n")
        assert where == {"A": "a", "Self": "self", "B": "b"}  # the first of equal headings
        assert summary.anchors("## Self\n## Self\n## Self-1\n")["Self-1"] == "self-1-1"


@dataclasses.dataclass
class BenchConfig:
    out_md: Path | None = None
    frames: int = 10


class TestWritten:
    def test_publish_puts_one_block_before_the_first_section_and_replaces_it(self, tmp_path, capsys):
        path = tmp_path / "BENCHMARKS.md"
        original = benchmarks(("finetune_curve", "| a | b |\n|---|---|\n| 1 | 2 |\n"))
        path.write_text(original)
        cfg = BenchConfig(out_md=path)
        sections.publish(cfg, "lsr bench live", "live", "Live (`lsr bench live`)", live_body("17.4"))
        first = path.read_text()
        assert first.count(SUMMARY_START) == first.count(SUMMARY_END) == 1
        assert first.index("Hand-written intro line.") < first.index(SUMMARY_START) < first.index("<!-- eval:")
        assert "| 17.4 fps, 170 ms | – | [`lsr bench live`](#live-lsr-bench-live), " in first

        sections.publish(cfg, "lsr bench live", "live", "Live (`lsr bench live`)", live_body("21.0"))
        second = path.read_text()
        assert second.count(SUMMARY_START) == second.count(SUMMARY_END) == 1
        assert "21.0 fps" in second and "17.4 fps" not in second
        # outside the block every byte is kept: the summary out, the file is the old one with the new section
        block = second[second.index(SUMMARY_START):second.index(SUMMARY_END) + len(SUMMARY_END) + 1]
        without = second.replace(block + "\n", "", 1)
        assert without.startswith(original.rstrip("\n") + "\n\n<!-- eval:live:start -->\n")
        assert without.endswith("<!-- eval:live:end -->\n") and without.count("<!-- eval:live:start -->") == 1
        assert with_summary(second) == second  # rebuilding again changes nothing
        capsys.readouterr()

    def test_a_rebuild_changes_only_the_block(self, tmp_path):
        path = tmp_path / "B.md"
        path.write_text(benchmarks(("live", live_body("17.4")), ("web", "no table here\n")))
        write_summary(path)
        before = path.read_text()
        edited = before.replace("| 17.4 | 170", "| 19.9 | 170")  # the section changed under the summary
        path.write_text(edited)
        write_summary(path)
        after = path.read_text()
        assert "19.9 fps" in after
        start, end = after.index(SUMMARY_START), after.index(SUMMARY_END)
        old_start, old_end = edited.index(SUMMARY_START), edited.index(SUMMARY_END)
        assert after[:start] == edited[:old_start] and after[end:] == edited[old_end:]

    def test_files_without_headline_rows_get_no_block(self, tmp_path):
        path = tmp_path / "B.md"
        path.write_text("# Mine\n\nintro\n")
        sections.write_section(path, "hard_cases", "Hard", "lsr bench hard", "| a |\n|---|\n| 1 |\n")
        assert SUMMARY_START not in path.read_text()
        empty = "# Mine\n\n" + SUMMARY_START + "\nold\n" + SUMMARY_END + "\n\nrest\n"  # a block stays, says so
        assert "No section below gives a headline row yet." in with_summary(empty)
        assert with_summary(empty).endswith(SUMMARY_END + "\n\nrest\n")

    def test_broken_summary_markers_are_a_clear_error_after_the_section_is_written(self, tmp_path):
        path = tmp_path / "B.md"
        path.write_text(benchmarks() + "\n" + SUMMARY_START + "\n")
        with pytest.raises(ConfigError, match="unbalanced or repeated"):
            sections.write_section(path, "live", "Live", "lsr bench live", live_body("17.4"))
        assert "<!-- eval:live:end -->" in path.read_text()  # the measured section is not lost


def test_the_committed_summary_is_the_one_the_code_writes():
    text = (REPO / "BENCHMARKS.md").read_text()
    assert text.count(SUMMARY_START) == 1 and with_summary(text) == text, \
        "BENCHMARKS.md's summary is stale: run lsr.eval.sections.write_summary('BENCHMARKS.md')"
