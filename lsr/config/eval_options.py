"""The config of ``lsr eval`` (re-exported by ``lsr.config``): the thesis protocol (§4.4) and its options."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from landmarks.parts.mouth.opening_gain import GAIN_RANGE
from lsr.config.shared import OptionalPath, SplitOptions, check_metric_weights, check_weights, evaluation_data
from lsr.core import DEFAULT_FINETUNE_LR
from lsr.errors import ConfigError


@dataclasses.dataclass
class _EvalRun:
    """The options of ``EvalConfig`` besides the evaluation split's (``SplitOptions``, listed after them)."""

    data: OptionalPath = None
    """LSR-release folder ({train,test}/<id>/<video>/combined/*_rgb.png) or an lsr dataset root (manifest.json);
    default: the shared FSTH sample (../shared/data/fsth_eval_sample, or $LSR_SHARED_DATA/fsth_eval_sample)."""
    out: Path = Path("out/eval")
    """Output folder: eval_report.md, eval_report.json, examples/, cache/ (detected landmarks)."""
    k: tuple[int, ...] = (1, 4, 8, 32)
    """K values (shots per identity), thesis Table 4.4."""
    methods: tuple[Literal["nearest_shot", "tps", "tps_mean3", "mesh", "mesh_mean3"], ...] = (
        "nearest_shot", "tps", "tps_mean3", "mesh", "mesh_mean3")
    """Methods to evaluate (the no-learning baselines of lsr.eval.baselines); mesh and mesh_mean3 warp over the face
    mesh and need --detector mesh (with a dlib detector they are skipped, with a note)."""
    weights: tuple[Path, ...] = ()
    """Trained LSR model folders (config.json + model.safetensors) to evaluate beside the baselines."""
    finetune_steps: int = 0
    """> 0: also evaluate each model fine-tuned on the K shots of each identity for this many steps (thesis §4.3.5)."""
    finetune_lr: float = DEFAULT_FINETUNE_LR
    """Adam lr of that fine-tuning (G^l, G^s, D)."""
    device: str = "cpu"
    """Torch device of the models (cpu, cuda, cuda:1, ...)."""
    split: str = "test"
    """Split of an lsr dataset to evaluate on."""
    seed: int = 0
    """Seed of the K-shot sampling."""
    shot_choice: Literal["random", "spread", "cover"] = "random"
    """How the K shots are drawn from an identity's inputs: random (the protocol's, seeded), spread (evenly over the
    inputs in time) or cover (as lsr reenact
    chooses them from many: spread over them with the person's extreme moments swapped in, lsr.core.inputs.choose_shots)."""
    judge: bool = True
    """Also judge the moving parts with dlib's 68 points, a detector that did not drive them (lsr.eval.part_regions):
    mouth and eye correlation and gain, gaze, iris contrast and the mouth's inside, cross-identity."""
    detector: Literal["mesh", "hog", "cnn"] = "mesh"
    """Face detector for ground-truth and output landmarks: mesh (MediaPipe, what reenact uses by default) or dlib's."""
    reference_warps: tuple[Literal["mesh", "tps"], ...] = ("mesh",)
    """How warp-guided models' references are warped: mesh (over the face mesh, needs --detector mesh) or tps (the
    68-point TPS); more than one adds a row per extra choice ("+tps-refs"), in the same run."""
    mouths: tuple[Literal["drawn", "nearest", "blend"], ...] = ()
    """A warp-guided model's mouth: drawn (redrawn by the model's mouth generator, lsr.core.finish), nearest (from the
    nearest warped shot, landmarks.parts.mouth.nearest_mouth) or blend (the network's blend of all its shots); empty: the model's
    default (drawn when it has a mouth generator); more than one adds a row per extra choice ("+blend-mouth")."""
    eyes: tuple[Literal["drawn", "warped", "blend"], ...] = ()
    """A model's eyes: drawn (one iris per eye, the subject's own, where the target looks: lsr.core.finish), warped
    (the shots' irises carried by their warps to where the target looks: landmarks.parts.eyes.iris_shift) or blend (the network's
    blend of its shots); empty: the model's default; more than one adds a row per extra choice
    ("+blend-eyes")."""
    mouth_interiors: tuple[Literal["driver", "shots"], ...] = ()
    """Inside a model's open mouth, cross-identity: driver (the driving frame's cavity, teeth and tongue inside the
    target's inner lips: landmarks.parts.mouth.interior) or shots (what the mouth choice gives); empty: the model's default
    (driver); more than one adds a row per extra choice ("+shots-interior"). Self re-enactment drives by landmarks
    alone (its driving frames are the ground truth), so there it changes nothing."""
    lids: tuple[Literal["drawn", "driver", "shots"], ...] = ()
    """Where the target shuts its eyes: drawn (the subject's own upper lids drawn down: landmarks.parts.eyes.drawn_lids), driver
    (cross-identity, the driving frame's shut lids laid over the model's eyes: landmarks.parts.eyes.driver_lids; self
    re-enactment, which drives by landmarks alone, drawn) or shots (the warped shots' lids alone); empty: the model's
    default (drawn); more than one adds a row per extra choice ("+shots-lids")."""
    banks: tuple[Literal["shots", "none"], ...] = ()
    """Where a model's eyes and mouth come from (landmarks.parts): shots (one real exemplar of the person per part and
    frame, from the K shots: the protocol's inputs) or none (the synthesis'); empty: the model's default (shots);
    more than one adds a row per extra choice ("+none-bank")."""
    expression_gains: tuple[float, ...] = ()
    """How many times, at most, a warp-guided model's mesh-warped references carry a shot's mouth toward a target
    that opens it wider (landmarks.parts.mouth.opening_gain, in [1, 2]; 1 = onto the target's points); empty: the model's
    default (1.25); more than one adds a row per extra gain ("+gain1")."""
    detector_upsample: int = 1
    """dlib only: pyramid upsampling; 1 finds the faces of 224-px crops at 1/4 the cost of 2."""
    bucket_thresholds: tuple[float, ...] = ()
    """Two pose-distance thresholds (low/medium, medium/high); empty = terciles per K."""
    cross_identity: bool = True
    """Also drive each identity with the next identity's landmarks, retargeted and composited into the source's
    anchor shot as `lsr reenact` does (expression, pose, identity and scene metrics; lsr.eval.cross)."""
    cross_drivers: int = 1
    """Drive each identity with the next N identities (i+1 ... i+N, at most all the others): N x the cross-identity
    sequences, for a steadier mean on few people."""
    retarget: Literal["2d", "3d"] = "2d"
    """How the cross-identity driver moves the source (landmarks.motion.retarget_mesh.retarget_face): 2d = the 68 points'
    relative motion, as `lsr reenact` drives; 3d = the head turned as a rotation of the source's own face mesh, the
    expression moved in the canonical head frame (needs --detector mesh; frames without a mesh as 2d)."""
    tps_regularization: float = 1e-3
    """lambda of the TPS baselines, tps and tps_mean3 (unit-spread coordinates)."""
    examples: int = 4
    """Frames per (method, K, identity) written to OUT/examples (output above ground truth); 0 = none."""
    figure: OptionalPath = None
    """Also write one picture comparing the methods: a hold-out frame per identity, methods side by side (PNG);
    with --cross-identity, also <stem>_cross<suffix> beside it: driver | source anchor | composited outputs."""
    figure_k: int = 8
    """K of that picture (one of --k)."""
    lpips_weights: OptionalPath = None
    """LPIPS (AlexNet v0.1) weights file, .pth or .safetensors (see lsr/eval/lpips.py); unset = LPIPS not computed."""
    fid_weights: OptionalPath = None
    """FID feature extractor, TorchScript (.pt) or .onnx (see lsr/eval/fid.py); unset = FID not computed."""
    out_md: OptionalPath = None
    """Also put the report into this markdown file (e.g. BENCHMARKS.md) as the section named by --section,
    with the command that wrote it; other sections are kept."""
    section: str = "eval"
    """Name of that section: its markers are <!-- eval:NAME:start --> / <!-- eval:NAME:end -->."""
    title: str = ""
    """Heading of that section (default: the data folder)."""
    note: str = ""
    """A note printed under the command in that section (e.g. how the weights were trained)."""
    progress: bool = True

    def resolved_data(self) -> Path:
        """--data, or the shared FSTH sample; ConfigError when neither exists."""
        return evaluation_data(self.data)

    def validate(self) -> None:
        from landmarks.io.image_files import check_output_path

        check_output_path(self.out, "--out", folder=True)  # before the frames are loaded and scored
        if self.data is not None and not Path(self.data).is_dir():
            raise ConfigError(f"--data {self.data} is not a folder")
        if not self.k or min(self.k) < 1:
            raise ConfigError(f"--k needs values >= 1, got {self.k}")
        if not self.methods and not self.weights:
            raise ConfigError("--methods needs at least one of nearest_shot, tps, tps_mean3, mesh, mesh_mean3 (or give --weights)")
        if not self.reference_warps:
            raise ConfigError("--reference-warps needs at least one of mesh, tps")
        if any(not GAIN_RANGE[0] <= gain <= GAIN_RANGE[1] for gain in self.expression_gains):
            raise ConfigError(f"--expression-gains must lie in [{GAIN_RANGE[0]:g}, {GAIN_RANGE[1]:g}], got "
                              f"{' '.join(map(str, self.expression_gains))}")
        for folder in self.weights:
            check_weights(folder)
        if self.finetune_steps < 0 or not self.finetune_lr > 0:
            raise ConfigError(f"--finetune-steps must be >= 0 and --finetune-lr > 0, got {self.finetune_steps}, {self.finetune_lr}")
        if self.inputs < 1 or self.holdouts < 1 or self.max_holdouts < 0 or self.max_identities < 0 or self.examples < 0:
            raise ConfigError("--inputs, --holdouts >= 1 and --max-holdouts, --max-identities, --examples >= 0 are required")
        if self.detector_upsample < 0:
            raise ConfigError(f"--detector-upsample must be >= 0, got {self.detector_upsample}")
        if self.figure is not None and self.figure_k not in self.k:
            raise ConfigError(f"--figure-k {self.figure_k} is not among --k {' '.join(map(str, self.k))}")
        if self.bucket_thresholds and (len(self.bucket_thresholds) != 2 or self.bucket_thresholds[0] > self.bucket_thresholds[1]):
            raise ConfigError(f"--bucket-thresholds needs two increasing values (or none for terciles), got {self.bucket_thresholds}")
        if self.tps_regularization < 0:
            raise ConfigError(f"--tps-regularization must be >= 0, got {self.tps_regularization}")
        if not self.section.replace("_", "").replace("-", "").isalnum():
            raise ConfigError(f"--section must be letters, digits, '-' or '_', got {self.section!r}")
        check_metric_weights(self.lpips_weights, self.fid_weights)


@dataclasses.dataclass
class EvalConfig(SplitOptions, _EvalRun):
    """Evaluate re-enactment with the thesis protocol (§4.4): K shots from the inputs, metrics on hold-out frames."""
