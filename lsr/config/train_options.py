"""Typed configs of the training commands: ``lsr train`` (its stages, losses and optimiser) and ``lsr finetune``.

Re-exported by ``lsr.config`` (every sub-command config is ``lsr.config.*``); kept apart so that each file
holds one family of commands.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import tyro

from lsr.config.shared import OptionalInt, OptionalPath, check_weights
from lsr.core import DEFAULT_FINETUNE_LR
from lsr.errors import ConfigError


@dataclasses.dataclass
class StagesConfig:
    """Budgets of the three training stages (thesis §4.3.2-4.3.4, §4.6). One epoch = ``steps_per_epoch`` steps."""

    pretrain_epochs: float = 2.0
    """Stage 1, layout pre-training: X-ent on G^l's layout + lambda_R x aux RGB reconstruction (eq. 4.2)."""
    full_epochs: float = 4.0
    """Stage 2, full pipeline with segmentation supervision still on (eqs. 4.3, 4.4)."""
    latent_epochs: float = 9.0
    """Stage 3, latent layout: X-ent off, G^l learns its own representation (§4.3.4). The thesis trains 8 + 5
    epochs after pre-training without stating where X-ent stops; 4 + 9 is this project's split."""
    steps_per_epoch: int = 0
    """Steps per epoch; 0 = episodes in the dataset // global batch size."""
    lr_decay_steps: int = 0
    """Linear lr decay to 1/100 over this many final steps (thesis: the last epoch); 0 = one epoch."""

    def validate(self) -> None:
        if min(self.pretrain_epochs, self.full_epochs, self.latent_epochs) < 0:
            raise ConfigError("stage epochs must be >= 0")
        if self.steps_per_epoch < 0 or self.lr_decay_steps < 0:
            raise ConfigError("--stages.steps-per-epoch and --stages.lr-decay-steps must be >= 0")


@dataclasses.dataclass
class LossConfig:
    """Loss weights of eqs. 4.2 and 4.4 (lambda_rec terms, lambda_adv, lambda_L2, lambda_R) and R1."""

    l1: float = 1.0
    """L1 reconstruction weight (colour fidelity, §4.3.3)."""
    l2: float = 0.0
    """Mean squared error weight (0 = off). Where the warped references disagree, L1 picks one (sharp, a median);
    L2 pays for hedging between them (a mean), which is what PSNR rewards."""
    ssim: float = 1.0
    """(1 - SSIM)/2 reconstruction weight."""
    feature_matching: float = 1.0
    """L1 between discriminator features of real and fake (perceptual signal without downloaded weights)."""
    vgg: float = 1.0
    """Weight of the VGG perceptual loss; used only when --losses.vgg-weights is given."""
    vgg_weights: OptionalPath = None
    """VGG19 (or VGGFace as VGG16) state dict with torchvision key names (.pth or .safetensors); None = off."""
    mouth: float = 0.0
    """L1 inside an ellipse around the target's mouth (``lsr.train.losses.mouth_mask``), on top of the whole-frame
    terms: the mouth is about 2 % of the frame, yet what another person's driving changes most (0 = off)."""
    adversarial: float = 0.1
    """lambda_adv: non-saturating logistic generator loss."""
    latent_l2: float = 1e-3
    """lambda_L2 on mean(z^l^2) + mean(z^s^2) (eq. 4.4)."""
    cross_entropy: float = 1.0
    """Weight of X-ent between G^l's layout and the (oracle) segmentation while segmentation-supervised."""
    aux_rgb: float = 0.1
    """lambda_R: reconstruction weight of G^l's auxiliary RGB head in stage 1 (eq. 4.2, 'a low value')."""
    r1_gamma: float = 10.0
    """R1 gradient penalty strength gamma (loss = gamma / 2 * E||grad D||^2)."""
    r1_every: int = 16
    """Lazy R1: apply the penalty every N discriminator steps, scaled by N."""

    def validate(self) -> None:
        weights = [self.l1, self.l2, self.ssim, self.mouth, self.feature_matching, self.vgg, self.adversarial, self.latent_l2,
                   self.cross_entropy, self.aux_rgb, self.r1_gamma]
        if min(weights) < 0:
            raise ConfigError("loss weights must be >= 0")
        if self.r1_every < 1:
            raise ConfigError(f"--losses.r1-every must be >= 1, got {self.r1_every}")
        if self.vgg_weights is not None and not Path(self.vgg_weights).is_file():
            raise ConfigError(f"--losses.vgg-weights {self.vgg_weights} is not a file; see docs/TRAINING.md")


