"""``lsr finetune``: subject fine-tuning on K shots of one person (thesis §4.3.5).

z^l and z^s are computed once from the K shots and kept fixed; G^l, G^s and D are fine-tuned by
reconstructing the shots from their own landmarks with the objective of eq. 4.4 (the same
generator/discriminator steps as ``lsr train``). A warp-guided model reconstructs each shot from the other
shots warped onto it (``landmarks.warp.tps.leave_one_out_references``; with one shot, a jittered copy of it).
Output: the subject's model folder (safetensors + config.json) and ``latents.safetensors`` (layout_latent,
style_latent), ready for the pipeline.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from lsr.core import DEFAULT_FINETUNE_LR
from lsr.core.inputs import SubjectShots, load_subject_shots  # one source loader for reenact, app and finetune
from lsr.errors import DatasetError, WeightsError
from lsr.train.checkpoint import DISCRIMINATOR_NAME, nonfinite_entries
from lsr.train.optim import make_adam
from lsr.train.steps import Batch, LossWeights, StagePlan, discriminator_step, generator_step
from models_def import Discriminator, LSRModel

if TYPE_CHECKING:
    from lsr.config import FinetuneConfig

LATENTS_NAME = "latents.safetensors"
FINETUNE_PLAN = StagePlan(stage=3, cross_entropy=False)  # eq. 4.4 only: the shots have no segmentation


@dataclasses.dataclass
class FinetuneResult:
    model: LSRModel
    layout_latent: Tensor
    """(1, D) fixed z^l."""
    style_latent: Tensor
    """(1, D) fixed z^s."""
    l1_before: float
    l1_after: float
    skipped_steps: int
    seconds: float


# ---- inputs --------------------------------------------------------------------------------------------


def shots_to_tensors(shots: SubjectShots, size: int) -> tuple[Tensor, Tensor]:
    """-> (images (K, 3, S, S) in [-1, 1], landmark images (K, 3, S, S) in [-1, 1]), as in lsr.data.episodes."""
    from lsr.data.episodes import landmark_images

    if shots.frames.ndim != 4 or shots.frames.shape[1:] != (size, size, 3):
        raise DatasetError(f"shots must be (K, {size}, {size}, 3) uint8 crops; got {shots.frames.shape}")
    images = torch.from_numpy(shots.frames).permute(0, 3, 1, 2).float() / 127.5 - 1
    return images, landmark_images(torch.from_numpy(shots.landmarks), size)


# ---- fine-tuning ---------------------------------------------------------------------------------------


def load_discriminator(weights: Path, model: LSRModel) -> tuple[Discriminator, bool]:
    """D saved beside the weights by ``lsr train``, or a fresh one (returns whether it was found)."""
    discriminator = Discriminator(model.config)
    path = Path(weights) / DISCRIMINATOR_NAME
    if not path.is_file():
        return discriminator, False
    from safetensors.torch import load_file

    try:
        discriminator.load_state_dict(load_file(str(path)))
    except (RuntimeError, OSError) as exc:
        raise WeightsError(f"{path} does not match the model config: {exc}; re-export with `lsr train`") from exc
    return discriminator, True


def shot_references(shots: SubjectShots, count: int, seed: int = 0) -> tuple[Tensor, Tensor]:
    """Warp-guided fine-tuning inputs: per shot, the nearest other shots warped onto it.

    -> (references (K, count, 3, S, S) in [-1, 1], reference_masks (K, count, 1, S, S) in {0, 1})."""
    from landmarks.warp.tps import leave_one_out_references

    warped, masks = leave_one_out_references(shots.frames, shots.landmarks, count, seed)
    references = torch.from_numpy(warped).permute(0, 1, 4, 2, 3).float() / 127.5 - 1
    return references, torch.from_numpy(masks)[:, :, None]


@torch.no_grad()
def reconstruction_l1(model: LSRModel, images: Tensor, landmark_images: Tensor, latents: tuple[Tensor, Tensor],
                      oracle: Tensor | None, references: tuple[Tensor, Tensor] | None = None) -> float:
    """Mean L1 of reconstructing every shot from its own landmarks with the fixed latents."""
    count = images.shape[0]
    layout_latent, style_latent = (z.expand(count, -1) for z in latents)
    warped, masks = references if references is not None else (None, None)
    fake = model.frame_generator(landmark_images, layout_latent, style_latent, oracle, warped, masks)
    return (fake - images).abs().mean().item()


def _oracle_one_hot(shots: SubjectShots) -> Tensor:
    from lsr.data.oracle_seg import oracle_segmentation

    maps = np.stack([oracle_segmentation(f, lm) for f, lm in zip(shots.frames, shots.landmarks, strict=True)])
    segmentation = torch.from_numpy(maps.astype(np.int64))
    return torch.nn.functional.one_hot(segmentation, 19).permute(0, 3, 1, 2).float()


def finetune_subject(
    model: LSRModel,
    discriminator: Discriminator,
    shots: SubjectShots,
    *,
    steps: int,
    lr: float = DEFAULT_FINETUNE_LR,
    batch_size: int = 4,
    weights: LossWeights | None = None,
    device: torch.device | str = "cpu",
    seed: int = 0,
    progress: bool = False,
) -> FinetuneResult:
    """Fine-tune G^l, G^s and D on the shots (thesis §4.3.5); the encoder and the latents stay fixed."""
    device = torch.device(device)
    weights = weights or LossWeights()
    size = model.config.resolution
    images, landmark_imgs = (t.to(device) for t in shots_to_tensors(shots, size))
    oracle = _oracle_one_hot(shots).to(device) if model.config.variant == "oracle_seg" else None
    references = None
    if model.config.uses_references:
        references = tuple(t.to(device) for t in shot_references(shots, model.config.warp_references, seed))
    model.to(device).train()
    discriminator.to(device).train()
    with torch.no_grad():  # z^l, z^s = 1/K sum_i E(I_i): computed once, then frozen (§4.3.5)
        layout_latent, style_latent = model.subject_encoder(images[None], landmark_imgs[None])
    model.requires_grad_(False)
    model.frame_generator.requires_grad_(True)
    aux_head = getattr(model.frame_generator.layout_predictor, "to_aux_rgb", None)
    if aux_head is not None:
        aux_head.requires_grad_(False)
    discriminator.requires_grad_(True)
    g_optimizer = make_adam([p for p in model.frame_generator.parameters() if p.requires_grad], lr, (0.0, 0.999))
    d_optimizer = make_adam(discriminator.parameters(), lr, (0.0, 0.999))
    latents = (layout_latent, style_latent)
    l1_before = reconstruction_l1(model, images, landmark_imgs, latents, oracle, references)

    rng = np.random.default_rng(seed)
    count = images.shape[0]
    batch_size = min(batch_size, count)
    skipped = 0
    started = time.perf_counter()
    iterator = range(steps)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="finetune", unit="step", dynamic_ncols=True)
    for step in iterator:
        picks = torch.from_numpy(rng.choice(count, size=batch_size, replace=False)).to(device)
        batch = Batch(
            shots=images[picks, None],  # unused: the latents are fixed
            shot_landmark_images=landmark_imgs[picks, None],
            target=images[picks],
            target_landmark_image=landmark_imgs[picks],
            target_segmentation=None if oracle is None else oracle[picks].argmax(1),
            references=None if references is None else references[0][picks],
            reference_masks=None if references is None else references[1][picks],
        )
        fixed = (layout_latent.expand(batch_size, -1), style_latent.expand(batch_size, -1))
        result = generator_step(model, discriminator, g_optimizer, batch, FINETUNE_PLAN, weights, latents=fixed)
        if not result.finite:
            skipped += 1
            continue
        d_result = discriminator_step(discriminator, d_optimizer, batch.target, result.fake, weights, step)
        skipped += int(not d_result.finite)
    seconds = time.perf_counter() - started
    model.eval()
    model.requires_grad_(False)
    l1_after = reconstruction_l1(model, images, landmark_imgs, latents, oracle, references)
    return FinetuneResult(model, layout_latent.cpu(), style_latent.cpu(), l1_before, l1_after, skipped, seconds)


def finetune_reenactor(reenactor, steps: int, *, lr: float = DEFAULT_FINETUNE_LR, batch_size: int = 4, seed: int = 0,
                       progress: bool = False) -> FinetuneResult:
    """Fine-tune a torch ``lsr.pipeline.Reenactor``'s G^l, G^s on its encoded subject's shots, in place (§4.3.5).

    The latents stay those of ``encode_subject`` (fixed during fine-tuning, as in the thesis); D comes from beside
    the weights (``lsr train`` saves it) or starts fresh. Inference knows nothing of training: fine-tuning is
    composed on top of it here, by ``lsr reenact``, the app and ``lsr eval``. Returns the ``FinetuneResult``."""
    from lsr.core.inputs import resize_shots
    from lsr.errors import ConfigError

    model = getattr(reenactor.backend, "model", None)
    if not isinstance(model, LSRModel):
        raise ConfigError("fine-tuning needs the torch runtime (the ONNX runtime runs the model as trained)")
    subject = reenactor._require_subject()
    if reenactor.weights_path is not None:
        discriminator, _ = load_discriminator(reenactor.weights_path, model)
    else:
        discriminator = Discriminator(model.config)
    result = finetune_subject(
        model, discriminator, resize_shots(subject.shots, reenactor.resolution),  # trained at the model resolution
        steps=steps, lr=lr, batch_size=batch_size, device=reenactor.backend.device, seed=seed, progress=progress,
    )
    reenactor.backend.model = result.model.eval().requires_grad_(False)
    return result


@contextlib.contextmanager
def finetuned(reenactor, steps: int, **options) -> Iterator[FinetuneResult | None]:
    """Fine-tune a copy of the re-enactor's model for the ``with`` block; its base model is back afterwards.

    ``steps`` <= 0 yields None and touches nothing; ``options``: those of ``finetune_reenactor``."""
    if steps <= 0:
        yield None
        return
    base = reenactor.backend.model
    reenactor.backend.model = copy.deepcopy(base)  # the base model (shared, e.g. by the app's sessions) stays untouched
    try:
        yield finetune_reenactor(reenactor, steps, **options)
    finally:
        reenactor.backend.model = base


def save_subject(result: FinetuneResult, out: Path, extra: dict | None = None) -> Path:
    """Write the subject model (safetensors + config.json), latents.safetensors and finetune.json. Never non-finite."""
    from safetensors.torch import save_file

    from landmarks.io.image_files import atomic_output

    out = Path(out)
    bad = nonfinite_entries(result.model.state_dict()) + nonfinite_entries(
        {"layout_latent": result.layout_latent, "style_latent": result.style_latent}
    )
    if bad:
        raise WeightsError(f"fine-tuning produced non-finite values ({', '.join(bad[:5])}); lower --lr and retry")
    result.model.cpu().save_pretrained(out)
    latents = {"layout_latent": result.layout_latent.contiguous(), "style_latent": result.style_latent.contiguous()}
    with atomic_output(out / LATENTS_NAME) as temp:
        save_file(latents, str(temp))
    summary = {"l1_before": result.l1_before, "l1_after": result.l1_after, "skipped_steps": result.skipped_steps,
               "seconds": result.seconds, **(extra or {})}
    with atomic_output(out / "finetune.json") as temp:
        temp.write_text(json.dumps(summary, indent=2) + "\n")
    return out


def run_finetune(cfg: FinetuneConfig) -> FinetuneResult:
    """Entry point of ``lsr finetune``."""
    from lsr.devices import resolve_device
    from lsr.weights import resolve_weights

    device = resolve_device(cfg.device)
    torch.manual_seed(cfg.seed)
    weights = resolve_weights(cfg.weights)
    try:
        model = LSRModel.from_pretrained(weights)
    except ValueError as exc:  # models_def's ModelConfigError says what is wrong with the folder
        raise WeightsError(str(exc)) from exc
    discriminator, found = load_discriminator(weights, model)
    if not found:
        print(f"lsr finetune: no {DISCRIMINATOR_NAME} in {weights}; fine-tuning with a fresh discriminator")
    from landmarks.detect.registry import make_detector

    shots = load_subject_shots(cfg.shots, model.config.resolution, k=cfg.k, detector=make_detector(cfg.detector))
    for note in shots.notes:
        print(f"lsr finetune: {note}")
    result = finetune_subject(
        model, discriminator, shots, steps=cfg.steps, lr=cfg.lr, batch_size=cfg.batch_size,
        weights=cfg.losses, device=device, seed=cfg.seed, progress=cfg.progress,
    )
    save_subject(result, cfg.out, {"shots": len(shots.frames), "steps": cfg.steps, "weights": str(weights)})
    print(
        f"fine-tuned on {len(shots.frames)} shot(s) in {result.seconds:.1f} s ({cfg.steps} steps, "
        f"{result.skipped_steps} skipped): shot L1 {result.l1_before:.4f} -> {result.l1_after:.4f}; wrote {cfg.out}"
    )
    return result
