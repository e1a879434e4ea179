"""Training a part generator (``models_def.part_generator``): the mouth drawn from the target's lips (issue 40).

Two steps, both resumable, both under ``lsr parts``:

1. ``build_pairs`` (``lsr parts pairs``): for every clip of a prepared dataset (all frames: ``lsr prepare
   --frames-per-clip 0``), K shots from one half of the clip are encoded and the frame model (the shipped
   default) re-enacts the other half onto its own landmarks and meshes (found anew by the mesh detector, as
   ``lsr eval`` finds them). Each target gives one pair: the mouth's window of the synthesis (what the part
   generator will see at run time) and of the real frame (what it should draw), and the target's landmarks in
   the window. Half of the clips' shots are drawn only from their frames with the mouth least open, so that
   many targets open the mouth wider than every shot: the moments the blend cannot draw. One ``.npz`` per
   clip and half, written atomically; finished ones are skipped.
2. ``train`` (``lsr parts train``): L1 and an L1 of image gradients (edges: teeth, the lip line) over the paste
   weight of the window, three times over the open mouth; flips left-right; Adam. Optionally a patch
   discriminator (``Adversary``), and the open mouth as its own target (``--interior``: drawn alone, judged alone,
   its L1 on low bands only). The validation split's pairs (people the frame model did not train on) are scored
   every ``eval_every`` steps; the best is kept. Checkpoints every ``save_every`` steps let a run resume where it
   stopped.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from landmarks.parts.part_window import (MOUTH, extract, lip_masks, paste_weight, to_window, window_eye_distance,
                                   window_transform)

OPEN_MOUTH_WEIGHT = 3.0
"""The loss weighs the open mouth (inside the inner lips) this much more than the rest of the paste weight."""
GRADIENT_WEIGHT = 1.0
"""Weight of the L1 of horizontal and vertical image differences beside the plain L1."""
CRITIC_LR = 0.25
"""The discriminator learns at this fraction of the generator's rate (at the same rate it won within a few hundred
steps and the generator drew magenta lips to fool it)."""
CRITIC_REACH = 4
"""Pixels the open mouth is grown by for an interior discriminator's view (``Adversary.interior``): the inner lip's
edge is in it."""
COLOUR_JITTER = 0.08
"""Training pairs' colours are jittered by up to this gain and offset (fractions) per channel."""


@dataclasses.dataclass
class PairsSummary:
    written: int = 0
    skipped: int = 0
    pairs: int = 0
    failed: list[str] = dataclasses.field(default_factory=list)


def _choose_shots(openings: np.ndarray, pool: np.ndarray, k: int, closed: bool, rng: np.random.Generator) -> np.ndarray:
    """K shot indices from ``pool`` (indices of valid frames); ``closed``: only from those with the mouth at most
    at the pool's 40th percentile of opening (at least K of them)."""
    if closed:
        order = pool[np.argsort(openings[pool], kind="stable")]
        pool = order[:max(k, int(math.ceil(0.4 * len(order))))]
    return np.sort(rng.choice(pool, size=min(k, len(pool)), replace=False))