@dataclasses.dataclass
class OptimConfig:
    """Adam for every network (thesis §4.6: beta1 = 0, beta2 = 0.999, lr = 0.001)."""

    lr: float = 1e-3
    beta1: float = 0.0
    beta2: float = 0.999
    ema_decay: float = 0.999
    """Per-step decay of the EMA generators used for evaluation and export."""

    def validate(self) -> None:
        if not self.lr > 0 or not (0 <= self.beta1 < 1 and 0 <= self.beta2 < 1):
            raise ConfigError("--optim.lr must be > 0 and betas in [0, 1)")
        if not 0 <= self.ema_decay < 1:
            raise ConfigError(f"--optim.ema-decay must be in [0, 1), got {self.ema_decay}")


@dataclasses.dataclass
class TrainConfig:
    """Train an LSR model in three stages (layout pre-training, full pipeline, latent layout)."""

    data: tuple[Path, ...] = ()
    """Dataset roots (lsr.data format); several mix (e.g. the clips prepared with --framing align and keep)."""
    out: Path = Path("runs/lsr")
    """Run folder: checkpoints/, tensorboard/, weights/ (inference safetensors + config.json)."""
    preset: Literal["paper", "small", "fast", "compact", "tiny"] = "paper"
    """Model size preset (models_def.presets)."""
    variant: Literal["baseline", "spade_landmarks", "learned_seg", "latent_layout", "oracle_seg", "warp_guided"] = "latent_layout"
    """Ablation variant (thesis Table 4.2), or warp_guided (latent layout + the nearest shots warped and blended)."""
    resolution: int = 0
    """Image resolution; 0 = the preset's."""
    warp_references: int = 0
    """warp_guided: how many of the nearest shots, TPS-warped to the target, G^s sees and blends; 0 = the preset's."""
    reference_flow: float = 0.0
    """warp_guided: > 0 lets G^s predict a residual flow per warped shot (at most this fraction of the crop side)."""
    reference_detail: float = 0.0
    """warp_guided: > 0 puts the per-pixel median of the warped shots' detail on the blend's low band, split at a
    Gaussian of this fraction of the crop side (0.0117 = 3 px at 256^2); 0 = the blend as it is."""
    crop_scale: int = 0
    """warp_guided: the crop (blend and output) side over the resolution that the saved model runs at (training
    itself runs at the resolution): 4 makes a 64^2 network output 256^2; 0 = the preset's (2)."""
    synthetic_identities: int = 0
    """Train on this many procedural synthetic identities: alone, or mixed with --data (real clips)."""
    init_from: OptionalPath = None
    """Start from this model folder (same preset) instead of random weights; channels a variant adds start at zero;
    at another --resolution G^s's start grid is resampled and D starts fresh."""
    k: int = 4
    """K: shots per training episode."""
    shots_from: Literal["video", "video_apart", "identity"] = "video"
    """Where an episode's K shots come from: the target's video (as the evaluation protocol), the half of its clip
    away from it (video_apart: no neighbour in time), or any video of the identity (lsr.data.episodes)."""
    expression_episodes: float = 0.0
    """Fraction of episodes whose target opens its mouth wider than any of its closed-mouthed shots, so that the
    network learns to draw the mouth no shot shows (lsr.data.episodes; 0 = off)."""
    batch_size: int = 8
    """Global batch (episodes per step, over all processes; each of N processes gets batch / N)."""
    workers: int = 2
    """DataLoader worker processes per training process."""
    seed: int = 0
    stages: StagesConfig = dataclasses.field(default_factory=StagesConfig)
    losses: LossConfig = dataclasses.field(default_factory=LossConfig)
    optim: OptimConfig = dataclasses.field(default_factory=OptimConfig)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    precision: Literal["fp32", "bf16"] = "fp32"
    """bf16 autocast on GPU (fp32 is the default; bf16 is ignored on CPU)."""
    threads: int = 0
    """CPU threads per process; 0 = os.cpu_count() // number of processes."""
    checkpoint_every: int = 1000
    """Save a full checkpoint every N steps (and at every stage end)."""
    keep_checkpoints: int = 3
    resume: bool = False
    """Continue exactly from the newest checkpoint in OUT/checkpoints."""
    stop_at_step: int = 0
    """Stop after this global step and export the weights (0 = the end of the schedule). The schedule (stages, lr
    decay) stays that of the whole run, so a later --resume continues it as if it had never stopped."""
    log_every: int = 50
    """TensorBoard scalars every N steps."""
    image_every: int = 500
    """TensorBoard image grids every N steps (0 = off)."""
    max_consecutive_nonfinite: int = 5
    """Non-finite steps in a row before restoring the last checkpoint with a halved lr."""
    max_recoveries: int = 2
    """Checkpoint restores allowed before stopping with an error."""
    progress: bool = True
    """tqdm progress bar with ETA (rank 0)."""

    def validate(self) -> None:
        self.stages.validate()
        self.losses.validate()
        self.optim.validate()
        if not self.data and self.synthetic_identities < 1:
            raise ConfigError("give --data DATASET_ROOT or --synthetic-identities N (N >= 1) for a procedural dataset")
        for root in self.data:
            if not Path(root).is_dir():
                raise ConfigError(f"--data {root} is not a folder; prepare a dataset first (see docs/TRAINING.md)")
        if self.crop_scale not in (0, 1, 2, 4, 8):
            raise ConfigError(f"--crop-scale must be 0 (the preset's), 1, 2, 4 or 8, got {self.crop_scale}")
        if self.resolution and (self.resolution < 32 or self.resolution & (self.resolution - 1)):
            raise ConfigError(f"--resolution must be 0 or a power of two >= 32, got {self.resolution}")
        if not 0.0 <= self.expression_episodes <= 1.0:
            raise ConfigError(f"--expression-episodes must be in [0, 1], got {self.expression_episodes}")
        if self.k < 1 or self.batch_size < 1 or self.workers < 0 or self.threads < 0:
            raise ConfigError("--k and --batch-size must be >= 1, --workers and --threads >= 0")
        if (self.reference_flow or self.reference_detail) and self.variant != "warp_guided":
            raise ConfigError("--reference-flow and --reference-detail are for --variant warp_guided")
        if self.warp_references < 0 or (self.warp_references and self.variant != "warp_guided"):
            raise ConfigError(f"--warp-references is for --variant warp_guided and must be >= 0, got {self.warp_references}")
        if self.checkpoint_every < 1 or self.keep_checkpoints < 1 or self.log_every < 1 or self.image_every < 0:
            raise ConfigError("--checkpoint-every, --keep-checkpoints, --log-every must be >= 1; --image-every >= 0")
        if self.max_consecutive_nonfinite < 1 or self.max_recoveries < 0:
            raise ConfigError("--max-consecutive-nonfinite must be >= 1 and --max-recoveries >= 0")
        if self.stop_at_step < 0:
            raise ConfigError(f"--stop-at-step must be >= 0 (0 = the end of the schedule), got {self.stop_at_step}")


