"""``lsr bench reenact`` times any variant, the warp-guided one included (its synthesis needs the warped shots)."""

from __future__ import annotations

import os

import pytest

pytestmark = pytest.mark.slow


def _weights_and_clip(tmp_path):
    """A tiny random warp-guided model and a 6-frame synthetic clip to time it on."""
    import torch

    from landmarks.io.video import VideoWriter
    from lsr.data.synth import render_video
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "w")
    clip = tmp_path / "clip.mp4"
    with VideoWriter(clip, 25) as writer:
        for frame in render_video(8, 6, 160).frames:
            writer.write(frame)
    return weights, clip


def test_warp_guided_model_is_timed_on_both_runtimes(tmp_path):
    from lsr.config import BenchReenactConfig
    from lsr.bench.bench_reenact import run_bench_reenact

    weights, clip = _weights_and_clip(tmp_path)
    table = run_bench_reenact(BenchReenactConfig(video=clip, weights=weights, frames=4, k=2, threads=1,
                                                 detectors=("mesh", "hog")))
    rows = [line for line in table.splitlines() if line.startswith(("| torch |", "| onnx |")) and line.count("|") > 10]
    assert len(rows) == 4  # each runtime with each detector
    assert [row.split("|")[2].strip() for row in rows] == ["mesh", "hog", "mesh", "hog"]
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        assert cells[2] == "nearest" and cells[3] == "warped"  # the defaults: no mouth generator, warped irises
        assert cells[4] == "driver" and cells[5] == "drawn"  # the driver's mouth interior, the subject's drawn lids
        assert int(cells[6]) == 4 and float(cells[15]) > 0  # frames, end-to-end fps
        assert 0 < float(cells[18]) <= os.cpu_count() + 0.5  # cores busy: the process's CPU time over its wall time
    assert "`" in table.splitlines()[0]  # the model named as given, not a random preset
    default = next(line for line in table.splitlines() if line.startswith("`lsr reenact` as it runs"))
    onnx_fps, torch_fps = (float(row.split("|")[16]) for row in (rows[2], rows[0]))  # the mesh rows
    assert f"{onnx_fps:.2f} fps end to end, {onnx_fps / torch_fps:.2f}x" in default  # onnx, the default, on torch


def test_the_drawn_mouth_and_eyes_are_timed_against_the_path_without_them(tmp_path):
    from lsr.config import BenchReenactConfig
    from lsr.bench.bench_reenact import run_bench_reenact
    from models_def.part_generator import MOUTH_FOLDER, PartGenerator

    weights, clip = _weights_and_clip(tmp_path)
    PartGenerator().save_pretrained(weights / MOUTH_FOLDER)
    table = run_bench_reenact(BenchReenactConfig(video=clip, weights=weights, frames=3, k=2, threads=1,
                                                 mouths=("drawn", "nearest"), eyes=("drawn", "blend"), runtimes=("onnx",),
                                                 mouth_interiors=("driver", "shots")))
    rows = [line for line in table.splitlines() if line.startswith(("| torch |", "| onnx |")) and line.count("|") > 10]
    assert [row.split("|")[3].strip() for row in rows] == ["drawn"] * 4 + ["nearest"] * 4
    assert [row.split("|")[4].strip() for row in rows] == ["drawn", "drawn", "blend", "blend"] * 2
    assert [row.split("|")[5].strip() for row in rows] == ["driver", "shots"] * 4
    assert table.count("the drawn mouth costs") == 1  # one ratio per runtime, from the same run
    assert table.count("drawn eyes run at") == 2  # one per mouth
    assert table.count("the driver's mouth interior runs at") == 4  # one per mouth and eyes


def test_the_shut_lids_are_timed_against_the_path_without_them(tmp_path):
    from lsr.config import BenchReenactConfig
    from lsr.bench.bench_reenact import run_bench_reenact

    weights, clip = _weights_and_clip(tmp_path)
    table = run_bench_reenact(BenchReenactConfig(video=clip, weights=weights, frames=3, k=2, threads=1,
                                                 runtimes=("onnx",), lids=("drawn", "driver", "shots")))
    rows = [line for line in table.splitlines() if line.startswith("| onnx |") and line.count("|") > 10]
    assert [row.split("|")[6].strip() for row in rows] == ["drawn", "driver", "shots"]
    assert table.count("the drawn lids run at") == 1 and table.count("the driver's shut lids run at") == 1


def test_no_flags_times_the_shipped_default():
    from lsr.config import BenchReenactConfig

    cfg = BenchReenactConfig()
    assert cfg.weights is None and cfg.preset is None and cfg.paste_back