def clip_pairs(reenactor, frames: np.ndarray, landmarks: np.ndarray, meshes: np.ndarray | None, shots: np.ndarray,
               targets: np.ndarray) -> dict[str, np.ndarray]:
    """The pairs of one clip half: the subject encoded from ``shots``, each target re-enacted onto its own
    landmarks. frames (N, S, S, 3) uint8, landmarks (N, 68, 2), meshes (N, 468, 3) or None -> arrays
    synthesis / truth (T, P, P, 3) uint8, window_landmarks (T, 68, 2) float32, target_index (T,) int32."""
    from lsr.core.inputs import SubjectShots

    size = MOUTH.size
    shot_meshes = None if meshes is None else meshes[shots]
    reenactor.encode_subject(SubjectShots(frames[shots], landmarks[shots].astype(np.float32),
                                          names=[f"frame {i}" for i in shots], meshes=shot_meshes))
    synthesis, truth, window_points, kept = [], [], [], []
    for index in targets:
        transform = window_transform(landmarks[index])
        if transform is None:
            continue
        mesh = None if meshes is None or not np.isfinite(meshes[index]).all() else meshes[index]
        image, _, _ = reenactor.synthesize_crop(landmarks[index].astype(np.float32), crop_mesh=mesh)
        synthesis.append(extract(image, transform, size))
        truth.append(extract(frames[index], transform, size))
        window_points.append(to_window(landmarks[index], transform).astype(np.float32))
        kept.append(index)
    empty = np.zeros((0, size, size, 3), np.uint8)
    return {"synthesis": np.stack(synthesis) if synthesis else empty, "truth": np.stack(truth) if truth else empty,
            "window_landmarks": np.stack(window_points) if window_points else np.zeros((0, 68, 2), np.float32),
            "target_index": np.array(kept, np.int32), "shots": shots.astype(np.int32)}


