"""LSR networks: shapes per variant, parameter counts per preset, K-shot averaging, determinism, dtypes,
config validation and safetensors round-trip. Everything runs on the ``tiny`` preset (64^2)."""

from __future__ import annotations

import json

import pytest
import torch

from models_def import (
    PRESET_NAMES,
    VARIANTS,
    Discriminator,
    LSRModel,
    ModelConfig,
    ModelConfigError,
    encode_k_shots,
    minibatch_stddev_group,
    preset_config,
)
from models_def.blocks import DownResBlock

# (subject encoder, frame generator, discriminator) parameters. The encoder and discriminator counts are
# re-derived from a formula below; frame-generator counts are recorded values.
PARAMETER_COUNTS = {
    ("paper", "baseline"): (8034432, 11804963, 19048993),
    ("paper", "spade_landmarks"): (8034432, 39822051, 19048993),
    ("paper", "learned_seg"): (8034432, 51709113, 19048993),
    ("paper", "latent_layout"): (8034432, 51709113, 19048993),
    ("paper", "oracle_seg"): (8034432, 39898659, 19048993),
    ("small", "latent_layout"): (2141504, 18036841, 4764689),
    ("fast", "latent_layout"): (2141504, 7051993, 4764689),
    ("tiny", "baseline"): (5912, 16487, 5885),
    ("tiny", "spade_landmarks"): (5912, 26639, 5885),
    ("tiny", "learned_seg"): (5912, 53405, 5885),
    ("tiny", "latent_layout"): (5912, 53405, 5885),
    ("tiny", "oracle_seg"): (5912, 36215, 5885),
}


def _count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def _conv(cin: int, cout: int, k: int, bias: bool = True) -> int:
    return cout * cin * k * k + (cout if bias else 0)


def _down_block(cin: int, cout: int) -> int:
    return _conv(cin, cin, 3) + _conv(cin, cout, 3) + _conv(cin, cout, 1, bias=False)


