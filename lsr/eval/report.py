"""``lsr eval``: run the protocol (``lsr.eval.protocol``) and write the report (markdown + JSON).

The report lists, per method and K: PSNR (mean over finite frames, the count of identical
frames = +inf, and PSNR of the mean MSE), PSNR and SSIM inside the face, SSIM, sharpness (median
Laplacian-variance ratio to the ground truth), ID-SIM, NMKE and the count of outputs without a detected
face; ID-SIM per pose-variance bucket (thesis §4.5.1); cross-identity re-enactment (§4.4.3, retargeted and
composited as ``lsr reenact`` does: expression, pose, NMKE, identity, sharpness and scene metrics,
``lsr.eval.cross``); TPS warp-method counts; methods skipped (the mesh baselines without a mesh detector); the thesis' Table 4.4 rows for reference; machine info.
With ``--figure``: the methods side by side on one hold-out frame per identity, and beside it
(``<figure>_cross.<ext>``) the cross-identity figure (``CrossFigure``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from landmarks.parts.appearance import gazes
from landmarks.detect.same_person import SAME_PERSON_RADIUS
from lsr.errors import ConfigError
from lsr.eval import cross, idsim, metrics
from lsr.eval import part_regions as parts
from lsr.eval.protocol import BUCKETS, EvalIdentity, EvalRun
from lsr.eval.machine import shown_path

if TYPE_CHECKING:
    from lsr.config import EvalConfig

NOT_COMPUTED = "not computed (pass --lpips-weights / --fid-weights: LPIPS needs AlexNet + LPIPS v0.1 heads, FID a feature extractor; neither can be downloaded here, see lsr/eval/lpips.py and lsr/eval/fid.py)"

# Thesis Table 4.4 (VoxCeleb2 test set of FSTH: 50 ids, 1,600 frames; ID-SIM from a VGGFace network).
# (method, K, fine-tuned): (PSNR, SSIM, LPIPS, ID-SIM, NMKE, FID); None = not reported.
THESIS_TABLE_4_4: dict[tuple[str, int, bool], tuple[float | None, ...]] = {
    ("FSTH", 1, False): (16.80, 0.570, 0.259, 0.801, 0.048, 51.12),
    ("FSTH", 1, True): (16.92, 0.597, 0.263, 0.836, 0.049, 53.07),
    ("LPD", 1, False): (None, None, None, 0.732, 0.072, 80.20),
    ("LPD", 1, True): (None, None, None, 0.837, 0.070, 48.48),
    ("LSR (ours)", 1, False): (17.27, 0.598, 0.241, 0.869, 0.041, 48.11),
    ("LSR (ours)", 1, True): (17.37, 0.605, 0.232, 0.886, 0.041, 45.69),
    ("LPD", 4, False): (None, None, None, 0.755, 0.069, 79.67),
    ("LPD", 4, True): (None, None, None, 0.909, 0.058, 38.81),
    ("LSR (ours)", 4, False): (18.90, 0.638, 0.192, 0.909, 0.039, 43.19),
    ("LSR (ours)", 4, True): (19.33, 0.661, 0.171, 0.930, 0.037, 34.31),
    ("FSTH", 8, False): (17.86, 0.600, 0.225, 0.836, 0.046, 46.38),
    ("FSTH", 8, True): (18.35, 0.647, 0.218, 0.899, 0.044, 45.15),
    ("LPD", 8, False): (None, None, None, 0.760, 0.068, 77.00),
    ("LPD", 8, True): (None, None, None, 0.922, 0.056, 35.87),
    ("LSR (ours)", 8, False): (19.18, 0.645, 0.186, 0.917, 0.039, 44.23),
    ("LSR (ours)", 8, True): (19.65, 0.675, 0.160, 0.940, 0.036, 32.54),
    ("FSTH", 32, False): (18.66, 0.613, 0.207, 0.843, 0.044, 44.85),
    ("FSTH", 32, True): (19.69, 0.686, 0.171, 0.927, 0.041, 33.69),
    ("LPD", 32, False): (None, None, None, 0.769, 0.066, 63.47),
    ("LPD", 32, True): (None, None, None, 0.935, 0.054, 33.96),
    ("LSR (ours)", 32, False): (19.35, 0.650, 0.182, 0.921, 0.037, 43.32),
    ("LSR (ours)", 32, True): (19.98, 0.690, 0.146, 0.948, 0.038, 28.26),
}


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


def _expression_correlations(group: list[dict[str, Any]]) -> dict[str, float]:
    """Self re-enactment's mouth / eye correlation: per identity, the Pearson correlation of the ground truth's
    openings with the output's detected ones (``lsr.eval.cross.opening_correlation``), averaged over identities
    (NaN where no identity has enough frames with a face and some motion)."""
    by_identity: dict[str, list[dict[str, Any]]] = {}
    for record in group:
        by_identity.setdefault(record["identity"], []).append(record)
    values = {}
    for part in ("mouth", "eye"):
        correlations = [cross.opening_correlation(np.array([r[f"truth_{part}"] for r in records], np.float64),
                                                  np.array([r[f"output_{part}"] for r in records], np.float64))
                        for records in by_identity.values()]
        values[f"{part}_corr"] = _mean(correlations)
    return values


def summarise(run: EvalRun, fid: dict[tuple[str, int], Any] | None = None, backbones: dict[str, str] | None = None) -> dict[str, Any]:
    """Aggregate an EvalRun into JSON-ready tables (keys: rows, buckets, cross, thresholds, counts, settings).

    LPIPS comes from the records' "lpips" values (``run_protocol(frame_metrics=...)``); fid maps
    (method, K) -> ``lsr.eval.fid.FidResult``; backbones {"lpips"/"fid": description} replaces
    NOT_COMPUTED for the metrics that were computed."""
    fid = fid or {}
    backbones = backbones or {}
    rows, bucket_rows = [], []
    for name in run.settings["methods"]:
        for k in run.settings["ks"]:
            group = [r for r in run.records if r["method"] == name and r["k"] == k]
            if not group:
                continue
            psnr = metrics.summarise_psnr(np.array([r["psnr"] for r in group]), np.array([r["mse"] for r in group]))
            rows.append({
                "method": name, "k": k, "frames": len(group),
                "psnr": psnr["mean_finite"], "psnr_infinite": psnr["infinite"], "psnr_of_mean_mse": psnr["of_mean_mse"],
                "psnr_face": _mean([r["psnr_face"] for r in group]),
                "psnr_face_infinite": sum(math.isinf(r["psnr_face"]) for r in group),
                "ssim": _mean([r["ssim"] for r in group]), "ssim_face": _mean([r["ssim_face"] for r in group]),
                "sharpness": metrics.median_sharpness(np.array([r["sharpness"] for r in group])),
                "sharpness_face": metrics.median_sharpness(np.array([r["sharpness_face"] for r in group])),
                "idsim": _mean([r["idsim"] for r in group]),
                "nmke": _mean([r["nmke"] for r in group]), "no_face": sum(r["no_face"] for r in group),
                **_expression_correlations(group),
                "lpips": _mean([r["lpips"] for r in group]) if "lpips" in group[0] else None,
                "fid": fid[(name, k)].value if (name, k) in fid else None,
                "fid_samples": fid[(name, k)].samples_first if (name, k) in fid else None,
            })
            bucket = {"method": name, "k": k}
            for label in BUCKETS:
                members = [r for r in group if r.get("bucket") == label]
                bucket[label] = _mean([r["idsim"] for r in members])
                bucket[f"{label}_frames"] = len(members)
            bucket_rows.append(bucket)
    return {
        "rows": rows,
        "buckets": bucket_rows,
        "cross": cross.summarise_cross(run.cross_records, run.settings["methods"], run.settings["ks"]),
        "parts_self": parts.summarise_self(run.records, run.settings["methods"], run.settings["ks"]),
        "parts_cross": parts.summarise_cross(run.cross_records, run.settings["methods"], run.settings["ks"]),
        "thresholds": {str(k): list(v) for k, v in run.thresholds.items()},
        "counts": run.counts,
        "settings": run.settings,
        "lpips": backbones.get("lpips", NOT_COMPUTED),
        "fid": backbones.get("fid", NOT_COMPUTED),
        "conventions": {
            "psnr": "uint8 RGB, peak 255; 'PSNR' = mean over frames with finite PSNR, 'inf' = identical frames "
                    "(excluded from that mean), 'PSNR(mean MSE)' = PSNR of the MSE averaged over all frames",
            "face region": f"PSNR face / SSIM face: inside the convex hull of the ground truth's 68 landmarks dilated "
                           f"by {metrics.FACE_DILATION:g} x its inter-ocular distance; PSNR of the MSE over those pixels "
                           "(mean over frames with finite PSNR), SSIM = mean of the whole-frame SSIM map over them",
            "ssim": f"kornia.metrics.ssim, {metrics.SSIM_WINDOW}x{metrics.SSIM_WINDOW} Gaussian window, sigma "
                    f"{metrics.SSIM_SIGMA}, reflect padding, RGB in [0, 1], mean over pixels and channels",
            "sharpness": f"per frame var(Laplacian(grey output)) / var(Laplacian(grey ground truth)) (cv2 RGB2GRAY, "
                         f"cv2.Laplacian CV_64F ksize {metrics.LAPLACIAN_KSIZE}); median over frames, frames whose ground "
                         "truth has zero variance ignored. 1 = as sharp as the real frame, < 1 blurrier (averaging "
                         "baselines, regression to the mean), > 1 sharper or noisier; 'sharpness face': the same ratio "
                         "of the variances over the face region (the background a blend leaves soft does not count)",
            "idsim": f"cosine similarity, {idsim.EMBEDDER_NAME}; outputs without a detected face are aligned with "
                     "the ground-truth landmarks. dlib's embeddings are compressed towards 1: its same-person "
                     "threshold (distance 0.6 between unit vectors) is cosine 0.82",
            "nmke": "mean distance of the 68 detected landmarks (output vs ground truth) / ground-truth eye-centre "
                    "distance (points 36-41, 42-47); mean over outputs with a detected face, the rest counted in 'no face'",
            "expression": "self re-enactment's mouth / eye corr: per identity, the Pearson correlation of the ground "
                          "truth's mouth / eye opening (its stored landmarks) with the output's detected one, over its "
                          "hold-outs with a detected face, then the mean over identities: the cross-identity table's "
                          "measure where the right answer is known",
            "buckets": "pose distance = raw-landmark NMKE between the nearest source shot and the target (the single "
                       "shot at K = 1), split at the thresholds given above the bucket table",
            "cross": cross.CONVENTION,
            "parts": parts.CONVENTION,
        },
    }


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        if math.isnan(value):
            return "n/a"
        if math.isinf(value):
            return "inf"
        return f"{value:.{digits}f}"
    return str(value)


CROSS_COLUMNS = ("method", "K", "frames", "mouth corr ↑", "mouth gain →1", "eye corr ↑", "eye gain →1",
                 "yaw / pitch / roll err ° ↓", "NMKE ↓", "ID-SIM to source ↑", "sharpness (face) →1", "scene PSNR ↑",
                 "scene flicker ↓", "no face")


def _scene_psnr(row: dict[str, Any]) -> str:
    """Mean of the finite scene PSNRs with the bit-identical frames counted; 'inf' when every frame is identical."""
    infinite = row["scene_psnr_infinite"]
    if infinite and infinite == row["frames"]:
        return "inf"
    return _fmt(row["scene_psnr"], 2) + (f" (+{infinite} inf)" if infinite else "")


def markdown(summary: dict[str, Any], machine: str) -> str:
    """The report as markdown (the same text is printed by ``lsr eval``)."""
    settings = summary["settings"]
    lines = [
        "# lsr eval: thesis §4.4 protocol",
        "",
        f"data: `{shown_path(settings.get('data', '?'))}` ({len(settings['identities'])} identities: {', '.join(settings['identities'])}); "
        f"K = {settings['ks']}; seed {settings['seed']}; hold-outs per identity: {settings['max_holdouts'] or 'all'}",
        "",
        "## Self re-enactment (hold-out frames)",
        "",
        "| method | K | frames | PSNR ↑ | inf | PSNR(mean MSE) | PSNR face ↑ | SSIM ↑ | SSIM face ↑ | sharpness →1 | "
        "sharpness face →1 | ID-SIM ↑ | NMKE ↓ | mouth corr ↑ | eye corr ↑ | no face | LPIPS ↓ | FID ↓ |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in summary["rows"]:
        lines.append(
            f"| {row['method']} | {row['k']} | {row['frames']} | {_fmt(row['psnr'], 2)} | {row['psnr_infinite']} | "
            f"{_fmt(row['psnr_of_mean_mse'], 2)} | {_fmt(row['psnr_face'], 2)} | {_fmt(row['ssim'])} | "
            f"{_fmt(row['ssim_face'])} | {_fmt(row['sharpness'], 2)} | {_fmt(row['sharpness_face'], 2)} | "
            f"{_fmt(row['idsim'])} | {_fmt(row['nmke'])} | {_fmt(row['mouth_corr'], 2)} | {_fmt(row['eye_corr'], 2)} | "
            f"{row['no_face']} | {_fmt(row['lpips'])} | {_fmt(row['fid'], 2)} |"
        )
    lines += ["", f"LPIPS: {summary['lpips']}.", "", f"FID: {summary['fid']}.", "",
              "## Thesis Table 4.4 (reference; VoxCeleb2, 50 ids, ID-SIM from VGGFace: compare trends, not absolute ID-SIM)", "",
              "| method | K | fine-tuned | PSNR ↑ | SSIM ↑ | sharpness →1 | LPIPS ↓ | ID-SIM ↑ | NMKE ↓ | FID ↓ |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    shown_ks = set(settings["ks"])
    for (method, k, tuned), values in THESIS_TABLE_4_4.items():
        if k in shown_ks:
            shown = (*values[:2], None, *values[2:])  # the thesis reports no sharpness
            cells = " | ".join(_fmt(v, 2 if i == 0 or i == 6 else 3) for i, v in enumerate(shown))
            lines.append(f"| {method} | {k} | {'yes' if tuned else 'no'} | {cells} |")
    lines += ["", "## ID-SIM per pose-variance bucket (thesis §4.5.1)", ""]
    lines.append("thresholds (pose distance, " + settings["bucket_thresholds"] + "): "
                 + "; ".join(f"K={k}: low < {_fmt(t[0])} <= medium < {_fmt(t[1])} <= high" for k, t in summary["thresholds"].items()))
    lines += ["", "| method | K | low | medium | high | frames (l/m/h) |", "|---|---|---|---|---|---|"]
    for row in summary["buckets"]:
        lines.append(f"| {row['method']} | {row['k']} | {_fmt(row['low'])} | {_fmt(row['medium'])} | {_fmt(row['high'])} | "
                     f"{row['low_frames']}/{row['medium_frames']}/{row['high_frames']} |")
    if summary["cross"]:
        retarget = {"3d": "retargeted in 3D where there are meshes", "2d": "retargeted in 2D"}.get(
            settings.get("retarget", "2d"), "retargeted")
        lines += ["", f"## Cross-identity re-enactment (thesis §4.4.3; {retarget}, composited into the anchor shot)", "",
                  "| " + " | ".join(CROSS_COLUMNS) + " |", "|" + "---|" * len(CROSS_COLUMNS)]
        for row in summary["cross"]:
            angles = " / ".join(_fmt(row[f"{angle}_error"], 1) for angle in ("yaw", "pitch", "roll"))
            lines.append(f"| {row['method']} | {row['k']} | {row['frames']} | {_fmt(row['mouth_corr'], 2)} | "
                         f"{_fmt(row['mouth_gain'], 2)} | {_fmt(row['eye_corr'], 2)} | {_fmt(row['eye_gain'], 2)} | "
                         f"{angles} | {_fmt(row['nmke'])} | "
                         f"{_fmt(row['idsim_source'])} | {_fmt(row['sharpness_face'], 2)} | {_scene_psnr(row)} | "
                         f"{_fmt(row['scene_flicker'], 2)} | {row['no_face']} |")
    lines += parts.markdown(summary.get("parts_self", []), summary.get("parts_cross", []), _fmt)
    warp = summary["counts"].get("warp_methods", {})
    if warp:
        lines += ["", "## TPS warp methods used (warps: one per frame for tps and mesh, up to 3 for tps_mean3 and "
                  "mesh_mean3; for mesh warps the TPS outside the face, 'no mesh': warped by the TPS alone)", "",
                  "| method | run | tps | tps_stronger | similarity | identity | no mesh |", "|---|---|---|---|---|---|---|"]
        for name, table in warp.items():
            for run_name, used in table.items():
                lines.append(f"| {name} | {run_name} | {used.get('tps', 0)} | {used.get('tps_stronger', 0)} | "
                             f"{used.get('similarity', 0)} | {used.get('identity', 0)} | {used.get('without_mesh', '–')} |")
    skipped = {k: v for k, v in summary["counts"]["holdouts_without_face"].items() if v}
    no_input = {k: v for k, v in summary["counts"]["inputs_without_face"].items() if v}
    lines += ["", "## Notes", ""]
    lines.append(f"- hold-out frames without a ground-truth face (cannot be driven, skipped): {skipped or 'none'}")
    lines.append(f"- input frames without a face (never drawn as shots): {no_input or 'none'}")
    others = summary["counts"].get("inputs_of_another_person", {})
    lines.append(f"- input frames showing another person (dlib face descriptor farther than "
                 f"{SAME_PERSON_RADIUS:g} from the person's; never drawn as shots, as lsr reenact leaves them out): "
                 f"{others or 'none'}")
    for name, why in summary["counts"].get("skipped_methods", {}).items():
        lines.append(f"- {name}: skipped, {why}")
    without_meshes = summary["counts"].get("skipped_without_meshes", {})
    for name, runs in without_meshes.items():
        lines.append(f"- {name}: skipped where the data has no face meshes ({len(runs)} of the (K, identity) runs)")
    if "judge_boxed" in summary["counts"]:
        lines.append(f"- images where dlib's detector found no face and the judge's shape predictor used the primary "
                     f"detector's box: {summary['counts']['judge_boxed']}")
    if settings.get("shot_choice") == "cover":
        lines.append("- shots: chosen to cover each person's mouth, eyes, pose and gaze (lsr.core.inputs.choose_shots, "
                     "as lsr reenact chooses them), not drawn at random")
    elif settings.get("shot_choice") == "spread":
        lines.append("- shots: spread evenly over each person's input frames in time, not drawn at random")
    capped = summary["counts"].get("k_capped")
    if capped:
        lines.append(f"- K larger than the input frames with a face (all of them used instead): {capped}")
    lines += [f"- {name}: {text}" for name, text in summary["conventions"].items()]
    lines += ["", machine, ""]
    return "\n".join(lines)


def write_report(out_dir: Path, summary: dict[str, Any], text: str) -> tuple[Path, Path]:
    """Atomically write OUT/eval_report.md and OUT/eval_report.json; returns both paths."""
    from landmarks.io.image_files import atomic_output, write_json

    out_dir = Path(out_dir)
    markdown_path, json_path = out_dir / "eval_report.md", out_dir / "eval_report.json"
    write_json(json_path, json_safe(summary))
    with atomic_output(markdown_path) as temp:
        temp.write_text(text)
    return markdown_path, json_path


def json_safe(value: Any) -> Any:
    """NaN / inf -> strings (strict JSON has neither)."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return json_safe(value.item())
    return value