def build_pairs(data: Path, out: Path, weights: Path | None = None, k: int = 8, every: int = 2, seed: int = 0,
                closed_share: float = 0.5, splits: tuple[str, ...] = ("train", "test"), limit: int = 0,
                shard: tuple[int, int] = (0, 1)) -> PairsSummary:
    """Step 1 (module docstring): ``out/<split>/<identity>__<video>__<half>.npz`` per clip half. ``shard`` (i, n):
    only every n-th clip from the i-th (to run n processes side by side)."""
    from tqdm import tqdm

    from landmarks.detect.registry import make_detector
    from landmarks.shape.expression import mouth_opening
    from landmarks.io.image_files import atomic_output
    from lsr.data.format import ClipReader, list_clips
    from landmarks.detect.registry import detect_faces
    from lsr.pipeline import Reenactor
    from lsr.weights import resolve_weights

    reenactor = Reenactor(resolve_weights(weights))
    detector = make_detector("mesh")
    summary = PairsSummary()
    clips = [(split, clip) for split in splits for clip in list_clips(data, split)]
    if limit:
        clips = clips[:limit]
    numbered = list(enumerate(clips))[shard[0]::shard[1]]
    for number, (split, clip_dir) in tqdm(numbered, desc="part pairs", unit="clip"):
        reader = ClipReader(clip_dir)
        names = [out / split / f"{reader.identity}__{reader.video}__{half}.npz" for half in (0, 1)]
        if all(name.is_file() for name in names):
            summary.skipped += 1
            continue
        frames = np.stack(list(reader.frames()))
        prepared = reader.landmarks  # the tracker's, to choose shots and targets by
        valid = np.flatnonzero(np.isfinite(prepared).all(axis=(1, 2)))
        if len(valid) < 2 * k + 2:
            summary.failed.append(f"{clip_dir}: {len(valid)} frames with a face")
            continue
        openings = mouth_opening(prepared)
        halves = (valid[valid < len(frames) // 2], valid[valid >= len(frames) // 2])
        rng = np.random.default_rng([seed, number])
        plans = []
        for half, name in enumerate(names):
            pool, targets = halves[half], halves[1 - half]
            if name.is_file() or len(pool) < k or not len(targets):
                continue
            plans.append((name, _choose_shots(openings, pool, k, bool(rng.random() < closed_share), rng), targets[::every]))
        # the landmarks and meshes the pipeline would have: the mesh detector's, on the frames used only
        needed = np.unique(np.concatenate([np.concatenate([shots, targets]) for _, shots, targets in plans] or [[]])).astype(int)
        found, found_meshes = detect_faces(frames[needed], detector)
        landmarks = np.full_like(prepared, np.nan)
        landmarks[needed] = found
        meshes = np.full((len(frames), *found_meshes.shape[1:]), np.nan, np.float32)
        meshes[needed] = found_meshes
        detected = np.isfinite(landmarks).all(axis=(1, 2))
        for name, shots, targets in plans:
            shots, targets = shots[detected[shots]], targets[detected[targets]]
            if not len(shots) or not len(targets):
                continue
            pairs = clip_pairs(reenactor, frames, landmarks, meshes, shots, targets)
            name.parent.mkdir(parents=True, exist_ok=True)
            with atomic_output(name) as temp, open(temp, "wb") as handle:
                    np.savez(handle, **pairs, shot_openings=mouth_opening(landmarks[shots]).astype(np.float32),
                         target_openings=mouth_opening(landmarks[pairs["target_index"]]).astype(np.float32))
            summary.written += 1
            summary.pairs += len(pairs["target_index"])
    return summary


# ---- training ------------------------------------------------------------------------------------------


@dataclasses.dataclass
class PairSet:
    """Every pair of a folder, as torch tensors on one device (batches are drawn there): synthesis / truth
    (N, P, P, 3) uint8, the lip masks (N, 2, P, P) and the loss weight (N, 1, P, P) of each pair's landmarks, and
    whether the target opens its mouth wider than every shot (``beyond``, (N,) bool)."""

    synthesis: "torch.Tensor"
    truth: "torch.Tensor"
    masks: "torch.Tensor"
    weight: "torch.Tensor"
    beyond: "torch.Tensor"

    def __len__(self) -> int:
        return len(self.synthesis)


def load_pairs(folder: Path, device: str = "cpu") -> PairSet:
    import torch

    files = sorted(Path(folder).glob("*.npz"))
    if not files:
        raise FileNotFoundError(f"no part pairs in {folder}; make them with `lsr parts pairs`")
    parts: dict[str, list[np.ndarray]] = {"synthesis": [], "truth": [], "window_landmarks": [], "beyond": []}
    for file in files:
        with np.load(file) as stored:
            for key in ("synthesis", "truth", "window_landmarks"):
                parts[key].append(stored[key])
            parts["beyond"].append(stored["target_openings"] > stored["shot_openings"].max() + 0.02)
    arrays = {key: np.concatenate(values) for key, values in parts.items()}
    size, eyes = arrays["synthesis"].shape[1], window_eye_distance(MOUTH)
    masks = np.stack([lip_masks(p, size) for p in arrays["window_landmarks"]])
    weight = np.stack([paste_weight(p, size, eyes) for p in arrays["window_landmarks"]])[:, None]
    weight = weight * (1.0 + (OPEN_MOUTH_WEIGHT - 1.0) * masks[:, 1:])

    def tensor(values: np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(values)).to(device)

    return PairSet(tensor(arrays["synthesis"]), tensor(arrays["truth"]), tensor(masks), tensor(weight.astype(np.float32)),
                   tensor(arrays["beyond"]))


def batch_tensors(pairs: PairSet, indices, flip=None, generator=None):
    """Tensors for ``indices`` on the pairs' device: window (B, 3, P, P) in [-1, 1], masks (B, 2, P, P), truth
    (B, 3, P, P), loss weight (B, 1, P, P). ``flip`` (B,) bool mirrors those pairs left-right (pictures and
    masks alike: a mouth's masks are symmetric under the mirror of its landmarks); ``generator`` (a
    ``torch.Generator`` on that device) jitters each pair's colour (a gain and an offset per channel,
    ``COLOUR_JITTER``, the same on its synthesis and its truth: people and lighting the clips do not have)."""
    import torch

    device = pairs.synthesis.device
    indices = torch.as_tensor(indices, device=device).long()
    synthesis = pairs.synthesis[indices].permute(0, 3, 1, 2).float()
    truth = pairs.truth[indices].permute(0, 3, 1, 2).float()
    masks, weight = pairs.masks[indices], pairs.weight[indices]
    if flip is not None:
        flip = torch.as_tensor(flip, device=device).bool()
        if bool(flip.any()):
            mirror = flip[:, None, None, None]
            synthesis, truth = torch.where(mirror, synthesis.flip(-1), synthesis), torch.where(mirror, truth.flip(-1), truth)
            masks, weight = torch.where(mirror, masks.flip(-1), masks), torch.where(mirror, weight.flip(-1), weight)
    if generator is not None:
        shape = (len(indices), 3, 1, 1)
        gain = 1.0 + COLOUR_JITTER * (2 * torch.rand(shape, generator=generator, device=device) - 1)
        offset = 255.0 * COLOUR_JITTER * (2 * torch.rand(shape, generator=generator, device=device) - 1)
        synthesis = (synthesis * gain + offset).clamp(0, 255)
        truth = (truth * gain + offset).clamp(0, 255)
    return synthesis / 127.5 - 1.0, masks, truth / 127.5 - 1.0, weight


def part_loss(drawn, truth, weight, masks=None, interior_sigma: float = 0.0):
    """Weighted L1 plus ``GRADIENT_WEIGHT`` x the weighted L1 of horizontal and vertical differences.

    ``interior_sigma`` > 0 (with the lip ``masks``): inside the open mouth only the Gaussian low bands of this
    sigma (window pixels) are compared: how dark the cavity is and where the teeth's brightness lies, not their
    detail, which an L1 averages into a smear (the detail is the discriminator's). The two regions' terms are each
    a weighted mean, summed: the open mouth counts as much as the rest of the window, however small it is."""
    if interior_sigma > 0 and masks is not None:
        from models_def.composite import low_band

        inside = masks[:, -1:]
        return (part_loss(drawn, truth, weight * (1.0 - inside))
                + part_loss(low_band(drawn, interior_sigma), low_band(truth, interior_sigma), weight * inside))
    norm = weight.sum().clamp_min(1e-6) * 3
    loss = ((drawn - truth).abs() * weight).sum() / norm
    for axis in (2, 3):
        d_drawn, d_truth = drawn.diff(dim=axis), truth.diff(dim=axis)
        w = weight.narrow(axis, 0, weight.shape[axis] - 1)
        loss = loss + GRADIENT_WEIGHT * ((d_drawn - d_truth).abs() * w).sum() / norm
    return loss


def _sharpness(images, weight):
    """Per window: the weighted mean absolute Laplacian (B,) of grey images (B, 3, P, P) in [-1, 1]."""
    import torch
    import torch.nn.functional as F

    grey = images.mean(dim=1, keepdim=True)
    kernel = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]], device=images.device)[None, None]
    response = F.conv2d(grey, kernel, padding=1).abs()
    return (response * weight).sum(dim=(1, 2, 3)) / weight.sum(dim=(1, 2, 3)).clamp_min(1e-6)


