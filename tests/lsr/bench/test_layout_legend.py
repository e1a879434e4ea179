"""``lsr bench layout-legend``: a model's layout channels named by the face parts they cover."""

from __future__ import annotations

import json

import pytest

from lsr.cli import main


@pytest.mark.slow
def test_layout_legend_names_every_channel_and_writes_it_beside_the_weights(tmp_path, capsys):
    from lsr.data.synth import generate_dataset
    from lsr.layout_view import LEGEND_FILE, load_layout_legend
    from models_def import LSRModel, preset_config

    data = tmp_path / "data"
    generate_dataset(data, identities=2, videos_per_identity=1, frames=12, size=128, seed=0, test_fraction=0.0,
                     progress=False)
    model = LSRModel(preset_config("tiny", variant="warp_guided"))
    weights = model.save_pretrained(tmp_path / "w")
    assert main(["bench", "layout-legend", str(data), "--weights", str(weights), "--clips", "2", "--every", "2"]) == 0
    printed = capsys.readouterr().out
    assert "| channel | legend name |" in printed and f"legend written to {weights / LEGEND_FILE}" in printed
    names = load_layout_legend(weights)
    assert len(names) == model.config.layout_channels and all(names)
    assert json.loads((weights / LEGEND_FILE).read_text())["from"].startswith("lsr bench layout-legend")