class ExampleWriter:
    """``on_outputs`` callback: per (method, K, identity), the first ``count`` outputs above their ground truth
    (OUT/examples/<method>_k<K>_<identity>.png); it also keeps each first frame for ``comparison``."""

    def __init__(self, out_dir: Path, count: int) -> None:
        self.out_dir, self.count = Path(out_dir), count
        self.first: dict[tuple[str, int, str], tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, name: str, k: int, identity: EvalIdentity, outputs: np.ndarray, targets: np.ndarray) -> None:
        from landmarks.io.image_files import write_image

        if not len(outputs):
            return
        self.first[(name, k, identity.name)] = (outputs[0], targets[0])
        if self.count <= 0:
            return
        strip = np.concatenate([np.concatenate(list(outputs[: self.count]), axis=1),
                                np.concatenate(list(targets[: self.count]), axis=1)], axis=0)
        write_image(self.out_dir / "examples" / f"{name}_k{k}_{identity.name}.png", strip)  # top: output, bottom: truth

    def comparison(self, k: int) -> np.ndarray:
        """One row per identity (its first hold-out frame), one column per method in run order, then the ground
        truth; method names above the columns. (rows * S + title, columns * S, 3) uint8."""
        methods = list(dict.fromkeys(name for name, at_k, _ in self.first if at_k == k))
        identities = list(dict.fromkeys(who for _, at_k, who in self.first if at_k == k))
        if not methods:
            raise ConfigError(f"no outputs at K={k} to compare; pick a K that was evaluated")
        rows = []
        for who in identities:
            cells = [self.first[(name, k, who)][0] for name in methods]
            rows.append(np.concatenate([*cells, self.first[(methods[0], k, who)][1]], axis=1))
        return np.concatenate([title_strip([*methods, "ground truth"], rows[0].shape[0]), *rows], axis=0)