def evaluate(model, pairs: PairSet, batch: int = 128) -> dict[str, float]:
    """Weighted loss, the PSNR over the paste weight of the drawn window and of the synthesis (all pairs and
    those beyond the shots), and the drawn windows' sharpness over the open mouth as a fraction of the real
    frames' (a hedged, blurred mouth scores well below 1)."""
    import torch

    losses, drawn_se, input_se, weights, sharp = [], [], [], [], []
    with torch.no_grad():
        for start in range(0, len(pairs), batch):
            idx = np.arange(start, min(start + batch, len(pairs)))
            window, masks, truth, weight = batch_tensors(pairs, idx)
            drawn = model(window, masks)
            losses.append(float(part_loss(drawn, truth, weight)) * len(idx))
            w = (weight > 0).float() * weight.clamp(max=1.0)
            drawn_se.append((((drawn - truth) / 2) ** 2 * w).sum(dim=(1, 2, 3)).cpu().numpy())
            input_se.append((((window - truth) / 2) ** 2 * w).sum(dim=(1, 2, 3)).cpu().numpy())
            weights.append(w.sum(dim=(1, 2, 3)).cpu().numpy() * 3)
            mouth = masks[:, 1:]
            sharp.append(torch.stack([_sharpness(drawn, mouth), _sharpness(truth, mouth), mouth.sum(dim=(1, 2, 3))], 1).cpu().numpy())
    drawn_se, input_se, weights = map(np.concatenate, (drawn_se, input_se, weights))
    sharp = np.concatenate(sharp)
    beyond = pairs.beyond.cpu().numpy()

    def psnr(errors: np.ndarray, where: np.ndarray) -> float:
        return float(np.mean(10 * np.log10(1.0 / np.maximum(errors[where] / weights[where], 1e-10)))) if where.any() else float("nan")

    open_mouth = sharp[:, 2] >= 20  # windows whose open mouth covers at least 20 pixels
    sharpness = float(sharp[open_mouth, 0].mean() / max(sharp[open_mouth, 1].mean(), 1e-6)) if open_mouth.any() else float("nan")
    every = np.ones(len(pairs), bool)
    return {"loss": sum(losses) / max(len(pairs), 1), "psnr": psnr(drawn_se, every), "psnr_input": psnr(input_se, every),
            "psnr_beyond": psnr(drawn_se, beyond), "psnr_input_beyond": psnr(input_se, beyond),
            "open_sharpness": sharpness, "beyond": int(beyond.sum()), "pairs": len(pairs)}