@dataclasses.dataclass
class FinetuneConfig:
    """Fine-tune a trained model on K shots of one person (thesis §4.3.5); writes subject weights + latents."""

    shots: tyro.conf.Positional[tuple[Path, ...]]
    """Image files, a folder of images, or one video (K frames with a face are sampled)."""
    weights: OptionalPath = None
    """Model folder (config.json + model.safetensors); default: $LSR_WEIGHTS, else the shipped default model (MODEL_CARD.md)."""
    out: Path = Path("out/subject")
    """Output folder: subject model (safetensors + config.json) and latents.safetensors."""
    k: OptionalInt = None
    """Number of shots to use (sampled evenly from a folder or video); default min(8, shots with a face)."""
    steps: int = 50
    """Fine-tuning steps (small preset at 128^2, batch 4: ~4.5 s/step on one loaded CPU core)."""
    lr: float = DEFAULT_FINETUNE_LR
    """Adam lr for G^l, G^s and D during fine-tuning (a tenth of the training lr: lsr.core.DEFAULT_FINETUNE_LR)."""
    batch_size: int = 4
    """Shots reconstructed per step (<= K)."""
    losses: LossConfig = dataclasses.field(default_factory=LossConfig)
    detector: Literal["mesh", "hog", "cnn"] = "mesh"
    """Face detector for the shots: mesh (MediaPipe, the default) or dlib's hog / cnn."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    seed: int = 0
    progress: bool = True

    def validate(self) -> None:
        from landmarks.io.image_files import check_output_path

        self.losses.validate()
        check_output_path(self.out, "--out", folder=True)  # before the shots are loaded and the model tuned
        check_weights(self.weights)
        if not self.shots:
            raise ConfigError("give at least one image, folder or video of the subject")
        for path in self.shots:
            if not Path(path).exists():
                raise ConfigError(f"shot input not found: {path}")
        if (self.k is not None and self.k < 1) or self.steps < 0 or not self.lr > 0 or self.batch_size < 1:
            raise ConfigError("--k >= 1, --steps >= 0, --lr > 0 and --batch-size >= 1 are required")


@dataclasses.dataclass
class PartPairsConfig:
    """Make a mouth generator's training pairs: the frame model re-enacts held-out frames of each prepared clip onto
    their own landmarks; each pair is the mouth's window of that synthesis and of the real frame (lsr.train.part_training)."""

    data: tyro.conf.Positional[Path]
    """A prepared dataset with every frame of its clips (`lsr prepare CLIPS --frames-per-clip 0`)."""
    out: Path = Path("runs/mouth_pairs")
    """Folder of pairs: <split>/<identity>__<video>__<half>.npz. Finished ones are skipped (a run resumes)."""
    weights: OptionalPath = None
    """The frame model whose synthesis the mouth generator learns to redraw (default: the shipped model)."""
    k: int = 8
    """Shots per clip half."""
    every: int = 2
    """Every n-th frame of the other half is a target."""
    closed_share: float = 0.5
    """Share of clip halves whose shots come only from their least open mouths (targets beyond the shots)."""
    seed: int = 0
    shard: tuple[int, int] = (0, 1)
    """(i, n): only every n-th clip from the i-th, to run n processes side by side."""

    def validate(self) -> None:
        check_weights(self.weights)
        if self.k < 1 or self.every < 1:
            raise ConfigError(f"--k and --every must be >= 1, got {self.k} and {self.every}")
        if not 0.0 <= self.closed_share <= 1.0:
            raise ConfigError(f"--closed-share must be in [0, 1], got {self.closed_share}")
        if not 0 <= self.shard[0] < self.shard[1]:
            raise ConfigError(f"--shard must be (i, n) with 0 <= i < n, got {self.shard}")


