"""`lsr bench speed`: Pareto front, section replacement, and one end-to-end run on a tiny model at 64^2."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lsr.config import BenchSpeedConfig
from lsr.errors import ConfigError
from lsr.bench.bench_speed import SECTION_END, SECTION_START, command_line, parse_weights, replace_section
from lsr.bench.pareto import pareto_front, plot_speed_error, y_axis_range


class TestParetoFront:
    def test_dominated_points_are_excluded(self):
        # (ms, PSNR): C is slower and worse than B; D is slower than A at the same PSNR.
        points = [(10.0, 20.0), (5.0, 18.0), (8.0, 17.0), (12.0, 20.0), (2.0, 15.0)]
        assert pareto_front(points) == [4, 1, 0]

    def test_lower_is_better_metric(self):
        points = [(10.0, 0.05), (5.0, 0.07), (8.0, 0.08), (20.0, 0.04)]  # (ms, NMKE)
        assert pareto_front(points, higher_y_is_better=False) == [1, 0, 3]

    def test_exact_ties_stay_on_the_front(self):
        points = [(5.0, 18.0), (5.0, 18.0), (6.0, 18.0)]
        assert pareto_front(points) == [0, 1]

    def test_same_time_better_error_wins(self):
        assert pareto_front([(5.0, 18.0), (5.0, 19.0)]) == [1]

    def test_non_finite_points_are_never_on_the_front(self):
        assert pareto_front([(math.nan, 30.0), (5.0, math.inf), (6.0, 10.0)]) == [2]

    def test_plot_is_an_rgb_image(self):
        image = plot_speed_error([(3.0, 20.0), (30.0, 22.0)], ["a", "b"], ["eager", "int8"],
                                 y_label="PSNR", higher_y_is_better=True, title="t")
        assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
        assert (image < 255).any()

    def test_axis_keeps_a_minimum_span_for_near_ties(self):
        # two runtimes of one model 0.003 dB apart must not fill a PSNR axis
        low, high = y_axis_range(np.array([26.337, 26.340]), min_span=0.5)
        assert high - low == pytest.approx(0.6) and low < 26.337 < 26.340 < high
        assert (26.3385 - low) == pytest.approx(high - 26.3385)  # centred on the points
        low, high = y_axis_range(np.array([18.0, 22.0]), min_span=0.5)  # wider data: 10 % margins
        assert (low, high) == pytest.approx((17.6, 22.4))


class TestSection:
    def test_replaces_in_place_and_keeps_other_text(self, tmp_path):
        path = tmp_path / "BENCHMARKS.md"
        path.write_text(f"# Top\n\nbefore\n\n{SECTION_START}\nold numbers\n{SECTION_END}\n\nafter\n")
        replace_section(path, f"{SECTION_START}\nnew numbers\n{SECTION_END}\n")
        text = path.read_text()
        assert "old numbers" not in text and "new numbers" in text
        assert text.startswith("# Top\n\nbefore\n\n") and text.endswith("\nafter\n")
        assert text.count(SECTION_START) == 1

    def test_appends_when_absent_and_rejects_broken_markers(self, tmp_path):
        path = tmp_path / "B.md"
        path.write_text("# Mine\n")
        replace_section(path, f"{SECTION_START}\nx\n{SECTION_END}\n")
        assert path.read_text().startswith("# Mine\n\n" + SECTION_START)
        path.write_text(f"{SECTION_START}\nno end\n")
        with pytest.raises(ConfigError, match="unbalanced"):
            replace_section(path, f"{SECTION_START}\nx\n{SECTION_END}\n")

    def test_weights_items_are_checked(self, tmp_path):
        assert parse_weights([f"tiny={tmp_path}"]) == {"tiny": tmp_path}
        with pytest.raises(ConfigError, match="PRESET=DIR"):
            parse_weights(["tiny"])
        with pytest.raises(ConfigError, match="not a folder"):
            parse_weights([f"tiny={tmp_path / 'missing'}"])

    def test_command_line_lists_changed_options(self):
        text = command_line(BenchSpeedConfig(presets=("tiny",), runs=3, progress=False))
        assert text == "lsr bench speed --presets tiny --runs 3 --no-progress"


@pytest.mark.slow
def test_end_to_end_writes_section_json_and_plot(tmp_path):
    import torch

    from lsr.data.synth import generate_dataset
    from lsr.bench.bench_speed import run_bench_speed
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    weights = tmp_path / "tiny_weights"
    LSRModel(preset_config("tiny")).save_pretrained(weights)  # random weights: the error is real, just large
    split = tmp_path / "split"
    generate_dataset(split, identities=2, videos_per_identity=1, frames=8, size=64, seed=3, test_fraction=0.5, progress=False)
    out_md = tmp_path / "BENCHMARKS.md"
    out_md.write_text(f"# Benchmarks\n\nhand-written intro\n\n{SECTION_START}\nstale\n{SECTION_END}\n\n## Other\nkept\n")
    cfg = BenchSpeedConfig(presets=("tiny", "fast"), resolutions=(64,), runtimes=("eager", "onnxruntime", "int8"),
                           weights=(f"tiny={weights}",), k=(1, 2), runs=2, warmup=0, encoder_runs=1, out_md=out_md,
                           synthetic_root=split, note="random weights (test)", threads=1, progress=False)
    cfg.validate()
    result = run_bench_speed(cfg)

    text = out_md.read_text()
    assert "stale" not in text and "hand-written intro" in text and text.rstrip().endswith("## Other\nkept")
    assert text.count(SECTION_START) == 1 and "random weights (test)" in text
    table = [line for line in text.splitlines() if line.startswith("| tiny |") or line.startswith("| fast |")]
    assert len(table) == 2 * 3  # preset x runtime at one resolution
    fast_rows = [line for line in table if line.startswith("| fast |")]
    assert all("not computed (no trained weights for fast" in line for line in fast_rows)

    rows = result["rows"]
    tiny = {row["runtime"]: row for row in rows if row["preset"] == "tiny"}
    for runtime in ("eager", "onnxruntime", "int8"):
        assert isinstance(tiny[runtime]["frame_ms"], float) and tiny[runtime]["frame_ms"] > 0
        errors = tiny[runtime]["error_synthetic"]
        assert set(errors) == {"1", "2"} and 0 < errors["1"]["psnr"] < 100 and 0 <= errors["1"]["ssim"] <= 1
    # onnxruntime fp32 reproduces the torch pipeline; int8 differs from it but stays close.
    assert tiny["onnxruntime"]["error_synthetic"]["1"]["psnr"] == pytest.approx(tiny["eager"]["error_synthetic"]["1"]["psnr"], abs=0.05)
    assert tiny["int8"]["error_synthetic"]["1"]["psnr"] == pytest.approx(tiny["eager"]["error_synthetic"]["1"]["psnr"], abs=3.0)

    stored = json.loads((tmp_path / "docs" / "bench_speed.json").read_text())  # beside its plot
    assert len(stored["rows"]) == 6 and stored["ks"] == [1, 2]
    png = tmp_path / "docs" / "bench_speed.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "docs/bench_speed.png" in text


@pytest.mark.slow
def test_warp_guided_rows_time_the_warps_too(tmp_path):
    """A warp-guided model's per-frame path is its shots' TPS warps + the network: both timed, and their sum; its
    int8 graph is calibrated on real inputs, the warped shots included (a traceback before)."""
    import torch

    from lsr.data.synth import generate_dataset
    from lsr.bench.bench_speed import run_bench_speed
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "warp")
    split = tmp_path / "split"
    generate_dataset(split, identities=2, videos_per_identity=1, frames=12, size=64, seed=3, test_fraction=0.5, progress=False)
    cfg = BenchSpeedConfig(presets=("tiny",), resolutions=(64,), runtimes=("eager", "onnxruntime", "int8"), weights=(f"tiny={weights}",),
                           k=(2,), runs=2, warmup=0, encoder_runs=1, out_md=tmp_path / "B.md", synthetic_root=split,
                           threads=1, progress=False)
    rows = run_bench_speed(cfg)["rows"]
    assert {row["runtime"] for row in rows} >= {"int8"}
    for row in rows:
        assert row["warp_ms"] > 0 and row["total_ms"] == pytest.approx(row["frame_ms"] + row["warp_ms"])
        assert 0 < row["error_synthetic"]["2"]["psnr"] < 100