def preview(model, pairs: PairSet, count: int = 8) -> np.ndarray:
    """A picture of the first ``count`` pairs beyond the shots (or any, when none is): rows synthesis | drawn |
    real frame, one column per pair -> (3 P, count P, 3) uint8 RGB."""
    import torch

    chosen = np.flatnonzero(pairs.beyond.cpu().numpy())[:count]
    if not len(chosen):
        chosen = np.arange(min(count, len(pairs)))
    window, masks, _, _ = batch_tensors(pairs, chosen)
    with torch.no_grad():
        drawn = model(window, masks)
    drawn = np.clip(np.rint((drawn.cpu().numpy().transpose(0, 2, 3, 1) + 1) * 127.5), 0, 255).astype(np.uint8)
    rows = [pairs.synthesis[chosen].cpu().numpy(), drawn, pairs.truth[chosen].cpu().numpy()]
    return np.concatenate([np.concatenate(list(row), axis=1) for row in rows], axis=0)


@dataclasses.dataclass(frozen=True)
class Adversary:
    """The adversarial terms of a part generator's training (``weight`` 0: none). A patch discriminator
    (``models_def.part_generator.PartDiscriminator``) judges the window with the target's lips; its
    non-saturating loss at ``weight``, an L1 between its features of the drawn and the real window at
    ``feature_matching`` (steadies the generator, as in the frame model), and R1 (``r1``: gamma, on real
    windows) on the discriminator, which learns at ``critic_lr`` x the generator's rate."""

    weight: float = 0.0
    feature_matching: float = 0.0
    r1: float = 0.0
    critic_lr: float = CRITIC_LR
    critic_width: int = 32
    interior: bool = False
    """The discriminator sees only the open mouth grown by ``CRITIC_REACH`` pixels (the rest of the window black):
    the cavity and teeth, not the skin around, which an interior generator keeps from the synthesis."""

    def view(self, window, masks):
        """What the discriminator judges of a window: all of it, or (``interior``) the grown open mouth."""
        import torch.nn.functional as F

        if not self.interior:
            return window
        region = F.max_pool2d(masks[:, -1:], 2 * CRITIC_REACH + 1, stride=1, padding=CRITIC_REACH)
        return window * region


