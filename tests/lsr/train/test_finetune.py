"""Subject fine-tuning (thesis §4.3.5) on a synthetic identity: lowers shot reconstruction error, saves outputs."""

from __future__ import annotations

import pytest
import torch
from safetensors.torch import load_file

from lsr.data.synth.generate import render_video
from lsr.train.finetune import SubjectShots, finetune_subject, load_discriminator, save_subject
from lsr.train.steps import LossWeights
from models_def import Discriminator, LSRModel, preset_config

pytestmark = pytest.mark.slow


def test_finetuning_lowers_reconstruction_error_and_writes_subject_files(tmp_path):
    torch.set_num_threads(1)
    torch.manual_seed(0)
    config = preset_config("tiny")
    clip = render_video(identity_seed=3, num_frames=4, size=config.resolution)
    shots = SubjectShots(clip.frames, clip.landmarks)
    model, discriminator = LSRModel(config), Discriminator(config)
    encoder_before = {k: v.clone() for k, v in model.subject_encoder.state_dict().items()}
    weights = LossWeights(ssim=0.0, adversarial=0.01, feature_matching=0.0, r1_every=4)
    result = finetune_subject(model, discriminator, shots, steps=30, lr=2e-3, batch_size=4, weights=weights)
    assert result.l1_after < 0.7 * result.l1_before, (result.l1_before, result.l1_after)
    assert result.skipped_steps == 0
    for name, tensor in model.subject_encoder.state_dict().items():  # the encoder is not fine-tuned
        assert torch.equal(tensor, encoder_before[name])
    out = save_subject(result, tmp_path / "subject")
    reloaded = LSRModel.from_pretrained(out)
    assert torch.equal(reloaded.state_dict()["frame_generator.image_generator.to_rgb.weight"],
                       model.state_dict()["frame_generator.image_generator.to_rgb.weight"])
    latents = load_file(str(out / "latents.safetensors"))
    assert latents["layout_latent"].shape == (1, config.latent_dim) and latents["style_latent"].shape == (1, config.latent_dim)


def test_missing_discriminator_gives_a_fresh_one(tmp_path):
    model = LSRModel(preset_config("tiny"))
    model.save_pretrained(tmp_path)
    discriminator, found = load_discriminator(tmp_path, model)
    assert not found and isinstance(discriminator, Discriminator)


@pytest.mark.parametrize("shots", [1, 3])
def test_warp_guided_finetuning_learns_from_the_other_shots(shots):
    """Each shot is reconstructed from the other shots warped onto it (one shot: from a jittered copy of itself)."""
    from lsr.train.finetune import shot_references

    torch.set_num_threads(1)
    torch.manual_seed(0)
    config = preset_config("tiny", variant="warp_guided")
    clip = render_video(identity_seed=5, num_frames=shots, size=config.resolution)
    subject = SubjectShots(clip.frames, clip.landmarks)
    references, masks = shot_references(subject, config.warp_references)
    assert references.shape == (shots, config.warp_references, 3, config.resolution, config.resolution)
    assert masks.shape == (shots, config.warp_references, 1, config.resolution, config.resolution)
    if shots == 1:  # the stand-in reference is not the shot itself
        assert (references[0, 0] - (torch.from_numpy(clip.frames[0]).permute(2, 0, 1) / 127.5 - 1)).abs().mean() > 0.01
    model, discriminator = LSRModel(config), Discriminator(config)
    weights = LossWeights(ssim=0.0, adversarial=0.01, feature_matching=0.0, r1_every=4)
    result = finetune_subject(model, discriminator, subject, steps=20, lr=2e-3, batch_size=2, weights=weights)
    assert result.skipped_steps == 0 and result.l1_after < result.l1_before, (result.l1_before, result.l1_after)
