"""`lsr bench landmarks`: the still-stretch finder and NME on made-up tracks, config errors, and a tiny run of the whole
bench on a synthetic clip (both trackers, every table, the BENCHMARKS.md section)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from landmarks.motion.head_pose import project_canonical
from lsr.config import BenchLandmarksConfig
from lsr.errors import ConfigError
from lsr.bench import bench_landmarks

FACE = project_canonical(0.0, 0.0, 0.0, (256, 256))  # (68, 2) a frontal face, inter-ocular distance ~44 px
IOD = float(np.linalg.norm(FACE[42:48].mean(0) - FACE[36:42].mean(0)))


def _sequence(shifts: np.ndarray, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    """(N, 68, 2): FACE translated by shifts (N, 2) in inter-ocular units, plus per-point noise (same units)."""
    rng = np.random.default_rng(seed)
    jitter = rng.normal(0.0, noise, (len(shifts), 68, 2))
    return (FACE[None] + (shifts[:, None, :] + jitter) * IOD).astype(np.float32)


def test_still_stretches_find_the_still_frames_only():
    # At rest on frames 0-19, 39-69 (frame 55 missing) and 75-80 (too short); moving 0.1 IOD per frame between them.
    rest = [(0, 20), (39, 70), (75, 81)]
    step = np.full(90, 0.1)
    for start, stop in rest:
        step[start + 1 : stop] = 0.0  # no motion into a resting frame after the first
    x = np.cumsum(step) - step[0]
    landmarks = _sequence(np.stack([x, np.zeros_like(x)], axis=1), noise=0.001)
    landmarks[55] = np.nan
    stretches = bench_landmarks.still_stretches(landmarks)
    # The centred 5-frame average sees a motion 2 frames early and 2 late: 2 resting frames next to a move are not
    # still, which leaves 2 frames of the last rest (< 8).
    assert stretches == [(0, 18), (41, 55), (56, 68)]
    still = np.zeros(90, bool)
    for start, stop in stretches:
        still[start:stop] = True
    expected = np.zeros(90, bool)
    for start, stop in rest[:2]:
        expected[start + (2 if start else 0) : stop - 2] = True
    expected[55] = False
    assert (still == expected).all()


def test_stretch_jitter_measures_rigid_motion_in_inter_ocular_units():
    reference = _sequence(np.zeros((20, 2)))
    shaky = reference.copy()
    shaky[1::2] += np.float32(0.02 * IOD)  # every other frame 0.02 IOD right (and down): steps of 0.02 * sqrt(2)
    steps = bench_landmarks.stretch_jitter(shaky, reference, [(0, 10), (12, 20)])
    assert steps.shape == (9 + 7,)
    assert np.allclose(steps, 0.02 * np.sqrt(2), rtol=1e-4)
    assert np.allclose(bench_landmarks.stretch_jitter(reference, reference, [(0, 20)]), 0.0)


def test_nme_per_frame_jaw_and_inner():
    reference = _sequence(np.zeros((3, 2)))
    points = reference.copy()
    points[0, 0:17] += np.float32([0.1 * IOD, 0.0])  # the jaw off by 0.1 IOD
    points[1] += np.float32([0.0, 0.05 * IOD])  # everything off by 0.05 IOD
    points[2] = np.nan  # missing
    errors = bench_landmarks.nme(points, reference)
    assert errors[0] == pytest.approx(0.1 * 17 / 68, rel=1e-4) and errors[1] == pytest.approx(0.05, rel=1e-4)
    assert np.isnan(errors[2])
    assert bench_landmarks.nme(points, reference, bench_landmarks.JAW)[0] == pytest.approx(0.1, rel=1e-4)
    assert bench_landmarks.nme(points, reference, bench_landmarks.INNER)[0] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match="68, 2"):
        bench_landmarks.nme(points[:, :10], reference[:, :10])


@pytest.mark.parametrize("options, message", [
    ({"clip_frames": 1}, "--clip-frames"),
    ({"size": 32}, "--size"),
    ({"video": "no/such/video.mp4"}, "--video"),
    ({"clips": ("no/such/clip.mp4",)}, "--clips"),
])
def test_config_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        BenchLandmarksConfig(**options).validate()


def test_no_video_and_no_clips_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("LSR_SHARED_DATA", str(tmp_path))
    with pytest.raises(ConfigError, match="pass --video PATH"):
        bench_landmarks.run_bench_landmarks(BenchLandmarksConfig())


def _cells(table: str, first: str, tracker: str | None = None) -> list[str]:
    """The cells of the table row whose first cell is ``first`` (and second ``tracker``)."""
    for line in table.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if cells[0] == first and (tracker is None or cells[1] == tracker):
            return cells
    raise AssertionError(f"no row {first!r} {tracker!r} in\n{table}")


@pytest.fixture(scope="module")
def synthetic_clip(tmp_path_factory):
    from landmarks.io.video import VideoWriter
    from lsr.data.synth import render_video

    path = tmp_path_factory.mktemp("bench_landmarks") / "synth.mp4"
    with VideoWriter(path, 25.0) as writer:
        for frame in render_video(3, 10, 256).frames:
            writer.write(frame)
    return path


def test_bench_runs_both_trackers_on_a_synthetic_clip(synthetic_clip, tmp_path, capsys):
    out_md = tmp_path / "BENCHMARKS.md"
    cfg = BenchLandmarksConfig(video=synthetic_clip, clips=(synthetic_clip,), frames=4, size=256, clip_frames=10,
                               out_md=out_md)
    cfg.validate()
    table = bench_landmarks.run_bench_landmarks(cfg)
    assert table in capsys.readouterr().out
    for label in bench_landmarks.TRACKER_LABELS.values():
        tracking = _cells(table, label, "tracking (detection on loss only)")
        assert float(tracking[2]) > 0 and "detections" in tracking[5]
        assert _cells(table, label, "full detection " + ("(BlazeFace + mesh), every frame" if "mesh" in label
                                                          else "(HOG + shape predictor), every frame"))
    assert _cells(table, "mesh (MediaPipe)", "mesh net only (in the tracked region)")
    assert _cells(table, "dlib (HOG)", "shape predictor only (in the tracked box)")

    header = _cells(table, "clip")
    row = dict(zip(header, _cells(table, "**all clips**")))
    assert row["frames"] == "10"
    assert re.fullmatch(r"\d+\.\d %", row["mesh detected"]) and re.fullmatch(r"\d+\.\d %", row["dlib detected"])
    assert float(row["mesh detected"].rstrip(" %")) >= 90 and float(row["dlib detected"].rstrip(" %")) >= 90
    for column in ("NME", "NME jaw 0-16", "NME inner 17-67"):
        assert 0 < float(row[column]) < 0.5, column  # the synthetic face is not a real one: loose, but finite
    assert int(row["gross > 0.25"]) <= int(row["both"]) <= 10
    if int(row["frontal frames"]):
        assert 0 < float(row["NME frontal"]) < 0.5 and 0 < float(row["NME frontal w/o gross"]) < 0.5
    assert "still stretches of the real clips" in table and "static face" in table
    for label in bench_landmarks.TRACKER_LABELS.values():
        static = _cells(table, "static face, one frame x50 with pixel noise sigma 4", label)
        assert np.isfinite(float(static[3])) and np.isfinite(float(static[4]))
    assert "Goals: the tracker <= 10 ms" in table and "<= 0.05 of the inter-ocular distance" in table
    assert "| cores |" in table  # machine info

    written = out_md.read_text()
    assert "<!-- eval:landmarks:start -->" in written and "<!-- eval:landmarks:end -->" in written
    assert "lsr bench landmarks --video" in written and table.splitlines()[-1] in written


def test_bench_without_clips_says_so(synthetic_clip, tmp_path, monkeypatch):
    monkeypatch.setenv("LSR_SHARED_DATA", str(tmp_path))  # no shared clips
    table = bench_landmarks.run_bench_landmarks(BenchLandmarksConfig(video=synthetic_clip, frames=2, size=128))
    assert "Note: no real clips" in table and "**all clips**" not in table
    assert "static face" in table