def train(pairs_dir: Path, out: Path, steps: int = 3000, batch: int = 32, lr: float = 1e-3, seed: int = 0,
          eval_every: int = 250, save_every: int = 250, threads: int = 2, adversarial: float | Adversary = 0.0,
          init_from: Path | None = None, device: str = "cpu", minutes: float = 0.0,
          widths: tuple[int, ...] | None = None, hole: int | None = None, interior: bool = False,
          interior_sigma: float = 0.0) -> dict:
    """Step 2 (module docstring). ``out``: ``checkpoint.pt`` (resumable), ``best/`` (the lowest validation
    loss, a ``PartGenerator.save_pretrained`` folder), ``steps/<step>/`` (each evaluated step's), ``log.jsonl`` and
    ``preview.png`` (``preview`` of the validation pairs at the last evaluation; ``steps/<step>.png`` each).

    ``adversarial``: an ``Adversary`` (or its weight alone), so that an open mouth is drawn as one plausible
    mouth (a dark cavity, teeth or not) rather than the average of them that L1 alone settles on.
    ``init_from``: a ``best/`` folder to start the generator from (a new run only); else ``widths``, ``hole`` and
    ``interior`` (it draws the open mouth only) size a new one (``PartGeneratorConfig``). ``interior_sigma``: inside
    the open mouth the L1 terms see only low bands (``part_loss``). ``minutes`` > 0: the run also ends (and its
    learning rate decays) by this run's wall time, whichever of the two comes first; ``device``: where it trains
    ("cuda" on a GPU)."""
    import torch
    import torch.nn.functional as F
    from tqdm import tqdm

    from landmarks.io.image_files import write_image
    from models_def.part_generator import PartDiscriminator, PartGenerator, PartGeneratorConfig

    adversary = adversarial if isinstance(adversarial, Adversary) else Adversary(weight=float(adversarial))
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    train_pairs, val_pairs = load_pairs(pairs_dir / "train", device), load_pairs(pairs_dir / "test", device)
    if init_from is not None:
        model = PartGenerator.from_pretrained(init_from)
    else:
        sizes = {"widths": tuple(widths)} if widths else {}
        sizes.update({} if hole is None else {"hole": hole})
        sizes.update({"interior": True} if interior else {})
        model = PartGenerator(PartGeneratorConfig(size=train_pairs.synthesis.shape[1], **sizes))
    model.to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, betas=(0.9, 0.99))
    critic = None if adversary.weight <= 0 else PartDiscriminator(model.config, adversary.critic_width).to(device)
    critic_optimizer = None if critic is None else torch.optim.Adam(critic.parameters(), lr=lr * adversary.critic_lr,
                                                                    betas=(0.5, 0.99))
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.pt"
    step, best = 0, math.inf
    if checkpoint.is_file():
        state = torch.load(checkpoint, weights_only=True, map_location=device)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        if critic is not None and "critic" in state:
            critic.load_state_dict(state["critic"])
            critic_optimizer.load_state_dict(state["critic_optimizer"])
        step, best = int(state["step"]), float(state["best"])
    generator = torch.Generator(device=device).manual_seed(seed * 1_000_003 + step)
    log = (out / "log.jsonl").open("a")
    bar = tqdm(total=steps, initial=step, desc="part generator", unit="step")
    started = time.perf_counter()
    budget = 60.0 * minutes

    def progress() -> float:
        done = step / steps
        return max(done, (time.perf_counter() - started) / budget) if budget > 0 else done

    while progress() < 1.0:
        model.train()
        idx = torch.randint(0, len(train_pairs), (batch,), generator=generator, device=device)
        flip = torch.rand(batch, generator=generator, device=device) < 0.5
        window, masks, truth, weight = batch_tensors(train_pairs, idx, flip, generator)
        decay = 0.5 * (1 + math.cos(math.pi * min(progress(), 1.0)))  # cosine decay over the run
        for group in optimizer.param_groups:
            group["lr"] = lr * decay
        for group in [] if critic is None else critic_optimizer.param_groups:
            group["lr"] = lr * adversary.critic_lr * decay
        drawn = model(window, masks)
        loss = part_loss(drawn, truth, weight, masks, interior_sigma)
        if critic is not None:
            critic.requires_grad_(False)
            fake_logits, fake_features = critic(adversary.view(drawn, masks), masks, features=True)
            loss = loss + adversary.weight * F.softplus(-fake_logits).mean()
            if adversary.feature_matching > 0:
                _, real_features = critic(adversary.view(truth, masks), masks, features=True)
                loss = loss + adversary.feature_matching * sum(
                    (fake - real.detach()).abs().mean() for fake, real in zip(fake_features, real_features)) / len(fake_features)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if critic is not None:  # the discriminator's step: real frames against the drawn ones
            critic.requires_grad_(True)
            real = adversary.view(truth, masks).detach().requires_grad_(adversary.r1 > 0)
            real_logits = critic(real, masks)
            critic_loss = (F.softplus(-real_logits).mean()
                           + F.softplus(critic(adversary.view(drawn.detach(), masks), masks)).mean())
            if adversary.r1 > 0:
                (grad,) = torch.autograd.grad(real_logits.sum(), real, create_graph=True)
                critic_loss = critic_loss + 0.5 * adversary.r1 * grad.pow(2).sum(dim=(1, 2, 3)).mean()
            critic_optimizer.zero_grad(set_to_none=True)
            critic_loss.backward()
            critic_optimizer.step()
        step += 1
        bar.update(1)
        finished = progress() >= 1.0
        if step % 50 == 0:
            bar.set_postfix(loss=f"{loss.item():.4f}")
        if step % eval_every == 0 or finished:
            model.eval()
            scores = evaluate(model, val_pairs)
            scores.update(step=step, train_loss=loss.item(), seconds=time.perf_counter() - started)
            log.write(json.dumps(scores) + "\n")
            log.flush()
            bar.write(f"step {step}: val loss {scores['loss']:.4f}, mouth PSNR {scores['psnr']:.2f} dB "
                      f"(synthesis {scores['psnr_input']:.2f}), beyond the shots {scores['psnr_beyond']:.2f} "
                      f"({scores['psnr_input_beyond']:.2f}, {scores['beyond']} pairs), open-mouth sharpness "
                      f"{scores['open_sharpness']:.2f}")
            if scores["loss"] < best:
                best = scores["loss"]
                model.save_pretrained(out / "best")
            picture = preview(model, val_pairs)
            write_image(out / "preview.png", picture)
            model.save_pretrained(out / "steps" / f"{step:06d}")  # to choose by eye where L1 and looks disagree
            write_image(out / "steps" / f"{step:06d}.png", picture)
        if step % save_every == 0 or finished:
            temp = checkpoint.with_suffix(".tmp")
            state = {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "step": step, "best": best}
            if critic is not None:
                state.update(critic=critic.state_dict(), critic_optimizer=critic_optimizer.state_dict())
            torch.save(state, temp)
            temp.replace(checkpoint)
    bar.close()
    log.close()
    return {"step": step, "best_val_loss": best}