def _inputs(config: ModelConfig, batch: int = 2, shots: int = 3, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    size, lm = config.resolution, config.landmark_channels
    inputs = {
        "shots": torch.rand(batch, shots, 3, size, size, generator=g) * 2 - 1,
        "shot_landmark_images": torch.rand(batch, shots, lm, size, size, generator=g) * 2 - 1,
        "landmark_image": torch.rand(batch, lm, size, size, generator=g) * 2 - 1,
    }
    if config.variant == "oracle_seg":
        labels = torch.randint(0, 19, (batch, size, size), generator=g)
        inputs["oracle_segmentation"] = torch.nn.functional.one_hot(labels, 19).permute(0, 3, 1, 2).float()
    if config.uses_references:
        count = config.warp_references
        inputs["references"] = torch.rand(batch, count, 3, size, size, generator=g) * 2 - 1
        inputs["reference_masks"] = torch.ones(batch, count, 1, size, size)
    return inputs


def _tiny(variant: str = "latent_layout", **overrides) -> LSRModel:
    torch.manual_seed(0)
    return LSRModel(preset_config("tiny", variant=variant, **overrides)).eval()


class TestShapesAndCounts:
    @pytest.mark.parametrize("variant", VARIANTS)
    def test_forward_shapes(self, variant):
        model = _tiny(variant)
        config = model.config
        with torch.no_grad():
            out = model(**_inputs(config), with_aux_rgb=config.uses_layout_predictor)
        assert out.frame.image.shape == (2, 3, 64, 64)
        assert out.frame.image.abs().max() <= 1
        assert out.layout_latent.shape == out.style_latent.shape == (2, config.latent_dim)
        if config.uses_layout_predictor:
            assert out.frame.layout.shape == out.frame.layout_logits.shape == (2, config.layout_channels, 64, 64)
            torch.testing.assert_close(out.frame.layout.sum(1), torch.ones(2, 64, 64))  # softmax
            assert out.frame.aux_rgb.shape == (2, 3, 64, 64)
        else:
            assert out.frame.layout_logits is None and out.frame.aux_rgb is None
        discriminator = Discriminator(config)
        assert discriminator(out.frame.image).shape == (2,)

    def test_aux_head_only_on_request(self):
        model = _tiny()
        with torch.no_grad():
            assert model(**_inputs(model.config)).frame.aux_rgb is None

    @pytest.mark.parametrize(("preset", "variant"), sorted(PARAMETER_COUNTS))
    def test_parameter_counts(self, preset, variant):
        config = preset_config(preset, variant=variant)
        model, discriminator = LSRModel(config), Discriminator(config)
        encoder, frame, disc = PARAMETER_COUNTS[(preset, variant)]
        assert (_count(model.subject_encoder), _count(model.frame_generator), _count(discriminator)) == (
            encoder,
            frame,
            disc,
        )

    def test_paper_encoder_and_discriminator_match_the_formula(self):
        # §4.6: 5 blur-pool residual blocks, 32 maps doubling to 512, one FC per head to a 512-d latent.
        widths = [32, 64, 128, 256, 512, 512]
        encoder = _conv(6, 32, 3) + sum(_down_block(a, b) for a, b in zip(widths, widths[1:]))
        encoder += 2 * (512 * 512 + 512)
        assert PARAMETER_COUNTS[("paper", "latent_layout")][0] == encoder
        # StyleGAN2 D with smallest width 32: 256 -> 4 in 6 blocks.
        widths = [32, 64, 128, 256, 512, 512, 512]
        disc = _conv(3, 32, 1) + sum(_down_block(a, b) for a, b in zip(widths, widths[1:]))
        disc += _conv(513, 512, 3) + (512 * 16 * 512 + 512) + (512 + 1)
        assert PARAMETER_COUNTS[("paper", "latent_layout")][2] == disc
        assert _count(DownResBlock(32, 64)) == _down_block(32, 64)

    def test_tiny_is_tiny_and_paper_widths(self):
        for variant in VARIANTS:
            model = LSRModel(preset_config("tiny", variant=variant))
            assert _count(model) < 100_000
        generator = LSRModel(preset_config("paper")).frame_generator.image_generator
        assert generator.to_rgb.in_channels == 32  # thesis: 32 maps at the last generator layer
        assert generator.head.projection.conv.out_channels == 64  # 64 maps in each SPADE block
        assert generator.head.projection.conv.in_channels == 19 + 3  # layout + landmark image

    def test_shape_errors_are_clear(self):
        model = _tiny()
        inputs = _inputs(model.config)
        with pytest.raises(ValueError, match="shots must have shape"):
            model(**{**inputs, "shots": inputs["shots"][:, :, :2]})
        with pytest.raises(ValueError, match="oracle_segmentation"):
            model(**inputs, oracle_segmentation=torch.zeros(2, 19, 64, 64))
        with pytest.raises(ValueError, match="landmark_image"):
            model.frame_generator(torch.zeros(2, 3, 32, 32), torch.zeros(2, 16), torch.zeros(2, 16))


class TestKShotAveraging:
    def test_identical_shots_give_one_shot_latents(self):
        model = _tiny()
        inputs = _inputs(model.config, batch=2, shots=1)
        repeated = {k: inputs[k].repeat(1, 5, 1, 1, 1) for k in ("shots", "shot_landmark_images")}
        with torch.no_grad():
            one = model.subject_encoder(inputs["shots"], inputs["shot_landmark_images"])
            five = model.subject_encoder(repeated["shots"], repeated["shot_landmark_images"])
        for a, b in zip(one, five):
            assert (a - b).abs().max() <= 1e-6

    def test_average_of_separately_encoded_shots(self):
        encoder = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(12, 4))
        shots = torch.randn(2, 3, 3, 2, 2)
        expected = torch.stack([encoder(shots[:, k]) for k in range(3)], dim=1).mean(1)
        torch.testing.assert_close(encode_k_shots(encoder, shots), expected)
        with pytest.raises(ValueError, match=r"\(B, K, C, H, W\)"):
            encode_k_shots(encoder, shots[0])


class TestDeterminismAndPrecision:
    def test_same_seed_same_weights_and_outputs(self):
        a, b = _tiny(), _tiny()
        inputs = _inputs(a.config, batch=1, shots=2)
        with torch.no_grad():
            torch.testing.assert_close(a(**inputs).frame.image, b(**inputs).frame.image, rtol=0, atol=0)
        torch.manual_seed(1)
        c = LSRModel(a.config)
        assert any(not torch.equal(p, q) for p, q in zip(a.parameters(), c.parameters()))

    @pytest.mark.parametrize("case", ["constant", "black_landmarks", "extreme"])
    @pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
    def test_finite_in_half_precisions(self, case, dtype):
        model = _tiny()
        inputs = _inputs(model.config, batch=2, shots=1)
        if case == "constant":  # InstanceNorm sees zero variance everywhere
            inputs = {k: torch.full_like(v, 0.5) for k, v in inputs.items()}
        elif case == "black_landmarks":
            inputs["landmark_image"] = torch.full_like(inputs["landmark_image"], -1.0)
            inputs["shot_landmark_images"] = torch.full_like(inputs["shot_landmark_images"], -1.0)
        else:
            inputs = {k: torch.sign(v) * 1e4 for k, v in inputs.items()}
        # float16 and bfloat16 convolutions both run on this CPU, so the whole model is cast (.to(dtype)),
        # which is stricter than autocast (autocast keeps some ops in float32).
        model = model.to(dtype)
        with torch.no_grad():
            out = model(**{k: v.to(dtype) for k, v in inputs.items()})
        for tensor in (out.frame.image, out.frame.layout, out.layout_latent, out.style_latent):
            assert tensor.dtype == dtype and torch.isfinite(tensor).all()
        disc = Discriminator(model.config).to(dtype)
        with torch.no_grad():
            assert torch.isfinite(disc(out.frame.image)).all()


