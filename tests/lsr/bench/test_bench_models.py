"""``lsr bench models`` runs end to end on the tiny preset and prints one row per variant (no timing limits)."""

from __future__ import annotations

import pytest

from lsr.config import BenchModelsConfig
from lsr.bench.bench_models import run_bench_models


@pytest.mark.slow
def test_bench_models_tiny_table(capsys):
    cfg = BenchModelsConfig(
        presets=("tiny",), variants=("latent_layout", "oracle_seg"), runtimes=("eager", "onnxruntime"), runs=1, warmup=0
    )
    cfg.validate()
    rows = run_bench_models(cfg)
    out = capsys.readouterr().out
    assert "conv peak" in out and "| tiny | latent_layout | 64 |" in out and "| tiny | oracle_seg | 64 |" in out
    assert [row["variant"] for row in rows] == ["latent_layout", "oracle_seg"]
    for row in rows:
        assert row["gflop"] > 0 and isinstance(row["eager"], float) and isinstance(row["onnxruntime"], float)
    # oracle_seg skips G^l, so it must cost fewer FLOPs than latent_layout at the same size.
    assert rows[1]["gflop"] < rows[0]["gflop"]
