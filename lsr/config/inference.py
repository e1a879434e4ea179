"""Typed configs. Each dataclass is one ``lsr`` sub-command; tyro turns it into a CLI.

Configs hold values only; the work lives in the modules that ``lsr.cli`` dispatches to.
Validation happens up front in ``validate()`` so a bad flag fails before any work starts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import tyro

from lsr.core import MAX_K  # lsr/core/__init__ imports nothing: --help stays instant
from lsr.config.bench_options import (  # noqa: F401 - re-exported: every sub-command config is lsr.config.*
    BenchLandmarksConfig,
    BenchTrainConfig,
    BenchModelsConfig,
    BenchSpeedConfig,
    BenchReenactConfig,
    BenchFinetuneConfig,
    BenchHardConfig,
    BenchLidsConfig,
    BenchPlateConfig,
    BenchEyesConfig,
    BenchLayoutLegendConfig,
    BenchAblationConfig,
    BenchOracleSegConfig,
    BenchSynthConfig,
    BenchWalkConfig,
)
from lsr.config.bench_app_options import BenchLiveConfig, BenchSoakConfig, BenchWebConfig  # noqa: F401 - re-exported
from lsr.config.eval_options import EvalConfig  # noqa: F401 - re-exported
from lsr.config.shared import OptionalFloat, OptionalInt, OptionalPath, OptionalStr, check_weights
from lsr.config.train_options import (  # noqa: F401 - re-exported: every sub-command config is lsr.config.*
    FinetuneConfig,
    LossConfig,
    OptimConfig,
    PartPairsConfig,
    PartTrainConfig,
    StagesConfig,
    TrainConfig,
)
from lsr.errors import ConfigError

# Subject fine-tuning steps used by `lsr reenact`, `lsr demo` and the app unless told otherwise (thesis §4.3.5).
# 0: on the shipped warp-guided default, fine-tuning buys nothing measurable (FSTH K=8, BENCHMARKS.md: whole-frame
# PSNR 18.99 dB at 0, 10 and 25 steps; the face region likewise) and cost 4-24 s of every job. --finetune-steps N.
DEFAULT_FINETUNE_STEPS = 0


def resolve_runtime(runtime: str, finetune_steps: int | None) -> str:
    """``--runtime``: "auto" runs onnx (the exported graphs on onnxruntime: the same frames as torch, and 1.3-1.5x
    its frame rate end to end in ``lsr bench reenact``), or torch when fine-tuning steps are asked (only the torch
    model trains); "torch" and "onnx" as given."""
    if runtime not in ("auto", "torch", "onnx"):
        raise ConfigError(f"--runtime must be auto, torch or onnx, got {runtime!r}")
    if runtime != "auto":
        return runtime
    return "torch" if finetune_steps else "onnx"


@dataclasses.dataclass
class LandmarksConfig:
    """Detect and track 68-point landmarks in an image, a folder of images or a video."""

    input: tyro.conf.Positional[Path]
    """Image file, folder of images, or video file."""
    out: Path = Path("out/landmarks")
    """Output folder: landmarks.npy (N x 68 x 2, NaN rows = missing), summary.json, overlay."""
    detector: Literal["mesh", "hog", "cnn"] = "mesh"
    """Face detector and tracker: mesh (MediaPipe's detector and face mesh, Apache-2.0 models; the default), or
    dlib's HOG (fast, frontal) or CNN/mmod (slower); dlib's 68-point model is for non-commercial use."""
    face_index: int = 0
    """Which face to use when several are found, ordered largest first."""
    smooth: bool = True
    """One-Euro temporal smoothing of tracked landmarks (videos only)."""
    min_cutoff: float = 1.0
    """One-Euro minimum cutoff frequency in Hz: lower = smoother at rest, more lag."""
    beta: float = 0.05
    """One-Euro speed coefficient: higher = less lag on fast motion."""
    overlay: bool = True
    """Also write an overlay image (or an H.264 overlay video for video input)."""

    def validate(self) -> None:
        if self.face_index < 0:
            raise ConfigError(f"--face-index must be >= 0, got {self.face_index}")
        if self.min_cutoff <= 0:
            raise ConfigError(f"--min-cutoff must be > 0, got {self.min_cutoff}")
        if self.beta < 0:
            raise ConfigError(f"--beta must be >= 0, got {self.beta}")


@dataclasses.dataclass
class DemoConfig:
    """The README's main job: re-enact the bundled real example (two GRID corpus speakers, CC BY 4.0) with the
    default model, or two procedural people with --synthetic (lsr.commands.demo)."""

    out: Path = Path("out")
    """Output folder: demo.mp4, demo_side_by_side.{mp4,png}, inputs/{source,driver}.mp4."""
    weights: OptionalPath = None
    """Model folder; default: $LSR_WEIGHTS, else the shipped default model."""
    frames: int = 100
    """Frames of the driving clip (25 fps; the real example's driver has 75)."""
    k: int = 8
    """Source shots to average (1..32)."""
    finetune_steps: int = DEFAULT_FINETUNE_STEPS
    """Subject fine-tuning steps on the K shots before re-enacting (thesis §4.3.5; 0 = the meta-learned model)."""
    threads: int = 0
    """CPU threads for the networks; 0 = the library default."""
    synthetic: bool = False
    """Two procedural people the model never saw (exact ground truth) instead of the bundled real example."""
    progress: bool = True

    def validate(self) -> None:
        check_weights(self.weights)
        if self.finetune_steps < 0:
            raise ConfigError(f"--finetune-steps must be >= 0, got {self.finetune_steps}")
        if self.frames < 1:
            raise ConfigError(f"--frames must be >= 1, got {self.frames}")
        if not 1 <= self.k <= MAX_K:
            raise ConfigError(f"--k must be in 1..{MAX_K}, got {self.k}")
        if self.threads < 0:
            raise ConfigError(f"--threads must be >= 0, got {self.threads}")


@dataclasses.dataclass
class SynthConfig:
    """Render procedural 3D talking heads with exact ground truth into an LSR dataset (or a preview / a benchmark)."""

    out: Path = Path("data/synth")
    """Dataset root to write (<identity>/<video>/ clips + manifest.json)."""
    identities: int = 20
    """Number of synthetic people."""
    videos_per_identity: int = 2
    """Videos per person (same identity, new background, motion and light)."""
    frames: int = 50
    """Frames per video."""
    resolution: int = 128
    """Frame side S (S x S); 128 default, 256 supported."""
    seed: int = 0
    """Dataset seed: the same seed gives byte-identical arrays; identity i depends only on (seed, i)."""
    preset: Literal[
        "default", "extreme_pose", "tiny_face", "huge_face", "heavy_occlusion", "low_light", "overexposed", "motion_blur", "noise"
    ] = "default"
    """Distribution: default, or a hard case (pose, framing, occlusion, exposure, blur, noise)."""
    test_fraction: float = 0.2
    """Share of identities in the manifest's test split."""
    fps: float = 25.0
    """Frame rate of the motion (talking speed, blinks)."""
    framing: Literal["aligned", "camera"] = "aligned"
    """aligned: faces cropped per frame like inference and `lsr prepare` (rendered at 2x, then cropped);
    camera: the scene camera's framing (the head moves inside a fixed frame)."""
    workers: int = 1
    """Parallel clip workers (processes); -1 = min(2, CPU count). Output does not depend on it."""
    overwrite: bool = False
    """Replace clips that already exist under --out."""
    preview: OptionalPath = None
    """Only write a contact sheet PNG here (frame | landmarks | landmark image | classes), no dataset."""

    def validate(self) -> None:
        if self.identities < 1 or self.videos_per_identity < 1 or self.frames < 1:
            raise ConfigError("--identities, --videos-per-identity and --frames must all be >= 1")
        if self.resolution < 32:
            raise ConfigError(f"--resolution must be >= 32, got {self.resolution}")
        if not 0.0 <= self.test_fraction < 1.0:
            raise ConfigError(f"--test-fraction must be in [0, 1), got {self.test_fraction}")
        if self.fps <= 0:
            raise ConfigError(f"--fps must be > 0, got {self.fps}")
        if self.workers == 0 or self.workers < -1:
            raise ConfigError(f"--workers must be >= 1 or -1 (auto), got {self.workers}")
        if self.preview is not None and self.preview.suffix.lower() not in (".png", ".jpg", ".jpeg"):
            raise ConfigError(f"--preview must name a .png or .jpg file, got {self.preview}")


@dataclasses.dataclass
class PrepareConfig:
    """Turn real videos / images (VoxCeleb2 layout, any folder, or the LSR release layout) into an LSR dataset."""

    input: tyro.conf.Positional[Path]
    """A video, a folder of videos / image folders, or an LSR release folder ({train,test}/<id>/<video>/combined/)."""
    out: Path = Path("data/prepared")
    """Dataset root to write (clips + manifest.json). Finished clips are skipped, so a run can be resumed."""
    resolution: int = 256
    """Training resolution S: frames, landmarks and segmentation are S x S."""
    frames_per_clip: int = 10
    """Frames sampled uniformly per clip (frames without a face are dropped); 0 = all frames, tracked (kept with NaN)."""
    framing: Literal["auto", "align", "keep"] = "auto"
    """align: crop and align on the landmarks; keep: centre square + resize; auto: keep for the LSR release layout."""
    detector: Literal["mesh", "hog", "cnn"] = "mesh"
    """Face detector: mesh (MediaPipe, the default) or dlib's hog / cnn."""
    official_segmaps: bool = True
    """Use an official *_segmap_merged.png beside an LSR release frame (framing keep) instead of the oracle."""
    workers: int = -1
    """Parallel clip workers; -1 = min(2, CPU count)."""
    test_fraction: float = 0.1
    """Share of identities put in the manifest's test split (stable hash of the name)."""
    test_identities: tuple[str, ...] = ()
    """Identities forced into the test split."""
    split_all: Literal["auto", "train", "test"] = "auto"
    """Put every identity into one split; auto: LSR release inputs -> test, others by --test-fraction."""
    progress: bool = True
    """A progress bar over the clips (--no-progress in logs, as lsr eval and lsr train take it)."""

    def validate(self) -> None:
        from landmarks.io.image_files import check_output_path

        check_output_path(self.out, "--out", folder=True)  # before any video is read
        if self.resolution < 32:
            raise ConfigError(f"--resolution must be >= 32, got {self.resolution}")
        if self.frames_per_clip < 0:
            raise ConfigError(f"--frames-per-clip must be >= 0 (0 = all frames), got {self.frames_per_clip}")
        if not 0.0 <= self.test_fraction < 1.0:
            raise ConfigError(f"--test-fraction must be in [0, 1), got {self.test_fraction}")
        if self.workers == 0 or self.workers < -1:
            raise ConfigError(f"--workers must be >= 1 or -1 (auto), got {self.workers}")


# ---- training (lsr.train) -------------------------------------------------------------------------------


@dataclasses.dataclass
class SingleJob:
    """The inputs and outputs of one re-enactment (``lsr reenact``)."""

    source: OptionalPath = None
    """Source person: an image, a folder of images, or a video (K frames with a face are sampled)."""
    driver: OptionalPath = None
    """Driver: a video, a folder of frames, or landmarks (.npy/.json, N x 68 x 2; see --landmark-space)."""
    out: OptionalPath = None
    """Output .mp4."""
    side_by_side: OptionalPath = None
    """Also write driver | landmarks | latent layout | output to this .mp4."""


@dataclasses.dataclass
class ManyJobs:
    """The jobs of a batch (``lsr batch``): a CSV, or every source of one folder with every driver of another."""

    jobs: OptionalPath = None
    """CSV with columns source,driver,output (paths relative to the CSV)."""
    source_dir: OptionalPath = None
    """Folder of sources (images, videos, or sub-folders of images)."""
    driver_dir: OptionalPath = None
    """Folder of drivers (videos, landmark files, or sub-folders of frames)."""
    out_dir: OptionalPath = None
    """Output folder for --source-dir/--driver-dir."""
    pairing: Literal["all", "by-name"] = "all"
    """Folders: every source x driver (<source>__<driver>.mp4), or same-stem pairs (<stem>.mp4)."""
    shard: OptionalStr = None
    """Take job share i of n ('i/n'); default RANK/WORLD_SIZE under torchrun, else all jobs."""


@dataclasses.dataclass
class JobOptions:
    """How every re-enactment job runs: declared once for ``lsr reenact`` and ``lsr batch``. The part ablations
    (eyes, lids, mouth, its interior, 3D retargeting) are ``lsr eval``'s and ``lsr bench``'s options; a job runs the
    best measured defaults (MODEL_CARD.md)."""

    weights: OptionalPath = None
    """Model folder (config.json + model.safetensors); for --runtime onnx also an `lsr export` bundle (a model
    folder without one is exported on first use and cached). Default: $LSR_WEIGHTS, else the shipped model."""
    k: OptionalInt = None
    """Shots of the source to average (1..32); default min(8, frames with a face). Larger than usable is an error."""
    paste_back: bool = False
    """Composite the re-enacted face into full frames of --scene (background and body stay, hair follows the head);
    otherwise output the crop-sized synthesis."""
    scene: Literal["source", "driver"] = "source"
    """--paste-back into the source's own scene (its anchor shot, or its video's frames back and forth; the output
    has the source's frame size) or into the driver's frames (dubbing; a face swap when the people differ)."""
    watermark: bool = False
    """Draw a visible 'SYNTHETIC' mark in the corner (container metadata always marks outputs as synthetic)."""
    runtime: Literal["auto", "torch", "onnx"] = "auto"
    """onnx: the exported graphs on onnxruntime (the same frames as torch, 1.3-1.5x faster end to end); torch: the
    model itself (a CUDA GPU when one is visible; fine-tuning); auto: torch when --finetune-steps asks for
    fine-tuning, else onnx."""
    finetune_steps: OptionalInt = None
    """Fine-tune the generators on the source shots first (thesis §4.3.5; torch runtime only). Default:
    DEFAULT_FINETUNE_STEPS (0: it buys nothing measurable on the shipped default; `lsr bench finetune`)."""
    motion: Literal["auto", "relative", "absolute"] = "auto"
    """relative = the driver's motion on the source's face shape; absolute = the driver's own landmarks; auto =
    absolute when the driver is the source itself, else relative."""
    face_index: int = 0
    """Which face of a source frame showing several people (0 = the largest; the output says when there were several)."""
    anchor: OptionalInt = None
    """Which of the K source shots is the neutral face and the scene (0..K-1); default the most frontal one with a
    closed mouth."""
    landmark_space: Annotated[Literal["frame", "crop"] | None,
                              tyro.conf.arg(metavar="{frame,crop}", help_behavior_hint="(optional)")] = None
    """Landmark drivers: pixel coordinates of the driver's frames (default), or of a training-framed crop (of the
    side a .json file gives, else the model's)."""
    fps: OptionalFloat = None
    """Output fps for landmark / image-folder drivers (default 25; videos keep their own)."""
    detector: Literal["mesh", "hog", "cnn"] = "mesh"
    """Face detector and tracker: mesh (MediaPipe, the default) or dlib's hog / cnn."""
    threads: int = 0
    """CPU threads for the networks (torch intra-op / onnxruntime intra-op); 0 = all cores but one, which decoding,
    tracking and encoding use beside the network (lsr.core.overlap.network_threads)."""
    overwrite: bool = False
    """Redo jobs whose output already exists (default: skip them, which makes reruns resume)."""
    progress: bool = True

    @property
    def resolved_runtime(self) -> str:
        """--runtime with "auto" resolved (``resolve_runtime``): "torch" or "onnx"."""
        return resolve_runtime(self.runtime, self.finetune_steps)

    @property
    def resolved_finetune_steps(self) -> int:
        """--finetune-steps, or its default for the runtime (the ONNX runtime cannot train)."""
        if self.finetune_steps is not None:
            return self.finetune_steps
        return DEFAULT_FINETUNE_STEPS if self.resolved_runtime == "torch" else 0

    def validate_options(self) -> None:
        if self.threads < 0:
            raise ConfigError(f"--threads must be >= 0, got {self.threads}")
        if self.face_index < 0:
            raise ConfigError(f"--face-index must be >= 0 (0 = the largest face), got {self.face_index}")
        check_weights(self.weights)
        if self.k is not None and not 1 <= self.k <= MAX_K:
            raise ConfigError(f"--k must be in 1..{MAX_K}, got {self.k}")
        if (self.finetune_steps or 0) < 0:
            raise ConfigError(f"--finetune-steps must be >= 0, got {self.finetune_steps}")
        if self.finetune_steps and self.resolved_runtime != "torch":
            raise ConfigError("--finetune-steps needs --runtime torch (fine-tuning trains the torch model)")
        if self.fps is not None and not self.fps > 0:
            raise ConfigError(f"--fps must be > 0, got {self.fps}")


@dataclasses.dataclass
class ReenactConfig(JobOptions, SingleJob):
    """Re-enact a source person with a driver: one job (--source/--driver/--out); many jobs: `lsr batch`."""

    def validate(self) -> None:
        self.validate_options()
        if None in (self.source, self.driver, self.out):
            raise ConfigError("lsr reenact needs --source, --driver and --out (many jobs: lsr batch)")
        if Path(self.out).suffix.lower() != ".mp4":
            raise ConfigError(f"--out must be an .mp4 file, got {self.out}")


@dataclasses.dataclass
class BatchConfig(JobOptions, ManyJobs):
    """Re-enact many (source, driver) pairs: a jobs CSV, or two folders; resumable and shardable."""

    def validate(self) -> None:
        self.validate_options()
        dirs = [self.source_dir, self.driver_dir, self.out_dir]
        if (self.jobs is not None) == any(v is not None for v in dirs):
            raise ConfigError("give exactly one of: --jobs CSV, or --source-dir/--driver-dir/--out-dir")
        if any(v is not None for v in dirs) and None in dirs:
            raise ConfigError("folders need all of --source-dir, --driver-dir and --out-dir")


@dataclasses.dataclass
class ExportConfig:
    """Export a model folder to the ONNX bundle run by deploy.runtime.OnnxReenactor (no torch needed)."""

    weights: OptionalPath = None
    """Model folder (config.json + model.safetensors); default: $LSR_WEIGHTS, else the shipped default model (MODEL_CARD.md)."""
    out: Path = Path("out/onnx")
    """Bundle folder: subject_encoder.onnx, frame_generator.onnx [, frame_generator.int8.onnx]."""
    int8: bool = False
    """Also write a frame generator whose network convolutions are int8, calibrated on real frames; prints its error vs fp32."""
    calibration_source: OptionalPath = None
    """--int8: source (image/folder/video) whose latents calibrate; default the bundled example person
    (lsr/examples), never an evaluation clip."""
    calibration_driver: OptionalPath = None
    """--int8: driving video whose landmark images calibrate; default --calibration-source, or the bundled example
    driver when that is not given."""
    calibration_frames: int = 32
    calibration_k: OptionalInt = None
    web: OptionalPath = None
    """Write the static web site here instead of the bundle: the example person re-enacted from the webcam in the
    browser (deploy/web, onnxruntime-web; needs Node.js and npm to build). Serve the folder with any static server."""

    def validate(self) -> None:
        check_weights(self.weights)
        if self.web is not None and self.int8:
            raise ConfigError("--web writes the site with the fp32 frame generator; leave out --int8")
        if self.calibration_frames < 1:
            raise ConfigError(f"--calibration-frames must be >= 1, got {self.calibration_frames}")


@dataclasses.dataclass
class AppConfig:
    """Start the Gradio web app (K-shot upload, re-enactment, the latent layout made visible) on HOST:PORT."""

    weights: OptionalPath = None
    """Model folder (config.json + model.safetensors, from `lsr train`). Default: $LSR_WEIGHTS, else the
    shipped default model (trained on synthetic heads; see MODEL_CARD.md)."""
    random_init: bool = False
    """No trained model yet: serve a randomly initialised 'tiny' model (outputs are noise; to try the interface)."""
    host: str = "127.0.0.1"
    port: int = 7860
    device: Literal["auto", "cpu", "cuda"] = "auto"
    max_video_seconds: float = 20.0
    """Longest driving or source video accepted (seconds)."""
    max_video_frames: int = 500
    """Most driving frames accepted (video frames or landmark rows)."""
    max_upload_mb: float = 50.0
    """Largest single uploaded file (MB)."""
    max_k: int = MAX_K
    """Largest K (source shots) offered (1..32)."""
    queue_size: int = 8
    """Requests allowed to wait while one runs (one runs at a time); beyond that the page says the queue is full."""
    examples_dir: OptionalPath = None
    """Where the bundled synthetic examples are generated on first use (default ~/.cache/lsr/app_examples)."""

    def validate(self) -> None:
        check_weights(self.weights)
        if self.weights is not None and self.random_init:
            raise ConfigError("--weights and --random-init exclude each other")
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"--port must be in 0..65535, got {self.port}")
        if self.max_video_seconds <= 0 or self.max_video_frames < 1 or self.max_upload_mb <= 0 or self.queue_size < 1:
            raise ConfigError("--max-video-seconds and --max-upload-mb must be > 0; --max-video-frames, --queue-size >= 1")
        if not 1 <= self.max_k <= MAX_K:
            raise ConfigError(f"--max-k must be in 1..{MAX_K}, got {self.max_k}")


@dataclasses.dataclass
class ShipConfig:
    """Copy a training run's weights into the package as the default model (checks that the copy loads; prints
    sizes and SHA-256 sums for MODEL_CARD.md). Never ship weights trained on the evaluation people."""

    weights: tyro.conf.Positional[Path]
    """The run's weights folder (RUN/weights: config.json + model.safetensors [+ discriminator.safetensors])."""

    def validate(self) -> None:
        if not Path(self.weights).is_dir():
            raise ConfigError(f"{self.weights} is not a folder; give a run's weights folder (RUN/weights)")


@dataclasses.dataclass
class CurvesConfig:
    """Write a training run's loss curves (its TensorBoard scalars) as one PNG of line plots."""

    run: tyro.conf.Positional[Path]
    """The run folder of `lsr train --out RUN` (or its tensorboard/ folder)."""
    out: Path = Path("out/curves.png")
    tags: tuple[str, ...] = ()
    """Only these scalars (e.g. g/l1 d/loss); empty = all."""

    def validate(self) -> None:
        if not Path(self.run).is_dir():
            raise ConfigError(f"{self.run} is not a folder; give the run folder of `lsr train --out RUN`")


@dataclasses.dataclass
class FaceModelsConvertConfig:
    """Rebuild the shipped face models: MediaPipe 0.10.21's face detector and face mesh, TFLite -> ONNX, checked
    against the originals on real frames (landmarks.detect.rebuild_mediapipe; needs pip install '.[convert]')."""

    wheel: OptionalPath = None
    """A downloaded mediapipe-0.10.21 wheel (checked by sha256); default: pip download it."""
    frames: tuple[Path, ...] = ()
    """Videos to check the conversion on (default: the ../shared clips that exist, else a seeded random image)."""
    frames_per_video: int = 10
    """Frames spread through each video."""
    out: OptionalPath = None
    """Folder for the models, SOURCES.json, LICENSE and NOTICE (default: the package's landmarks/assets/mediapipe)."""

    def validate(self) -> None:
        if self.frames_per_video < 1:
            raise ConfigError(f"--frames-per-video must be >= 1, got {self.frames_per_video}")


@dataclasses.dataclass
class FaceModelsFitConfig:
    """Fit the 68-from-mesh mapping (landmarks.shape.mesh68, against dlib's points) and the canonical mesh of the 3D head
    pose (landmarks.motion.mesh_rotation) on the training people's clips."""

    data: tyro.conf.Positional[Path]
    """The real_talking_heads folder (training people; the validation people are left out)."""
    frames_per_clip: int = 6
    """Frames spread through each clip."""
    out: OptionalPath = None
    """Folder for mesh68.json and mesh_canonical.json (default: the package's landmarks/assets)."""

    def validate(self) -> None:
        if self.frames_per_clip < 1:
            raise ConfigError(f"--frames-per-clip must be >= 1, got {self.frames_per_clip}")


@dataclasses.dataclass
class FaceModelsLidsConfig:
    """Survey where the training people's lids sit when their eyes close (landmarks.parts.eyes.lids_survey): the numbers
    behind landmarks.parts.eyes.lids.LID_CLOSED and CLOSED_SHARE, for the mesh net's own eye contours and the refined ones."""

    data: tyro.conf.Positional[Path]
    """The real_talking_heads folder (training people; the validation people are left out)."""
    frames_per_clip: int = 64
    """Frames spread through each clip."""

    def validate(self) -> None:
        if self.frames_per_clip < 1:
            raise ConfigError(f"--frames-per-clip must be >= 1, got {self.frames_per_clip}")