class TestConfigAndSerialization:
    def test_invalid_configs_raise_typed_errors(self):
        with pytest.raises(ModelConfigError, match="variant must be one of"):
            ModelConfig(variant="unet")
        with pytest.raises(ModelConfigError, match="power of two"):
            ModelConfig(resolution=200)
        with pytest.raises(ModelConfigError, match="layout_channels=19"):
            ModelConfig(variant="learned_seg", layout_channels=8)
        with pytest.raises(ModelConfigError, match="too small"):
            ModelConfig(resolution=16)
        with pytest.raises(ModelConfigError, match="width"):
            ModelConfig(width=0)
        with pytest.raises(ModelConfigError, match="unknown model preset"):
            preset_config("huge")
        assert set(PRESET_NAMES) >= {"paper", "small", "fast", "tiny"}
        assert issubclass(ModelConfigError, ValueError)

    @pytest.mark.parametrize("variant", ["latent_layout", "oracle_seg"])
    def test_round_trip_identical_outputs(self, tmp_path, variant):
        model = _tiny(variant)
        model.save_pretrained(tmp_path / "model")
        assert sorted(p.name for p in (tmp_path / "model").iterdir()) == ["config.json", "model.safetensors"]
        loaded = LSRModel.from_pretrained(tmp_path / "model").eval()
        assert loaded.config == model.config
        inputs = _inputs(model.config)
        with torch.no_grad():
            torch.testing.assert_close(loaded(**inputs).frame.image, model(**inputs).frame.image, rtol=0, atol=0)
        disc = Discriminator(model.config)
        disc.save_pretrained(tmp_path / "disc")
        image = inputs["landmark_image"]
        torch.testing.assert_close(Discriminator.from_pretrained(tmp_path / "disc")(image), disc(image))

    def test_from_pretrained_errors(self, tmp_path):
        with pytest.raises(ModelConfigError, match="config.json"):
            LSRModel.from_pretrained(tmp_path)
        folder = _tiny().save_pretrained(tmp_path / "model")
        config = json.loads((folder / "config.json").read_text())
        (folder / "config.json").write_text(json.dumps({**config, "extra": 1}))
        with pytest.raises(ModelConfigError, match="unknown \\['extra'\\]"):
            LSRModel.from_pretrained(folder)
        (folder / "config.json").write_text(json.dumps({**config, "layout_channels": 8}))
        with pytest.raises(ModelConfigError, match="does not match"):
            LSRModel.from_pretrained(folder)
        (folder / "config.json").write_text(json.dumps(config))
        with pytest.raises(ModelConfigError, match="holds a LSRModel"):
            Discriminator.from_pretrained(folder)
        (folder / "model.safetensors").unlink()
        with pytest.raises(ModelConfigError, match="model.safetensors not found"):
            LSRModel.from_pretrained(folder)


class TestMinibatchStddev:
    def test_group_divides_batch(self):
        assert [minibatch_stddev_group(4, b) for b in (1, 2, 3, 4, 6, 8)] == [1, 2, 3, 4, 3, 4]
        with pytest.raises(ValueError):
            minibatch_stddev_group(4, 0)

    def test_discriminator_small_batches(self):
        torch.manual_seed(0)
        disc = Discriminator(preset_config("tiny"))
        for batch in (1, 3, 5):
            assert disc(torch.randn(batch, 3, 64, 64)).shape == (batch,)
        conditioned = Discriminator(preset_config("tiny", discriminator_conditioned=True))
        with pytest.raises(ValueError, match="landmark_image"):
            conditioned(torch.randn(2, 3, 64, 64))
        assert conditioned(torch.randn(2, 3, 64, 64), torch.randn(2, 3, 64, 64)).shape == (2,)


def test_saved_files_get_the_mode_of_a_plain_open(tmp_path):
    """Atomic writes go through mkstemp (0600); the files must still be readable by others, as open() makes them."""
    import os
    import stat

    previous = os.umask(0o022)
    try:
        folder = LSRModel(preset_config("tiny")).save_pretrained(tmp_path / "model")
    finally:
        os.umask(previous)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in folder.iterdir()}
    assert modes == {"config.json": 0o644, "model.safetensors": 0o644}
