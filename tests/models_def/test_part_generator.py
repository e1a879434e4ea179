"""The part generator (models_def.part_generator): shapes, identity at start, save/load, ONNX parity."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from models_def.config import ModelConfigError
from models_def.part_generator import MOUTH_FOLDER, PartGenerator, PartGeneratorConfig, load_mouth_generator


def _inputs(size: int = 40, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(2, 3, size, size, generator=generator) * 2 - 1, torch.rand(2, 2, size, size, generator=generator)


def test_an_untrained_generator_passes_its_window_through_but_the_open_mouth():
    model = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16)))
    window, masks = _inputs()
    masks = torch.zeros_like(masks)
    masks[:, 1, 18:22, 10:30] = 1.0  # an open mouth
    out = model(window, masks)
    grown = torch.zeros(40, 40, dtype=torch.bool)
    grown[16:24, 8:32] = True  # the open mouth grown by the hole's 2 pixels
    assert torch.equal(out[..., ~grown], window[..., ~grown])
    assert torch.equal(out[..., grown], torch.zeros_like(out[..., grown]))  # blanked: mid-grey, to be drawn
    kept = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16), hole=-1))
    assert torch.equal(kept(window, masks), window)


def test_an_interior_generator_changes_only_the_open_mouth():
    model = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16), interior=True))
    torch.nn.init.normal_(model.out.weight, std=0.5)
    window, masks = _inputs()
    masks = torch.zeros_like(masks)
    masks[:, 0, 14:26, 6:34] = 1.0  # the lips, kept
    masks[:, 1, 18:22, 10:30] = 1.0  # the open mouth, drawn (grown by the hole's 2 pixels)
    with torch.no_grad():
        out = model(window, masks)
    grown = torch.zeros(40, 40, dtype=torch.bool)
    grown[16:24, 8:32] = True
    assert torch.equal(out[..., ~grown], window[..., ~grown])
    inner = torch.zeros(40, 40, dtype=torch.bool)
    inner[17:23, 9:31] = True  # a pixel in from the grown edge: fully drawn
    assert float((out[..., inner] - window[..., inner]).abs().mean()) > 0.05
    with pytest.raises(ModelConfigError, match="hole"):
        PartGeneratorConfig(interior=True, hole=-1)


def test_shapes_are_checked_and_outputs_stay_in_range():
    model = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16)))
    torch.nn.init.normal_(model.out.weight, std=1.0)
    window, masks = _inputs()
    out = model(window * 3, masks)
    assert out.shape == window.shape and out.abs().max() <= 1.0
    with pytest.raises(ValueError):
        model(window[:, :, :32, :32], masks)
    with pytest.raises(ModelConfigError):
        PartGeneratorConfig(size=42, widths=(8, 16, 16))


def test_save_and_load_round_trip(tmp_path):
    model = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16)))
    torch.nn.init.normal_(model.out.weight, std=0.1)
    assert load_mouth_generator(tmp_path) is None  # a model folder without a mouth generator
    model.save_pretrained(tmp_path / MOUTH_FOLDER)
    loaded = load_mouth_generator(tmp_path)
    window, masks = _inputs()
    assert loaded.config == model.config
    assert torch.equal(loaded(window, masks), model(window, masks))
    (tmp_path / MOUTH_FOLDER / "model.safetensors").write_bytes(b"broken")
    with pytest.raises(ModelConfigError, match="model.safetensors"):
        load_mouth_generator(tmp_path)


@pytest.mark.parametrize("interior", [False, True])
def test_onnx_export_matches_torch(tmp_path, interior):
    ort = pytest.importorskip("onnxruntime")
    from lsr.export.graphs import export_onnx

    model = PartGenerator(PartGeneratorConfig(size=40, widths=(8, 16, 16), interior=interior)).eval()
    torch.nn.init.normal_(model.out.weight, std=0.1)
    window, masks = _inputs()
    path = export_onnx(model, (window[:1], masks[:1]), tmp_path / "mouth.onnx", ["window", "masks"], ["drawn"], {})
    out = ort.InferenceSession(str(path)).run(["drawn"], {"window": window[:1].numpy(), "masks": masks[:1].numpy()})[0]
    with torch.no_grad():
        expected = model(window[:1], masks[:1]).numpy()
    assert np.abs(out - expected).max() < 1e-5
