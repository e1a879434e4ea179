"""`lsr bench finetune`: the steps-vs-error curve on a tiny warp-guided model over a synthetic split."""

from __future__ import annotations

import pytest

from lsr.config import BenchFinetuneConfig
from lsr.errors import ConfigError


def test_bad_options_are_clear_errors():
    with pytest.raises(ConfigError, match="--steps"):
        BenchFinetuneConfig(steps=()).validate()
    with pytest.raises(ConfigError, match="--k"):
        BenchFinetuneConfig(k=0).validate()


@pytest.mark.slow
def test_curve_rows_and_section(tmp_path, capsys):
    import torch

    from lsr.data.synth import generate_dataset
    from lsr.bench.bench_finetune import run_bench_finetune
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    data = tmp_path / "data"
    generate_dataset(data, identities=2, videos_per_identity=1, frames=8, size=64, seed=5, test_fraction=0.5, progress=False)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "warp")
    cfg = BenchFinetuneConfig(weights=weights, data=data, out=tmp_path / "out", k=2, steps=(0, 2), max_holdouts=2,
                              out_md=tmp_path / "BENCH.md", progress=False)
    rows = run_bench_finetune(cfg)
    assert [(row.method, row.steps) for row in rows] == [("tps", None), ("tps_mean3", None), ("lsr:warp", 0), ("lsr:warp", 2)]
    assert rows[3].seconds is not None and rows[3].seconds > 0 and rows[2].seconds is None
    assert all(row.psnr > 5 and 0 < row.ssim <= 1 and row.sharpness > 0 for row in rows)
    section = (tmp_path / "BENCH.md").read_text()
    assert "<!-- eval:finetune_curve:start -->" in section and "lsr bench finetune --weights" in section
    assert "| lsr:warp | 2 |" in capsys.readouterr().out
