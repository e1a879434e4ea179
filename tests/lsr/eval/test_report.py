"""End-to-end report generation on tiny runs (lsr.eval.report)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from lsr.config import EvalConfig
from lsr.errors import ConfigError
from lsr.eval import report
from lsr.eval.baselines import NearestShot, TpsMean3, TpsWarp
from lsr.eval.protocol import FaceAnalysis, load_lsr_split, run_protocol


def test_report_on_synthetic_identities(tmp_path, no_face_detector):
    from lsr.data.synth.generate import generate_dataset

    root = tmp_path / "synth"
    generate_dataset(root, identities=4, videos_per_identity=1, frames=10, size=64, test_fraction=0.5, progress=False)
    identities = load_lsr_split(root, "test", inputs=6, holdouts=4)
    assert len(identities) == 2 and all(len(i.input_frames) == 6 and len(i.holdout_frames) == 4 for i in identities)
    cross_figure = report.CrossFigure(1)
    run = run_protocol([NearestShot(), TpsWarp(), TpsMean3()], identities, [1], FaceAnalysis(no_face_detector()),
                       on_cross_outputs=cross_figure, progress=False)
    run.settings["data"] = str(root)
    summary = report.summarise(run)
    text = report.markdown(summary, "| machine | |")
    markdown_path, json_path = report.write_report(tmp_path / "out", summary, text)
    written = markdown_path.read_text()
    assert "| tps | 1 | 8 |" in written and "| tps_mean3 | 1 | 8 |" in written
    header = next(line for line in written.splitlines() if line.startswith("| method | K | frames | PSNR"))
    assert "| PSNR face ↑ | SSIM ↑ | SSIM face ↑ | sharpness →1 | sharpness face →1 | ID-SIM" in header
    cross_header = ("| method | K | frames | mouth corr ↑ | mouth gain →1 | eye corr ↑ | eye gain →1 | yaw / pitch / roll err ° ↓ | "
                    "NMKE ↓ | ID-SIM to source ↑ | sharpness (face) →1 | scene PSNR ↑ | scene flicker ↓ | no face |")
    assert cross_header in written.splitlines()
    # the fake detector finds (almost) no face: no expression to correlate; the scene is measured all the same
    assert "| tps | 1 | 8 | n/a | n/a | n/a | " in written and "| inf | 0.00 |" in written
    assert "| FSTH | 1 | no | 16.80 | 0.570 | – | 0.259 |" in written  # the thesis table has the column, empty
    stored = json.loads(json_path.read_text())
    rows = {row["method"]: row for row in stored["rows"]}
    assert set(rows) == {"nearest_shot", "tps", "tps_mean3"}
    no_face = {name: row["no_face"] for name, row in rows.items()}
    assert no_face == {"nearest_shot": 0, "tps": 8, "tps_mean3": 8}  # copies of inputs reuse their landmarks; warps meet the fake detector
    sharpness = {name: row["sharpness"] for name, row in rows.items()}
    assert all(isinstance(value, float) and value > 0 for value in sharpness.values())
    assert sharpness["tps_mean3"] == sharpness["tps"]  # K = 1: the mean of one warped shot is that shot
    per_frame = [r["sharpness"] for r in run.records if r["method"] == "tps"]
    assert sharpness["tps"] == pytest.approx(float(np.median(per_frame)))
    per_frame_face = [r["sharpness_face"] for r in run.records if r["method"] == "tps"]
    assert rows["tps"]["sharpness_face"] == pytest.approx(float(np.median(per_frame_face)))
    assert rows["tps_mean3"]["sharpness_face"] == rows["tps"]["sharpness_face"] > 0
    assert "'sharpness face'" in stored["conventions"]["sharpness"]
    assert "median" in stored["conventions"]["sharpness"] and "- sharpness: " in written
    assert "not computed" in stored["lpips"]
    assert all(np.isfinite(row["psnr_face"]) and 0 < row["ssim_face"] <= 1 for row in stored["rows"])
    crossed = {row["method"]: row for row in stored["cross"]}
    assert set(crossed) == {"nearest_shot", "tps", "tps_mean3"} and crossed["tps"]["sequences"] == 2
    for row in crossed.values():  # every composite leaves the scene outside the head regions untouched
        assert row["scene_psnr_infinite"] == row["frames"] == 8 and row["scene_flicker"] == 0.0
    assert "retargeted" in stored["conventions"]["cross"] and "- face region: " in written
    # the cross-identity figure: per identity up to 4 driver frames; driver | anchor | tps, tps_mean3 (no copies)
    picture = cross_figure.picture()
    rows = sum(len(row["frames"]) for row in cross_figure.rows.values())
    assert 2 <= rows <= 8 and picture.shape == (28 + rows * 64, 4 * 64, 3)
    assert report.cross_figure_path(tmp_path / "compare.png") == tmp_path / "compare_cross.png"
    for name in ("tps", "tps_mean3"):
        warp = stored["counts"]["warp_methods"][name]["K=1 self"]
        assert sum(warp.values()) == 8
    # --out-md: the report becomes a named section of a markdown file; other sections survive re-runs.
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\nintro\n\n<!-- bench:speed:start -->\nspeed\n<!-- bench:speed:end -->\n")
    cfg = EvalConfig(data=root, out_md=md, section="synthetic", k=(1,), note="a note")
    report.write_section(cfg, text)
    report.write_section(cfg, text.replace("| tps | 1 | 8 |", "| tps | 1 | 9 |"))
    written = md.read_text()
    assert written.count("<!-- eval:synthetic:start -->") == 1 and "| tps | 1 | 9 |" in written
    assert "intro" in written and "<!-- bench:speed:start -->\nspeed" in written and "**Note:** a note" in written
    assert f"lsr eval --data {root}" in written and "--k 1" in written and "--section synthetic" in written


@pytest.mark.slow
def test_lsr_eval_on_two_real_identities(shared_data, tmp_path, capsys):
    source = shared_data / "fsth_eval_sample"
    if not source.is_dir():
        pytest.skip("fsth_eval_sample not in the shared data")
    small = tmp_path / "fsth"
    for split in ("train", "test"):  # 4 inputs + 4 hold-outs of 2 identities keep detection cheap
        for identity in sorted((source / split).iterdir())[:2]:
            for frame in sorted(identity.glob("*/combined/*_rgb.png"))[:4]:
                target = small / frame.relative_to(source)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(frame, target)
    cfg = EvalConfig(data=small, out=tmp_path / "out", k=(1,), max_holdouts=4, progress=False, examples=2,
                     figure=tmp_path / "compare.png", figure_k=1)
    cfg.validate()
    summary = report.run_eval(cfg)
    printed = capsys.readouterr().out
    assert "## Self re-enactment" in printed and "| machine |" in printed
    assert (tmp_path / "out" / "eval_report.md").is_file()
    rows = {row["method"]: row for row in summary["rows"]}
    assert set(rows) == {"nearest_shot", "tps", "tps_mean3", "mesh", "mesh_mean3"}  # the default methods
    assert all(np.isfinite(row["ssim"]) and 0 < row["ssim"] < 1 for row in rows.values())
    assert all(np.isfinite(row["sharpness"]) and row["sharpness"] > 0 for row in rows.values())
    assert rows["tps"]["nmke"] < rows["nearest_shot"]["nmke"]  # warping onto the target landmarks fixes the pose
    assert list((tmp_path / "out" / "examples").glob("tps_k1_*.png"))
    from landmarks.io.image_files import read_image

    figure = read_image(tmp_path / "compare.png")  # 2 identities x (5 methods + ground truth), under a title strip
    assert figure.shape == (28 + 2 * 224, 6 * 224, 3)
    crossed = read_image(tmp_path / "compare_cross.png")  # driver | anchor | 4 methods at 176 px, <= 4 rows per identity
    side = report.CROSS_FIGURE_SIDE
    assert crossed.shape[1] == 6 * side and (crossed.shape[0] - 28) % side == 0
    assert {row["method"] for row in summary["cross"]} == {"nearest_shot", "tps", "tps_mean3", "mesh", "mesh_mean3"}
    assert summary["counts"]["warp_methods"]["mesh"]["K=1 self"]["without_mesh"] == 0  # the mesh detector: meshes
    with pytest.raises(ConfigError, match="--figure-k"):
        EvalConfig(data=small, k=(1,), figure=tmp_path / "x.png", figure_k=8).validate()


def test_tables_show_paths_relative_to_the_repository_or_home(tmp_path):
    from lsr.eval.machine import REPO_ROOT, shown_path

    assert shown_path(REPO_ROOT / "lsr" / "weights" / "default") == "lsr/weights/default"
    assert shown_path(REPO_ROOT.parent / "shared" / "data" / "x") == "../shared/data/x"
    home, repo = tmp_path / "home", tmp_path / "work" / "repo"
    assert shown_path(home / ".cache" / "lsr" / "split", root=repo, home=home) == "~/.cache/lsr/split"
    assert shown_path(tmp_path / "elsewhere", root=repo, home=home) == str(tmp_path / "elsewhere")