def _label(image: np.ndarray, text: str, origin: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """Draw ``text`` in place, scaled down to fit 0.9 of the image width (at most scale 0.5)."""
    import cv2

    width = image.shape[1]
    scale = min(0.5, 0.9 * width / max(1, cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 1.0, 1)[0][0]))
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def title_strip(labels: Sequence[str], side: int) -> np.ndarray:
    """A white strip naming figure columns of width ``side``: (28, len(labels) * side, 3) uint8."""
    title = np.full((28, side * len(labels), 3), 255, np.uint8)
    for column, label in enumerate(labels):
        cell = title[:, column * side : (column + 1) * side]  # a view: drawing on it draws on the strip
        _label(cell, label, (4, 19), (0, 0, 0))
    return title


CROSS_FIGURE_SKIPS = ("nearest_shot",)  # a copy of a shot: no re-enactment to look at
CROSS_FIGURE_SIDE = 176  # panel side: 5 people x 5 moments stay a picture, not a poster


class CrossFigure:
    """``on_cross_outputs`` callback that keeps, at K = ``k``, what the cross-identity figure shows (``picture``):
    per driven identity up to 5 driver frames (``lsr.eval.cross.figure_frames``: widest mouth, "O", blink, glance
    aside, head turn), the source's anchor shot and each method's composited frame at those times."""

    def __init__(self, k: int) -> None:
        self.k = k
        # identity -> {"frames": [(why, index)], "anchor", "by" (driver name), "driver": (F, S', S', 3),
        #              "methods": {name: (F, S, S, 3)}}
        self.rows: dict[str, dict[str, Any]] = {}

    def __call__(self, name: str, sequence: cross.CrossSequence, composited: np.ndarray) -> None:
        if sequence.k != self.k:
            return
        if sequence.identity not in self.rows:
            picks = cross.figure_frames(sequence.driver_landmarks, sequence.driver_frames.shape[1:3],
                                        gazes(sequence.driver_frames, sequence.driver_landmarks))
            self.rows[sequence.identity] = {"frames": picks, "anchor": sequence.anchor_shot, "by": sequence.driver,
                                            "driver": sequence.driver_frames[[i for _, i in picks]], "methods": {}}
        row = self.rows[sequence.identity]
        if row["by"] == sequence.driver:  # --cross-drivers N: the figure shows each identity's first driver
            row["methods"][name] = composited[[i for _, i in row["frames"]]]

    def picture(self) -> np.ndarray:
        """Rows: per identity, per chosen frame; columns: driver frame (labelled with why it was chosen) | source
        anchor | each method's composited output, in run order. (28 + rows * S, (2 + methods) * S, 3) uint8."""
        import cv2

        if not self.rows:
            raise ConfigError(f"no cross-identity drive at K={self.k}: it needs >= 2 identities and --cross-identity")
        methods = [name for name in dict.fromkeys(name for row in self.rows.values() for name in row["methods"])
                   if name not in CROSS_FIGURE_SKIPS and not name.endswith("+ft")]  # copies and near-duplicates
        side = next(iter(self.rows.values()))["anchor"].shape[0]
        lines = []
        for who, row in self.rows.items():
            for index, (why, _) in enumerate(row["frames"]):
                driver = row["driver"][index]
                if driver.shape[:2] != (side, side):
                    driver = cv2.resize(driver, (side, side), interpolation=cv2.INTER_AREA)
                driver = driver.copy()
                _label(driver, f"{why}: {row['by']} -> {who}", (4, side - 8), (255, 255, 0))
                blank = np.zeros_like(row["anchor"])
                cells = [driver, row["anchor"], *(row["methods"][name][index] if name in row["methods"] else blank
                                                  for name in methods)]
                cells = [cv2.resize(c, (CROSS_FIGURE_SIDE,) * 2, interpolation=cv2.INTER_AREA) if side > CROSS_FIGURE_SIDE
                         else c for c in cells]
                lines.append(np.concatenate(cells, axis=1))
        shown = min(side, CROSS_FIGURE_SIDE)
        return np.concatenate([title_strip(["driver", "source (anchor)", *methods], shown), *lines], axis=0)


