"""Configs of the ``lsr bench`` sub-commands (re-exported by ``lsr.config``; ``lsr eval``'s is ``lsr.config.eval_options``).

Each benchmark is a command that prints a markdown table with machine info; never a timed test.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import tyro

from lsr.core import DEFAULT_FINETUNE_LR
from lsr.config.shared import (  # noqa: F401 - re-exported for the commands that read them from here
    OptionalFloat, OptionalInt, OptionalPath, OptionalStr, SplitOptions, check_metric_weights, check_weights,
    evaluation_data, shared_data_dir)
from lsr.errors import ConfigError

@dataclasses.dataclass
class BenchLandmarksConfig:
    """Print speed, detection rate, NME and jitter of both face trackers (mesh and dlib's), as tables with machine
    info."""

    video: OptionalPath = None
    """Video to time on; default: the shared real clip (../shared/data/clips/tpsmm_driving.mp4), else the first
    of --clips."""
    size: int = 512
    """Timing frames are resized to size x size (the tracking goal is stated at 512)."""
    frames: int = 100
    """Number of frames to time."""
    raster_size: int = 256
    """Resolution of the rasterised landmark image."""
    clips: tuple[Path, ...] = ()
    """Real clips for detection rate, NME and jitter (at their own size); empty = every .mp4 under
    ../shared/data/clips that exists."""
    clip_frames: int = 150
    """At most this many frames of each clip."""
    out_md: OptionalPath = None
    """Also write the tables as the 'landmarks' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = False
    """Progress bars over the clips."""

    def validate(self) -> None:
        if self.size < 64 or self.frames < 1 or self.raster_size < 16 or self.clip_frames < 2:
            raise ConfigError("--size >= 64, --frames >= 1, --raster-size >= 16 and --clip-frames >= 2 are required")
        if self.video is not None and not Path(self.video).is_file():
            raise ConfigError(f"--video {self.video} is not a file; pass a talking-head video")
        absent = [str(clip) for clip in self.clips if not Path(clip).is_file()]
        if absent:
            raise ConfigError(f"--clips: {', '.join(absent)} not found; pass existing video files")


@dataclasses.dataclass
class BenchTrainConfig:
    """Print training steps/s for presets at a resolution on this machine (a markdown table)."""

    presets: tuple[str, ...] = ("small", "paper")
    resolution: int = 128
    batch_size: int = 2
    k: int = 2
    """K: shots per episode."""
    steps: int = 5
    """Timed steps per preset and stage (after one warm-up step)."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    threads: int = 0
    """CPU threads (0 = torch's default). On a shared/loaded machine 1 is often fastest."""

    def validate(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.k < 1 or self.resolution < 32:
            raise ConfigError("--steps, --batch-size, --k >= 1 and --resolution >= 32 are required")


@dataclasses.dataclass
class BenchModelsConfig:
    """Print params, GFLOP and ms/frame of the per-frame path (G^l + G^s) per preset, variant and runtime."""

    presets: tuple[str, ...] = ("fast", "small")
    """Model presets (models_def.presets), or 'all' (paper at 256^2 is slow on 2 cores)."""
    variants: tuple[str, ...] = ("latent_layout",)
    """Ablation variants (baseline, spade_landmarks, learned_seg, latent_layout, oracle_seg), or 'all'."""
    runtimes: tuple[Literal["eager", "channels_last", "compile", "onnxruntime"], ...] = (
        "eager",
        "channels_last",
        "onnxruntime",
    )
    """Runtimes to time; 'compile' (torch.compile, channels-last) takes minutes to compile on 2 cores."""
    runs: int = 10
    """Timed runs per runtime (median reported), after ``warmup`` untimed runs."""
    warmup: int = 2
    resolution: int = 0
    """Override every preset's resolution (0 = the preset's own, 256 except tiny)."""
    threads: int = 0
    """CPU threads for torch and onnxruntime (0 = default)."""

    def validate(self) -> None:
        from models_def import PRESET_NAMES, VARIANTS

        for name in self.presets:
            if name != "all" and name not in PRESET_NAMES:
                raise ConfigError(f"unknown preset {name!r}; choose from {', '.join(PRESET_NAMES)} or all")
        for name in self.variants:
            if name != "all" and name not in VARIANTS:
                raise ConfigError(f"unknown variant {name!r}; choose from {', '.join(VARIANTS)} or all")
        if self.runs < 1 or self.warmup < 0 or self.threads < 0:
            raise ConfigError("--runs >= 1, --warmup >= 0 and --threads >= 0 are required")
        if self.resolution and (self.resolution < 64 or self.resolution & (self.resolution - 1)):
            raise ConfigError(f"--resolution must be 0 or a power of two >= 64; got {self.resolution}")


@dataclasses.dataclass
class BenchSpeedConfig:
    """Speed beside error: params, GFLOP, ms/frame and subject-encoding ms per preset x resolution x runtime, with
    PSNR / SSIM / NMKE of each preset's trained weights (thesis protocol), written into a BENCHMARKS.md section."""

    presets: tuple[str, ...] = ("tiny", "fast")
    """Model presets (models_def.presets)."""
    resolutions: tuple[int, ...] = (128, 256)
    runtimes: tuple[Literal["eager", "channels_last", "compile", "onnxruntime", "int8"], ...] = (
        "eager",
        "channels_last",
        "onnxruntime",
        "int8",
    )
    """'compile' (torch.compile) is opt-in: it takes minutes to compile on 2 cores. 'int8': the frame generator with its network's convolutions int8 (``lsr.export.bundle.quantize_frame_generator``)."""
    weights: tuple[str, ...] = ()
    """Trained weights per preset as PRESET=DIR (from `lsr train`); presets without weights get no error columns."""
    k: tuple[int, ...] = (1, 8)
    """K (shots) of the error columns."""
    runs: int = 10
    """Timed runs per measurement (median), after ``warmup`` untimed runs."""
    warmup: int = 2
    encoder_runs: int = 3
    """Timed runs of subject encoding at K=32 (slow at 256^2)."""
    out_md: Path = Path("BENCHMARKS.md")
    """Markdown file whose `bench:speed` section is replaced (created when missing); bench_speed.json goes beside the plot."""
    plot: OptionalPath = None
    """PNG of ms/frame against the error with the Pareto front; default OUT_MD's folder/docs/bench_speed.png."""
    pareto_metric: Literal["psnr", "ssim", "nmke"] = "psnr"
    synthetic_root: OptionalPath = None
    """An existing `lsr synth` dataset whose 'test' split is scored; default a small fixed-seed one in --cache-dir."""
    cache_dir: OptionalPath = None
    """Where the default synthetic split and FSTH landmarks are cached (default ~/.cache/lsr/bench_speed)."""
    fsth: bool = False
    """Also score on the FSTH sample (../shared/data/fsth_eval_sample or --fsth-root)."""
    fsth_root: OptionalPath = None
    inputs: int = 32
    """Input frames per identity of the synthetic split (shots are drawn from them)."""
    holdouts: int = 32
    max_holdouts: int = 0
    """Score only the first N hold-out frames per identity (0 = all)."""
    note: str = ""
    """Free text shown in the section header (e.g. how the weights were trained)."""
    threads: int = 0
    """CPU threads for torch and onnxruntime (0 = default)."""
    progress: bool = True

    def validate(self) -> None:
        from models_def import PRESET_NAMES

        for name in self.presets:
            if name not in PRESET_NAMES:
                raise ConfigError(f"unknown preset {name!r}; choose from {', '.join(PRESET_NAMES)}")
        for resolution in self.resolutions:
            if resolution < 32 or resolution & (resolution - 1):
                raise ConfigError(f"--resolutions must be powers of two >= 32; got {resolution}")
        if not self.presets or not self.resolutions or not self.runtimes or not self.k:
            raise ConfigError("--presets, --resolutions, --runtimes and --k need at least one value each")
        if min(self.k) < 1 or self.runs < 1 or self.warmup < 0 or self.encoder_runs < 1 or self.threads < 0:
            raise ConfigError("--k >= 1, --runs >= 1, --encoder-runs >= 1, --warmup >= 0 and --threads >= 0 are required")
        if self.inputs < 1 or self.holdouts < 1 or self.max_holdouts < 0:
            raise ConfigError("--inputs and --holdouts must be >= 1, --max-holdouts >= 0")


# ---- evaluation (lsr.eval) ------------------------------------------------------------------------------


@dataclasses.dataclass
class BenchReenactConfig:
    """Print end-to-end and per-stage fps of `lsr reenact` for each runtime (a table with machine info)."""

    video: OptionalPath = None
    """Driving (and source) clip; default the shared ../shared/data/clips/tpsmm_driving.mp4."""
    weights: OptionalPath = None
    """Model folder; default: the shipped default model ($LSR_WEIGHTS if set)."""
    preset: OptionalStr = None
    """Time a randomly initialised model of this preset instead (speed does not depend on the weights)."""
    resolution: int = 256
    """The --preset model's resolution."""
    frames: int = 50
    """Driving frames timed (the clip is cut to its first N frames)."""
    runtimes: tuple[Literal["torch", "onnx"], ...] = ("torch", "onnx")
    detectors: tuple[Literal["mesh", "hog", "cnn"], ...] = ("mesh",)
    """Face detectors (the driver's tracking and the source's shots); one row per runtime and detector."""
    mouths: tuple[Literal["drawn", "nearest", "blend"], ...] = ()
    """A warp-guided model's mouth (as `lsr eval --mouths`), one row each; e.g. drawn nearest times the mouth
    generator against the per-frame path without it, in the same run. Empty: the model's default."""
    eyes: tuple[Literal["drawn", "warped", "blend"], ...] = ()
    """The eyes (as `lsr eval --eyes`), one row each; with blend among them, drawn or warped prints its frame-rate
    ratio to blend. Empty: the default (warped)."""
    mouth_interiors: tuple[Literal["driver", "shots"], ...] = ()
    """Inside an open mouth (as `lsr eval --mouth-interiors`), one row each; driver shots prints the driver
    interior's frame-rate ratio. Empty: the default (driver)."""
    lids: tuple[Literal["drawn", "driver", "shots"], ...] = ()
    """Where the target shuts its eyes (as `lsr eval --lids`), one row each; with shots among them each other
    choice's frame-rate ratio is printed (the driver's shut lids are cut and read on every frame, laid in where they
    shut; the drawn ones read from the target). Empty: the default (drawn)."""
    paste_back: bool = True
    k: int = 4
    device: Literal["auto", "cpu", "cuda"] = "auto"
    threads: int = 0
    """CPU threads for the networks (as `lsr reenact --threads`); 0 = all cores but one, as lsr reenact."""
    out_md: OptionalPath = None
    """Also write the table as the 'reenact' section of this markdown file (e.g. BENCHMARKS.md)."""

    def validate(self) -> None:
        if self.frames < 2 or self.k < 1 or self.resolution < 32:
            raise ConfigError("--frames >= 2, --k >= 1 and --resolution >= 32 are required")


@dataclasses.dataclass
class BenchFinetuneConfig:
    """Print subject fine-tuning's steps-vs-error curve beside the TPS baselines (lsr.bench.bench_finetune)."""

    weights: OptionalPath = None
    """Model folder; default: $LSR_WEIGHTS, else the shipped default model."""
    data: OptionalPath = None
    """As `lsr eval --data`; default: the shared FSTH sample."""
    out: Path = Path("out/bench_finetune")
    """Folder for the landmark cache of the evaluation frames."""
    k: int = 8
    """Shots per identity (drawn as `lsr eval` draws them)."""
    steps: tuple[int, ...] = (0, 10, 25, 50, 100)
    """Fine-tuning budgets (0 = the model as trained)."""
    finetune_lr: float = DEFAULT_FINETUNE_LR
    max_identities: int = 0
    max_holdouts: int = 0
    seed: int = 0
    threads: int = 1
    """CPU threads for torch (timings are per subject; 0 = torch's default)."""
    out_md: OptionalPath = None
    """Also write the table as the 'finetune_curve' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def resolved_data(self) -> Path:
        return evaluation_data(self.data)

    def validate(self) -> None:
        if self.k < 1 or not self.steps or min(self.steps) < 0 or not self.finetune_lr > 0:
            raise ConfigError("--k >= 1, --steps values >= 0 (at least one) and --finetune-lr > 0 are required")
        if self.max_identities < 0 or self.max_holdouts < 0 or self.threads < 0:
            raise ConfigError("--max-identities, --max-holdouts and --threads must be >= 0")
        check_weights(self.weights)


@dataclasses.dataclass
class BenchLidsConfig:
    """Print how far the synthesised lids follow the lids they are asked for, as the driving detector and the judge
    read them (lsr.bench.bench_lids): each hold-out re-enacted with its upper lids at a range of shares of the shots'
    aperture."""

    weights: OptionalPath = None
    """A warp-guided model folder; default: $LSR_WEIGHTS, else the shipped default model."""
    data: OptionalPath = None
    """As `lsr eval --data` (an lsr dataset's test split or the FSTH layout); default: the shared FSTH sample."""
    out: Path = Path("out/bench_lids")
    """Folder for the face and mesh cache of the evaluation frames, and the readings (lids.npz)."""
    k: int = 8
    """Shots per identity (drawn as `lsr eval` draws them)."""
    holdouts: int = 3
    """Hold-outs per identity, evenly among those with a face."""
    shares: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
    """Aperture shares asked for, of the shots' at rest (0 shut, 1 as open as the shots)."""
    lids: tuple[Literal["drawn", "shots"], ...] = ("drawn", "shots")
    """Where the target shuts its eyes (as `lsr eval --lids`), one row each."""
    judge: bool = True
    """Also read the outputs and the identities' real frames with dlib's 68 points (the independent judge)."""
    figure: OptionalPath = None
    """Also write the eyes of each identity's first hold-out at every share (a .png)."""
    max_identities: int = 0
    seed: int = 0
    threads: int = 0
    """CPU threads for torch (0 = torch's default)."""
    out_md: OptionalPath = None
    """Also write the tables as the 'lids' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def resolved_data(self) -> Path:
        return evaluation_data(self.data)

    def validate(self) -> None:
        if self.k < 1 or self.holdouts < 1 or len(self.shares) < 2 or min(self.shares) < 0 or not self.lids:
            raise ConfigError("--k >= 1, --holdouts >= 1, at least two --shares >= 0 and one --lids are required")
        if not any(share < 1 for share in self.shares) or not any(share > 1 for share in self.shares):
            raise ConfigError("--shares must reach below 1 and above 1 (closing and opening are measured apart)")
        if self.max_identities < 0 or self.threads < 0:
            raise ConfigError("--max-identities and --threads must be >= 0")
        check_weights(self.weights)


@dataclasses.dataclass
class _AblationRun:
    """The options of ``BenchAblationConfig`` besides the evaluation split's (``SplitOptions``, listed after them)."""

    data: OptionalPath = None
    """Dataset root (an lsr dataset, e.g. from `lsr prepare`); its 'test' split is scored too when it has one."""
    synthetic_identities: int = 0
    """Also (or only) train on this many procedural identities, as `lsr train --synthetic-identities`."""
    out: Path = Path("runs/ablation")
    """Run folder: OUT/<variant>/ (an `lsr train` run each), OUT/eval/<split>/ (reports), OUT/ablation.json."""
    preset: Literal["paper", "small", "fast", "compact", "tiny"] = "compact"
    steps: int = 1000
    """Training steps per variant, split like `lsr train`'s stages (2 : 4 : 9); variants without G^l (baseline,
    spade_landmarks) skip stage 1 and give its steps to stage 2, so every variant trains the same number of steps."""
    batch_size: int = 8
    k: int = 4
    """K: shots per training episode (the evaluation is single-shot, K = 1)."""
    seed: int = 0
    workers: int = 0
    """DataLoader worker processes (0: load in the training process; on 2 busy cores workers only compete)."""
    threads: int = 1
    """CPU threads for torch (0 = torch's default); the default schedule was measured with 1."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    checkpoint_every: int = 200
    """Full checkpoint every N steps: a run killed by a session limit loses at most this many steps."""
    fsth: bool = True
    """Also score on the FSTH sample (--fsth-root, else ../shared/data/fsth_eval_sample; skipped when absent)."""
    fsth_root: OptionalPath = None
    lpips_weights: OptionalPath = None
    """As `lsr eval --lpips-weights` (unset: no LPIPS column)."""
    fid_weights: OptionalPath = None
    """As `lsr eval --fid-weights` (unset: no FID column)."""
    out_md: OptionalPath = None
    """Also write the tables as the 'ablation' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def validate(self) -> None:
        from landmarks.io.image_files import check_output_path

        check_output_path(self.out, "--out", folder=True)  # before hours of training
        if self.data is None and self.synthetic_identities < 1:
            raise ConfigError("give --data DATASET_ROOT and/or --synthetic-identities N (N >= 1) to train on")
        if self.data is not None and not Path(self.data).is_dir():
            raise ConfigError(f"--data {self.data} is not a folder; prepare a dataset first (see docs/TRAINING.md)")
        if self.steps < 3:
            raise ConfigError(f"--steps must be >= 3 (one per training stage), got {self.steps}")
        if self.batch_size < 1 or self.k < 1 or self.checkpoint_every < 1:
            raise ConfigError("--batch-size, --k and --checkpoint-every must be >= 1")
        if min(self.synthetic_identities, self.workers, self.threads, self.max_identities, self.max_holdouts) < 0:
            raise ConfigError("--synthetic-identities, --workers, --threads, --max-identities, --max-holdouts must be >= 0")
        if self.inputs < 1 or self.holdouts < 1:
            raise ConfigError("--inputs and --holdouts must be >= 1")
        if self.fsth_root is not None and not Path(self.fsth_root).is_dir():
            raise ConfigError(f"--fsth-root {self.fsth_root} is not a folder; give the FSTH sample or leave it unset")
        check_metric_weights(self.lpips_weights, self.fid_weights)


@dataclasses.dataclass
class BenchAblationConfig(SplitOptions, _AblationRun):
    """Reproduce the thesis ablation (Table 4.2): train baseline, +SPADE, +learned seg. maps and +latent layout with
    one schedule on one data set (resumable), score each single-shot without fine-tuning with `lsr eval`'s protocol,
    and print each metric's ranks beside the thesis' (lsr.bench.bench_ablation).

    Default schedule: 1000 steps per variant, preset compact, batch 8, K 4: the four train in about three hours on
    this project's 2-core CPU with --threads 1 while another job shares it (2.2-2.9 s/step measured so), one hour alone.
    Uncontended s/step (16 steps each, data loading included; stage 1 | stages 2-3): baseline 0.74,
    spade_landmarks 0.72, learned_seg 0.54 | 1.01, latent_layout 0.51 | 0.99. 3000 steps (~3 h alone, ~6 h shared)
    did not fit a 3-hour session, whose run folders do not outlive it."""


def shared_real_clips() -> tuple[Path | None, Path | None]:
    """Two clips of different people from the shared *training* clips (../shared/data/real_talking_heads or
    $LSR_SHARED_DATA/real_talking_heads): the manifest's first clip and the first clip of the next person."""
    import csv

    root = shared_data_dir() / "real_talking_heads"
    manifest = root / "manifest.csv"
    if not manifest.is_file():
        return None, None
    with open(manifest, newline="") as handle:
        rows = [row for row in csv.DictReader(handle) if (root / row["file"]).is_file()]
    if not rows:
        return None, None
    first = rows[0]
    other = next((row for row in rows if row["identity"] != first["identity"]), None)
    return root / first["file"], None if other is None else root / other["file"]


@dataclasses.dataclass
class BenchHardConfig:
    """Hard inputs through the pipeline: the clear error, or finite outputs with faces, against an easy twin."""

    weights: OptionalPath = None
    """Model folder; default: $LSR_WEIGHTS, else the shipped default model."""
    clip: OptionalPath = None
    """Real clip the cases are built from; default: the first of the shared training clips (synthetic if absent)."""
    other_clip: OptionalPath = None
    """Clip of another person (the 'other face shape' driver); default: the next person of the shared clips."""
    long_frames: int = 10000
    """Length of the long landmark-sequence case."""
    cases: tuple[str, ...] = ()
    """Run only these cases (names as in the table; the easy twins always run)."""
    threads: int = 1
    """CPU threads for torch (0 = torch's default)."""
    out_md: OptionalPath = None
    """Also write the table as the 'hard_cases' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def resolved_clips(self) -> tuple[Path | None, Path | None]:
        shared = shared_real_clips() if self.clip is None or self.other_clip is None else (None, None)
        return self.clip or shared[0], self.other_clip or shared[1]

    def validate(self) -> None:
        if self.long_frames < 1 or self.threads < 0:
            raise ConfigError("--long-frames must be >= 1 and --threads >= 0")
        for flag, path in (("--clip", self.clip), ("--other-clip", self.other_clip)):
            if path is not None and not Path(path).is_file():
                raise ConfigError(f"{flag} {path} is not a file; give a video")
        check_weights(self.weights)


# ---- re-enactment and deployment (lsr.commands.reenact, lsr.export.bundle) ------------------------------------------


@dataclasses.dataclass
class BenchWalkConfig:
    """Print the path of one frame through `lsr reenact --paste-back`: the modules each stage enters, in order
    (lsr.bench.bench_walk)."""

    source: OptionalPath = None
    """Source person; default the bundled example's (lsr/examples)."""
    driver: OptionalPath = None
    """Driver; default the bundled example's."""
    frame: int = 10
    """Which driver frame to follow (0-based; the first frames warm the loop up)."""
    runtime: Literal["torch", "onnx"] = "torch"
    out_md: OptionalPath = None
    """Also write the table as the 'walk' section of this markdown file (e.g. BENCHMARKS.md)."""

    def validate(self) -> None:
        if self.frame < 0:
            raise ConfigError(f"--frame must be >= 0, got {self.frame}")
        for label, path in (("--source", self.source), ("--driver", self.driver)):
            if path is not None and not Path(path).exists():
                raise ConfigError(f"{label} {path} not found")


@dataclasses.dataclass
class BenchSynthConfig:
    """Print the synthetic generator's speed (frames/s at 128² and 256², 1 and 2 workers) with machine info."""

    preset: Literal["default", "extreme_pose", "tiny_face", "huge_face", "heavy_occlusion", "low_light", "overexposed",
                    "motion_blur", "noise"] = "default"

    def validate(self) -> None:
        pass


@dataclasses.dataclass
class BenchOracleSegConfig:
    """Print the per-class IoU of the oracle face parsing (lsr.data.oracle_seg) against the official LSR maps."""

    root: tyro.conf.Positional[OptionalPath] = None
    """Folder searched for combined/*_segmap_merged.png; default: the shared fsth_eval_sample_processed."""

    def validate(self) -> None:
        if self.root is not None and not Path(self.root).is_dir():
            raise ConfigError(f"{self.root} is not a folder")


@dataclasses.dataclass
class BenchLayoutLegendConfig:
    """Name a model's latent-layout channels by the face parts they cover (lsr.bench.layout_legend): writes
    WEIGHTS/layout_legend.json, which the side-by-side, the app and the live tab show as the layout's legend."""

    data: tyro.conf.Positional[Path]
    """A prepared dataset with segmentation maps (lsr prepare), e.g. data/real256."""
    weights: OptionalPath = None
    """Model folder (default: the shipped default model); its layout_legend.json is (re)written."""
    split: str = "train"
    clips: int = 14
    """Clips surveyed, spread over the split."""
    every: int = 3
    """Every n-th frame of a clip after its 8 shots."""
    out_md: OptionalPath = None
    """Also write the table as the 'layout_legend' section of this markdown file."""

    def validate(self) -> None:
        check_weights(self.weights)
        if self.clips < 1 or self.every < 1:
            raise ConfigError(f"--clips and --every must be >= 1, got {self.clips} and {self.every}")


@dataclasses.dataclass
class BenchPlateConfig:
    """Print how well the scene plate's fill guesses the background beside a person, at several trusts
    (lsr.bench.bench_plate): one frame of the first clip of each person, a band just outside the person hidden and
    filled, its error against the real background."""

    data: OptionalPath = None
    """A folder of <person>/.../<clip>.mp4 (the first clip of each person); default: the shared training clips
    (../shared/data/real_talking_heads or $LSR_SHARED_DATA/real_talking_heads)."""
    trusts: tuple[float, ...] = (1.0, 2.0, 8.0, 16.0, 64.0)
    """``landmarks.scene.compositing.fill_in`` trusts to compare (the shipped ``PLATE_TRUST`` is marked)."""
    frame: int = 10
    """Which frame of each clip (0-based; a clip shorter than that gives its last)."""
    band: float = 0.08
    """The hidden band's width beyond the person's plate margin, in face sides."""
    max_people: int = 0
    """0 = every person."""
    out_md: OptionalPath = None
    """Also write the table as the 'plate' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def resolved_data(self) -> Path:
        if self.data is not None:
            return Path(self.data)
        return shared_data_dir() / "real_talking_heads"

    def validate(self) -> None:
        if not self.trusts or min(self.trusts) < 1.0:
            raise ConfigError(f"--trusts must be >= 1 (1 = the plain push-pull), got {self.trusts}")
        if self.frame < 0 or self.max_people < 0 or not 0.0 < self.band <= 0.5:
            raise ConfigError("--frame and --max-people must be >= 0 and --band in (0, 0.5]")
        if not self.resolved_data().is_dir():
            raise ConfigError(f"{self.resolved_data()} is not a folder: give --data, a folder of <person>/.../*.mp4")


@dataclasses.dataclass
class BenchEyesConfig:
    """Print how real and how faithful the re-enacted eyes and mouth are over whole driving clips, per eye bank
    (lsr.bench.bench_eyes): each clip re-enacted by the next as `lsr reenact` drives it, every frame judged by dlib
    beside the two detectors' agreement on the drivers' own frames, and each output eye's distance to the nearest of
    the source's real eyes beside that of its real frames."""

    clips: tuple[Path, ...] = ()
    """Videos of people (each source is driven by the next, the last by the first); default: the expressive
    evaluation set (../shared/data/clips/expressive or $LSR_SHARED_DATA/clips/expressive)."""
    weights: OptionalPath = None
    """A model folder; default: $LSR_WEIGHTS, else the shipped default model."""
    k: int = 8
    banks: tuple[Literal["none", "shots", "all", "all+mouth"], ...] = ("none", "shots", "all", "all+mouth")
    """Where the eyes come from (``lsr.core.finish.BANKS``), one row each; "all+mouth": the mouth from the bank too."""
    max_frames: int = 0
    """Judge at most this many frames of each driver, evenly spread (0 = every frame)."""
    figure: OptionalPath = None
    """Also write each pair's hardest eye moments, driver | each bank, zoomed on the eyes (a .png)."""
    threads: int = 0
    """CPU threads for torch (0 = torch's default)."""
    set_name: str = "expressive"
    """The clips' name in the table's title and its section ('eyes_<set-name>')."""
    out_md: OptionalPath = None
    """Also write the table as the 'eyes_<set-name>' section of this markdown file (e.g. BENCHMARKS.md)."""
    progress: bool = True

    def resolved_clips(self) -> tuple[Path, ...]:
        if self.clips:
            return tuple(Path(clip) for clip in self.clips)
        from landmarks.io.video import VIDEO_SUFFIXES

        folder = shared_data_dir() / "clips" / "expressive"
        return tuple(sorted(p for p in folder.glob("*") if p.suffix.lower() in VIDEO_SUFFIXES)) if folder.is_dir() else ()

    def validate(self) -> None:
        clips = self.resolved_clips()
        if len(clips) < 2:
            raise ConfigError("--clips needs at least two videos (each drives the next)" + (
                "" if self.clips else "; the default, the shared expressive set, was not found"))
        missing = [str(clip) for clip in clips if not clip.is_file()]
        if missing:
            raise ConfigError(f"--clips: no such file: {', '.join(missing)}")
        if not self.set_name.replace("_", "").isalnum():
            raise ConfigError(f"--set-name must be letters, digits and _, got {self.set_name!r}")
        if not 1 <= self.k <= 32:
            raise ConfigError(f"--k must be in 1..32, got {self.k}")
        if not self.banks or self.max_frames < 0 or self.threads < 0:
            raise ConfigError("give at least one --banks, and --max-frames and --threads >= 0")
        check_weights(self.weights)