@dataclasses.dataclass
class PartTrainConfig:
    """Train a mouth generator on `lsr parts pairs`' pairs (train split), scored on the test split's
    (lsr.train.part_training). The best step's weights go to OUT/best: copy them to a model folder's mouth/ to use them."""

    pairs: tyro.conf.Positional[Path]
    """`lsr parts pairs`' folder (train/ and test/)."""
    out: Path = Path("runs/mouth")
    """Run folder: checkpoint.pt (a run resumes from it), best/, log.jsonl."""
    steps: int = 3000
    batch_size: int = 32
    lr: float = 1e-3
    seed: int = 0
    eval_every: int = 250
    threads: int = 2
    """Torch CPU threads."""
    adversarial: float = 0.0
    """Weight of a patch discriminator's loss (0 = L1 terms only): an open mouth drawn as one plausible mouth."""
    feature_matching: float = 0.0
    """With --adversarial: weight of an L1 between the discriminator's features of drawn and real windows."""
    r1: float = 0.0
    """With --adversarial: R1 gamma on the discriminator (real windows)."""
    critic_lr: float = 0.25
    """With --adversarial: the discriminator's learning rate as a fraction of --lr."""
    critic_width: int = 32
    """With --adversarial: the discriminator's first layer's channels."""
    init_from: OptionalPath = None
    """Start the generator from this part generator folder (e.g. an earlier run's best/)."""
    widths: tuple[int, ...] = ()
    """A new generator's channels per level (default: PartGeneratorConfig's)."""
    hole: OptionalInt = None
    """A new generator's blanking of the open mouth, in pixels grown (-1: none; default: PartGeneratorConfig's)."""
    interior: bool = False
    """A new generator draws only the open mouth (the lips and skin stay the synthesis'), and the discriminator
    judges only the open mouth: the interior as its own target."""
    interior_sigma: float = 0.0
    """> 0: inside the open mouth the L1 terms compare Gaussian low bands of this sigma (window pixels) only, so
    that the cavity's darkness is learnt from them and its detail (teeth) from the discriminator."""
    device: str = "cpu"
    """Where to train: cpu, or cuda on a GPU."""
    minutes: float = 0.0
    """> 0: stop (and decay the learning rate) by this run's wall time too, whichever of it and --steps comes first."""

    def validate(self) -> None:
        if min(self.steps, self.batch_size, self.eval_every, self.threads) < 1:
            raise ConfigError("--steps, --batch-size, --eval-every and --threads must be >= 1")
        if self.lr <= 0:
            raise ConfigError(f"--lr must be > 0, got {self.lr}")
        if self.device not in ("cpu", "cuda") and not self.device.startswith("cuda:"):
            raise ConfigError(f"--device must be cpu or cuda[:N], got {self.device!r}")
        if self.interior and self.hole is not None and self.hole < 0:
            raise ConfigError("--interior draws the open mouth grown by --hole pixels: --hole must be >= 0")
        weights = (self.adversarial, self.feature_matching, self.r1, self.minutes, self.interior_sigma)
        if min(weights) < 0 or self.critic_lr <= 0:
            raise ConfigError("--adversarial, --feature-matching, --r1, --minutes and --interior-sigma must be >= 0, "
                              "--critic-lr > 0")