def cross_figure_path(figure: Path) -> Path:
    """Where ``--figure F`` puts the cross-identity figure: beside F, named ``<F's stem>_cross<F's suffix>``."""
    figure = Path(figure)
    return figure.with_name(f"{figure.stem}_cross{figure.suffix}")


def _fid_collector(weights: Path, device: str, then: Any) -> tuple[dict[tuple[str, int], tuple[list, list]], Any]:
    """An ``on_outputs`` callback that stores FID features of outputs and targets per (method, K), then calls ``then``.
    Ground-truth features are computed once per distinct target set (they repeat for every method and K)."""
    from lsr.eval.fid import image_features, load_feature_extractor
    from lsr.eval.analysis import FaceAnalysis

    extractor = load_feature_extractor(weights, device=device)
    collected: dict[tuple[str, int], tuple[list, list]] = {}
    target_cache: dict[bytes, np.ndarray] = {}

    def collect(name: str, k: int, identity: EvalIdentity, outputs: np.ndarray, targets: np.ndarray) -> None:
        if len(outputs):
            key = FaceAnalysis.key(np.ascontiguousarray(targets))
            if key not in target_cache:
                target_cache[key] = image_features(extractor, targets)
            outputs_list, targets_list = collected.setdefault((name, k), ([], []))
            outputs_list.append(image_features(extractor, outputs))
            targets_list.append(target_cache[key])
        then(name, k, identity, outputs, targets)

    return collected, collect