def run_pairs(cfg) -> None:
    """Entry point of ``lsr parts pairs`` (``lsr.config.PartPairsConfig``)."""
    summary = build_pairs(cfg.data, cfg.out, weights=cfg.weights, k=cfg.k, every=cfg.every, seed=cfg.seed,
                          closed_share=cfg.closed_share, shard=tuple(cfg.shard))
    print(f"part pairs: {summary.written} clip halves written ({summary.pairs} pairs), {summary.skipped} clips "
          f"already done, {len(summary.failed)} failed" + "".join(f"\n  {why}" for why in summary.failed))


def run_train(cfg) -> None:
    """Entry point of ``lsr parts train`` (``lsr.config.PartTrainConfig``)."""
    adversary = Adversary(weight=cfg.adversarial, feature_matching=cfg.feature_matching, r1=cfg.r1,
                          critic_lr=cfg.critic_lr, critic_width=cfg.critic_width, interior=cfg.interior)
    result = train(cfg.pairs, cfg.out, steps=cfg.steps, batch=cfg.batch_size, lr=cfg.lr, seed=cfg.seed,
                   eval_every=cfg.eval_every, save_every=cfg.eval_every, threads=cfg.threads,
                   adversarial=adversary, init_from=cfg.init_from, device=cfg.device, minutes=cfg.minutes,
                   widths=tuple(cfg.widths) if cfg.widths else None, hole=cfg.hole, interior=cfg.interior,
                   interior_sigma=cfg.interior_sigma)
    print(f"trained to step {result['step']}; best validation loss {result['best_val_loss']:.4f}: {cfg.out / 'best'}")