def label_by_variant(models: Sequence[Any], folders: Sequence[Any]) -> list[Any]:
    """Name each model method "lsr:<variant>" (thesis Table 4.2 rows); variants given twice get "@<folder>" too."""
    variants = [model.variant for model in models]
    for model, folder, variant in zip(models, folders, variants, strict=True):
        model.name = f"lsr:{variant}" if variants.count(variant) == 1 else f"lsr:{variant}@{folder}"
    return list(models)


def run_eval(cfg: EvalConfig) -> dict[str, Any]:
    """Run ``lsr eval`` (cfg: lsr.config.EvalConfig): load, evaluate the baselines, write and print the report."""
    from landmarks.detect.registry import make_detector
    from lsr.eval.baselines import MeshMean3, MeshWarp, NearestShot, TpsMean3, TpsWarp
    from lsr.eval.analysis import FaceAnalysis
    from lsr.eval.protocol import (takes_meshes, attach_meshes, detect_layout, gives_meshes,
                                   load_fsth_sample, load_lsr_split, run_protocol)
    from lsr.eval.machine import machine_markdown

    data = cfg.resolved_data()
    detector = make_detector(cfg.detector, **({"upsample": cfg.detector_upsample} if cfg.detector != "mesh" else {}))
    layout = detect_layout(data)
    if layout == "fsth":
        identities = load_fsth_sample(data, detector, cache_dir=Path(cfg.out) / "cache", progress=cfg.progress)
    else:
        identities = load_lsr_split(data, cfg.split, cfg.inputs, cfg.holdouts)
    if cfg.max_identities:
        identities = identities[: cfg.max_identities]
    available = {"nearest_shot": NearestShot, "tps": lambda: TpsWarp(regularization=cfg.tps_regularization),
                 "tps_mean3": lambda: TpsMean3(regularization=cfg.tps_regularization),
                 "mesh": lambda: MeshWarp(regularization=cfg.tps_regularization),
                 "mesh_mean3": lambda: MeshMean3(regularization=cfg.tps_regularization)}
    methods = [available[name]() for name in cfg.methods]
    skipped = {}
    if not gives_meshes(detector):  # dlib's detectors give 68 points only: the mesh baselines cannot run
        skipped = {m.name: f"needs face meshes, which the {cfg.detector} detector does not give (use --detector mesh)"
                   for m in methods if getattr(m, "needs_meshes", False)}
        methods = [m for m in methods if m.name not in skipped]
        for name, why in skipped.items():
            print(f"lsr eval: {name} skipped: {why}")
    if cfg.weights:
        from lsr.eval.model_method import LsrModelMethod

        choice = {"reference_warp": cfg.reference_warps[0], "mouth": cfg.mouths[0] if cfg.mouths else None,
                  "eyes": cfg.eyes[0] if cfg.eyes else None,
                  "mouth_interior": cfg.mouth_interiors[0] if cfg.mouth_interiors else None,
                  "lids": cfg.lids[0] if cfg.lids else None,
                  "expression_gain": cfg.expression_gains[0] if cfg.expression_gains else None,
                  "bank": cfg.banks[0] if cfg.banks else None}
        models = [LsrModelMethod(folder, device=cfg.device, finetune_steps=cfg.finetune_steps,
                                 finetune_lr=cfg.finetune_lr, **choice) for folder in cfg.weights]
        methods += label_by_variant(models, cfg.weights)
        # the same models with their references warped another way, another mouth, eyes or interior, in the same run
        extras = [({**choice, "reference_warp": warp}, f"+{warp}-refs") for warp in cfg.reference_warps[1:]]
        extras += [({**choice, "mouth": other}, f"+{other}-mouth") for other in cfg.mouths[1:]]
        extras += [({**choice, "eyes": other}, f"+{other}-eyes") for other in cfg.eyes[1:]]
        extras += [({**choice, "mouth_interior": other}, f"+{other}-interior") for other in cfg.mouth_interiors[1:]]
        extras += [({**choice, "lids": other}, f"+{other}-lids") for other in cfg.lids[1:]]
        extras += [({**choice, "expression_gain": other}, f"+gain{other:g}") for other in cfg.expression_gains[1:]]
        extras += [({**choice, "bank": other}, f"+{other}-bank") for other in cfg.banks[1:]]
        for options, suffix in extras:
            for model in models:
                if model.reenactor.warp_references:
                    methods.append(LsrModelMethod(model.weights, device=cfg.device, finetune_steps=cfg.finetune_steps,
                                                  finetune_lr=cfg.finetune_lr, name=f"{model.name}{suffix}", **options))
    retargets_meshes = cfg.cross_identity and cfg.retarget == "3d"  # the drivers' and anchors' meshes move the 68 points
    if gives_meshes(detector) and layout != "fsth" and (retargets_meshes or any(takes_meshes(m) for m in methods)):
        attach_meshes(identities, detector, cache_dir=Path(cfg.out) / "cache", progress=cfg.progress)
    if not methods:
        raise ConfigError("no method to evaluate: pass --methods nearest_shot tps tps_mean3 (mesh, mesh_mean3 with "
                          "--detector mesh) and/or --weights MODEL_DIR")
    thresholds = tuple(cfg.bucket_thresholds) if cfg.bucket_thresholds else None
    examples = ExampleWriter(Path(cfg.out), cfg.examples)
    cross_figure = CrossFigure(cfg.figure_k) if cfg.figure is not None and cfg.cross_identity else None
    frame_metrics, backbones, on_outputs = {}, {}, examples
    if cfg.lpips_weights is not None:
        from lsr.eval.lpips import load_lpips, lpips_distance

        lpips_model = load_lpips(cfg.lpips_weights, device=cfg.device)
        frame_metrics["lpips"] = lambda outputs, targets: lpips_distance(lpips_model, outputs, targets)
        backbones["lpips"] = f"AlexNet LPIPS v0.1 from {cfg.lpips_weights}; inputs uint8 RGB -> [-1, 1], mean over hold-out frames"
    if cfg.fid_weights is not None:
        fid_features, on_outputs = _fid_collector(cfg.fid_weights, cfg.device, on_outputs)
    run = run_protocol(methods, identities, cfg.k, FaceAnalysis(detector), seed=cfg.seed, max_holdouts=cfg.max_holdouts,
                       fixed_thresholds=thresholds, cross_identity=cfg.cross_identity, on_outputs=on_outputs,
                       on_cross_outputs=cross_figure, frame_metrics=frame_metrics, progress=cfg.progress,
                       retarget=cfg.retarget, cross_drivers=cfg.cross_drivers, shot_choice=cfg.shot_choice,
                       judge=cfg.judge)
    if skipped:
        run.counts["skipped_methods"] = skipped
    fid_results = {}
    if cfg.fid_weights is not None:
        from lsr.eval.fid import fid_from_features

        for key, (outputs, targets) in fid_features.items():
            fid_results[key] = fid_from_features(np.concatenate(outputs), np.concatenate(targets))
        dims = {r.dims for r in fid_results.values()}
        eps = {r.eps for r in fid_results.values() if r.eps}
        backbones["fid"] = (f"features from {cfg.fid_weights} (D = {', '.join(map(str, sorted(dims)))}), outputs vs ground "
                            f"truth over all hold-out frames per (method, K); samples per row in the JSON 'fid_samples'"
                            + (f"; N <= D, so {min(eps):g} was added to the covariance diagonals (values are not "
                               "comparable to 50k-sample FIDs)" if eps else ""))
    run.settings.update({"data": str(data), "layout": layout, "detector": detector.settings,
                         "tps_regularization": cfg.tps_regularization, "retarget": cfg.retarget})
    summary = summarise(run, fid=fid_results, backbones=backbones)
    if cfg.figure is not None:
        from landmarks.io.image_files import write_image

        write_image(cfg.figure, examples.comparison(cfg.figure_k))
        print(f"comparison figure (K={cfg.figure_k}: one hold-out frame per identity, methods side by side) written to {cfg.figure}")
        if cross_figure is not None and cross_figure.rows:
            path = cross_figure_path(cfg.figure)
            write_image(path, cross_figure.picture())
            print(f"cross-identity figure (K={cfg.figure_k}: driver | source anchor | composited outputs; widest mouth, "
                  f"'O', blink, glance aside and head turn per identity) written to {path}")
    text = markdown(summary, machine_markdown())
    markdown_path, json_path = write_report(Path(cfg.out), summary, text)
    print(text)
    print(f"report written to {markdown_path} and {json_path}")
    if cfg.out_md is not None:
        print(f"section eval:{cfg.section} written to {write_section(cfg, text)}")
    return summary


def write_section(cfg: EvalConfig, text: str) -> Path:
    """Put the report ``text`` into ``cfg.out_md`` between ``<!-- eval:SECTION:start/end -->`` with its command."""
    from lsr.eval.sections import command_line, write_section as write

    body = text.split("\n", 1)[1] if text.startswith("# ") else text  # the report's own title becomes the heading
    body = body.replace("\n## ", "\n### ")
    title = cfg.title or f"Evaluation on {cfg.resolved_data().name} (`lsr eval`)"
    return write(Path(cfg.out_md), cfg.section, title, command_line(cfg, "lsr eval"), body, cfg.note)
