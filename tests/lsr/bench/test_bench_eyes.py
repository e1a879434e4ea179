"""lsr bench eyes (lsr.bench.bench_eyes): the realism floor, the per-pair rows, the table, and the command's checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from landmarks.parts.eyes.eye_realism import REALISM_PATCH, eye_realism
from lsr.config.bench_options import BenchEyesConfig
from lsr.errors import ConfigError
from lsr.bench import bench_eyes
from lsr.bench.bench_eyes import FLOOR_GAP, eyes_markdown, mouth_roundness, own_scale, pair_rows, realism_floor

PIXELS = REALISM_PATCH[0] * REALISM_PATCH[1]


def _eyes(rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` distinct frames' eyes as ``realism_patches`` gives them: (count, 2, P), each row zero-mean, unit-norm
    (random ones: any two correlate near 0, so their distance is near 1)."""
    eyes = rng.standard_normal((count, 2, PIXELS)).astype(np.float32)
    eyes -= eyes.mean(axis=-1, keepdims=True)
    return eyes / np.linalg.norm(eyes, axis=-1, keepdims=True)


# ---- the realism floor -------------------------------------------------------------------------------------------


def test_the_floor_leaves_out_a_frames_neighbours_which_are_near_copies_of_it(rng):
    # a still stretch: each frame shown three times running, closer together than FLOOR_GAP
    assert FLOOR_GAP > 3
    real = np.repeat(_eyes(rng, 4), 3, axis=0)  # (12, 2, P)
    np.testing.assert_allclose(eye_realism(real, real), 0.0, atol=1e-5)  # compared with itself and its copies
    floor = realism_floor(real)
    assert floor.shape == (12, 2) and np.isfinite(floor).all()
    assert (floor > 0.8).all()  # only other stretches' eyes are left to compare with


def test_the_floor_compares_a_frame_with_those_exactly_gap_frames_away_and_not_nearer(rng):
    real = _eyes(rng, 10)
    real[1 + FLOOR_GAP] = real[1]  # a copy exactly FLOOR_GAP frames on: compared
    real[3 + FLOOR_GAP - 1] = real[3]  # a copy one frame nearer: left out
    floor = realism_floor(real)
    np.testing.assert_allclose(floor[[1, 1 + FLOOR_GAP]], 0.0, atol=1e-5)
    assert (floor[[3, 3 + FLOOR_GAP - 1]] > 0.8).all()
    nearer = realism_floor(real, gap=FLOOR_GAP - 1)  # a smaller gap reaches that copy
    np.testing.assert_allclose(nearer[[1, 1 + FLOOR_GAP, 3, 3 + FLOOR_GAP - 1]], 0.0, atol=1e-5)


def test_a_frame_without_a_face_has_no_floor_and_is_no_neighbour(rng):
    real = np.repeat(_eyes(rng, 3), 2, axis=0)  # (6, 2, P)
    real[3] = np.nan  # no face in frame 3 (source_eyes' NaN rows)
    floor = realism_floor(real, gap=2)
    assert np.isnan(floor[3]).all() and np.isfinite(np.delete(floor, 3, axis=0)).all()


# ---- one pair's rows ---------------------------------------------------------------------------------------------


def _driver(frames: int = 8) -> dict[str, np.ndarray]:
    """The driver read by the judge and by the mesh: the mesh reads its eyes at half the judge's, its mouth the
    other way round, its gaze as the judge."""
    eye = np.linspace(0.1, 0.3, frames)
    mouth = np.array([0.0, 0.2, 0.05, 0.3, 0.1, 0.25, 0.15, 0.35])[:frames]
    gaze = np.sin(np.arange(frames))
    return {"judge_eye": eye, "mesh_eye": 0.5 * eye + 0.02, "judge_mouth": mouth, "mesh_mouth": 1.0 - mouth,
            "judge_gaze": gaze, "mesh_gaze": 3.0 * gaze - 1.0}


def test_pair_rows_give_the_detectors_agreement_and_each_banks_correlation_and_gain_against_the_driver():
    driver = _driver()
    eye, mouth, gaze = driver["judge_eye"], driver["judge_mouth"], driver["judge_gaze"]
    realism = np.array([[0.1, 0.2], [0.3, np.nan]] + [[np.nan, np.nan]] * 6)
    twice = {"judge_eye": 2.0 * eye - 0.1, "judge_mouth": np.where(np.arange(8) == 2, np.nan, -0.5 * mouth),
             "judge_gaze": gaze, "realism": realism, "switches": 3, "ms_per_frame": 12.5,
             "asked_eye": 3.0 * eye, "asked_mouth": 0.5 * mouth + 0.1}
    frozen = {"judge_eye": np.full(8, 0.2), "judge_mouth": mouth, "judge_gaze": -gaze,
              "realism": np.full((8, 2), np.nan)}
    rows = pair_rows("a ← b", driver, {"all": twice, "none": frozen}, floor=0.04)
    assert [(row["pair"], row["row"]) for row in rows] == [("a ← b", "agreement"), ("a ← b", "asked"),
                                                           ("a ← b", "all"), ("a ← b", "none")]
    agreement, asked, banked, plain = rows
    # what the target's own points asked, against the judge's reading of the driver (the first bank's targets)
    assert asked["eye_r"] == pytest.approx(1.0) and asked["eye_gain"] == pytest.approx(3.0)
    assert asked["mouth_r"] == pytest.approx(1.0) and asked["mouth_gain"] == pytest.approx(0.5)
    assert all(math.isnan(asked[name]) for name in ("gaze_r", "realism", "switches", "ms_per_frame", "eye_jitter"))
    # no source frames given: its own jitter unknown
    assert math.isnan(agreement["own_eye_jitter"]) and math.isnan(agreement["own_mouth_jitter"])
    assert agreement["eye_r"] == pytest.approx(1.0) and agreement["eye_gain"] == pytest.approx(0.5)  # the mesh's
    assert agreement["mouth_r"] == pytest.approx(-1.0) and agreement["mouth_gain"] == pytest.approx(-1.0)
    assert agreement["gaze_r"] == pytest.approx(1.0)
    assert agreement["realism"] == 0.04 and math.isnan(agreement["switches"]) and math.isnan(agreement["ms_per_frame"])
    assert banked["eye_r"] == pytest.approx(1.0) and banked["eye_gain"] == pytest.approx(2.0)  # output = 2 driver
    # on each face's own scale: output 2 eye - 0.1 over its median 0.3, the driver's eye over its 0.2
    assert banked["eye_own_gain"] == pytest.approx(2.0 * 0.2 / 0.3)
    assert asked["eye_own_gain"] == pytest.approx(1.0)  # 3 eye is the driver's, in proportion
    assert agreement["eye_own_gain"] == pytest.approx(0.5 * 0.2 / 0.12)  # the mesh's 0.5 eye + 0.02, median 0.12
    # a frame without the judge's face is left out of both figures, not read as 0
    assert banked["mouth_r"] == pytest.approx(-1.0) and banked["mouth_gain"] == pytest.approx(-0.5)
    assert banked["gaze_r"] == pytest.approx(1.0)
    assert banked["realism"] == pytest.approx(0.2)  # the median of every eye found, over eyes and frames
    assert banked["switches"] == 3.0 and banked["ms_per_frame"] == 12.5
    assert math.isnan(plain["eye_r"]) and math.isnan(plain["eye_gain"])  # a frozen eye has no correlation
    assert math.isnan(plain["eye_own_gain"])
    assert plain["mouth_r"] == pytest.approx(1.0) and plain["mouth_gain"] == pytest.approx(1.0)
    assert plain["gaze_r"] == pytest.approx(-1.0)
    # no eyes read; no bank, no switches; not timed
    assert math.isnan(plain["realism"]) and math.isnan(plain["switches"]) and math.isnan(plain["ms_per_frame"])


def test_own_scale_divides_by_the_median_keeps_gaps_and_gives_nan_without_an_opening():
    assert np.allclose(own_scale(np.array([0.1, 0.2, np.nan, 0.3])), [0.5, 1.0, np.nan, 1.5], equal_nan=True)
    assert np.isnan(own_scale(np.array([0.0, 0.0, 0.1]))).all()
    assert np.isnan(own_scale(np.full(3, np.nan))).all()


def test_mouth_roundness_reads_an_o_above_a_wide_open_mouth_and_nothing_in_a_shut_one():
    from landmarks.motion.head_pose import project_canonical

    def face(height: float, width: float) -> np.ndarray:
        points = project_canonical(0, 0, 0, (256, 256), scale=0.5).astype(np.float64)
        centre = points[60:68].mean(axis=0)
        angles = np.linspace(np.pi, -np.pi, 8, endpoint=False)  # 60 left, 61-63 upper, 64 right, 65-67 lower
        points[60:68] = centre + np.stack([width / 2 * np.cos(angles), -height / 2 * np.sin(angles)], axis=1)
        return points

    round_, wide, shut = mouth_roundness(np.stack([face(30.0, 30.0), face(20.0, 50.0), face(0.0, 50.0)]))
    assert round_ > wide > 0.3 and np.isnan(shut)
    assert np.isnan(mouth_roundness(np.full((1, 68, 2), np.nan))).all()


def test_the_agreement_row_carries_how_steady_the_judge_reads_the_source_s_own_frames():
    from landmarks.motion.smooth import part_jitter

    rng = np.random.default_rng(0)
    base = rng.uniform(20, 80, (68, 2))
    still = np.repeat(base[None], 6, axis=0)
    blinking = still.copy()
    blinking[1::2, 36:48, 1] += 1.5  # the eyes alone jump every other frame
    rows = pair_rows("a ← b", _driver(6), {}, floor=0.04, source_points=blinking)
    assert rows[0]["own_eye_jitter"] == pytest.approx(part_jitter(blinking, slice(36, 48)))
    assert rows[0]["own_eye_jitter"] > 0.01
    assert rows[0]["own_mouth_jitter"] == pytest.approx(part_jitter(blinking, slice(48, 68)))
    assert rows[0]["own_mouth_jitter"] < rows[0]["own_eye_jitter"] / 2
    assert pair_rows("a ← b", _driver(6), {}, floor=0.04, source_points=still)[0]["own_eye_jitter"] == pytest.approx(
        0.0, abs=1e-9)


# ---- the table ---------------------------------------------------------------------------------------------------


def _row(pair, name, realism, switches=math.nan, **values):
    cells = dict.fromkeys(("eye_r", "eye_gain", "mouth_r", "mouth_gain", "gaze_r"), 0.5)
    return {"pair": pair, "row": name, **cells, **values, "realism": realism, "switches": switches}  # no speed: blank


def test_the_table_prints_each_pairs_agreement_then_each_bank_with_its_share_of_it():
    rows = [_row("a ← b", "agreement", 0.04, eye_r=0.8, eye_gain=0.5, mouth_r=math.nan, eye_jitter=0.02,
                 own_eye_jitter=0.04),
            _row("a ← b", "none", 0.1, eye_r=0.4, eye_gain=1.0),
            _row("a ← b", "all", 0.05, switches=3.0, eye_r=0.6, eye_gain=0.25, ms_per_frame=41.6, eye_jitter=0.03),
            _row("b ← a", "agreement", 0.02, eye_r=0.2),
            _row("b ← a", "all", 0.05, switches=0.0, eye_r=0.6)]
    settings = {"clips": "a.mp4 and 1 more", "k": 8, "weights": "weights/tiny", "frames": "10-12"}
    text = eyes_markdown(rows, settings, "machine: test box")
    lines = text.splitlines()
    assert lines[0] == "clips: a.mp4 and 1 more; K = 8; model `weights/tiny`; judged frames per driver: 10-12"
    assert ("| pair | eyes from | eye r | eye gain | eye gain, own opening | mouth r | mouth gain | gaze r | realism ↓ "
            "(x floor) | switches | ms / frame | eye jitter (x driver, x own) | mouth jitter (x driver, x own) |") in lines
    table = [line for line in lines if line.startswith("| ") and "pair |" not in line]
    assert table == [
        "| a ← b | agreement / floor | 0.80 | 0.50 | nan | nan | 0.50 | 0.50 | 0.040 | | | 0.0200 (own 0.0400) | nan |",
        # in brackets: the share of the agreement (gains: their ratio), realism over the floor; no agreement, no share
        "| | none | 0.40 (0.50) | 1.00 (2.00) | – | 0.50 | 0.50 (1.00) | 0.50 (1.00) | 0.100 (2.50) |  |  | – | – |",
        # jitter: over the driver's, then over the source's own
        "| | all | 0.60 (0.75) | 0.25 (0.50) | – | 0.50 | 0.50 (1.00) | 0.50 (1.00) | 0.050 (1.25) | 3 | 42 | 0.0300 (1.50, 0.75) "
        "| – |",
        "| b ← a | agreement / floor | 0.20 | 0.50 | nan | 0.50 | 0.50 | 0.50 | 0.020 | | | nan | nan |",
        "| | all | 0.60 (3.00) | 0.50 (1.00) | – | 0.50 (1.00) | 0.50 (1.00) | 0.50 (1.00) | 0.050 (2.50) | 0 |  | – | – |",
    ]
    assert f"at least {FLOOR_GAP} frames away" in text and lines[-1] == "machine: test box"


# ---- the command's checks ----------------------------------------------------------------------------------------


@pytest.fixture
def two_clips(tmp_path):
    clips = (tmp_path / "a.mp4", tmp_path / "b.mp4")
    for clip in clips:
        clip.write_bytes(b"")  # validate only looks for the files
    return clips


def test_two_existing_clips_and_the_defaults_validate(two_clips):
    BenchEyesConfig(clips=two_clips).validate()


def test_fewer_than_two_clips_is_refused(two_clips, tmp_path, monkeypatch):
    with pytest.raises(ConfigError, match="--clips needs at least two videos"):
        BenchEyesConfig(clips=two_clips[:1]).validate()
    monkeypatch.setenv("LSR_SHARED_DATA", str(tmp_path / "nothing"))  # no shared expressive set to default to
    with pytest.raises(ConfigError, match="at least two videos.*the shared expressive set, was not found"):
        BenchEyesConfig().validate()


def test_a_missing_clip_is_named(two_clips, tmp_path):
    missing = tmp_path / "gone.mp4"
    with pytest.raises(ConfigError, match=r"--clips: no such file: \S*gone\.mp4$"):
        BenchEyesConfig(clips=(*two_clips, missing)).validate()


@pytest.mark.parametrize("changes, message", [
    ({"k": 0}, r"--k must be in 1\.\.32, got 0"), ({"k": 33}, r"--k must be in 1\.\.32, got 33"),
    ({"banks": ()}, "at least one --banks"), ({"max_frames": -1}, "--max-frames and --threads >= 0"),
    ({"threads": -2}, "--max-frames and --threads >= 0")])
def test_k_banks_frames_and_threads_out_of_range_are_refused(two_clips, changes, message):
    with pytest.raises(ConfigError, match=message):
        BenchEyesConfig(clips=two_clips, **changes).validate()


@pytest.mark.parametrize("name", ["", "expressive set", "a-b", "../x"])
def test_a_set_name_that_is_not_a_section_name_is_refused(two_clips, name):
    with pytest.raises(ConfigError, match=f"--set-name must be letters, digits and _, got {name!r}"):
        BenchEyesConfig(clips=two_clips, set_name=name).validate()
    BenchEyesConfig(clips=two_clips, set_name="real_15").validate()


def test_a_missing_weights_folder_is_refused(two_clips, tmp_path):
    with pytest.raises(ConfigError, match="--weights .* is not a folder"):
        BenchEyesConfig(clips=two_clips, weights=tmp_path / "nope").validate()


def test_the_command_reports_a_bad_config_in_one_line_and_exits_2(two_clips, capsys):
    from lsr.cli import main

    assert main(["bench", "eyes", "--clips", str(two_clips[0]), "--no-progress"]) == 2
    assert "lsr: error: --clips needs at least two videos" in capsys.readouterr().err


# ---- end to end ----------------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_command_drives_each_clip_by_the_next_and_prints_a_row_per_bank(tmp_path, capsys):
    import torch

    from landmarks.io.video import VideoWriter
    from lsr.data.synth import render_video
    from models_def import LSRModel, preset_config

    clips = []
    for seed in (31, 32):
        clips.append(tmp_path / f"person{seed}.mp4")
        with VideoWriter(clips[-1], 25) as writer:
            for frame in render_video(seed, 8, 256).frames:
                writer.write(frame)
    torch.manual_seed(0)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "w")
    cfg = BenchEyesConfig(clips=tuple(clips), weights=weights, k=2, banks=("none", "all", "all+mouth"), threads=1,
                          set_name="synthetic", out_md=tmp_path / "BENCH.md", figure=tmp_path / "eyes.png",
                          progress=False)
    cfg.validate()
    threads = torch.get_num_threads()
    try:
        rows = bench_eyes.run_bench_eyes(cfg)
    finally:
        torch.set_num_threads(threads)
    assert [(row["pair"], row["row"]) for row in rows] == [
        (pair, name) for pair in ("person31 ← person32", "person32 ← person31")
        for name in ("agreement", "asked", "none", "all", "all+mouth")]
    for row in rows:
        if row["row"] == "asked":  # the target's points: openings only
            assert math.isfinite(row["mouth_gain"]) and math.isnan(row["realism"])
            continue
        assert math.isfinite(row["realism"])  # the floor; each output's eyes against the source's real ones
        assert math.isfinite(row["switches"]) == (row["row"] in ("all", "all+mouth"))
        assert math.isfinite(row["ms_per_frame"]) == (row["row"] != "agreement")
    printed = capsys.readouterr().out
    assert printed.count("agreement / floor") == 2 and "| | all+mouth |" in printed
    section = (tmp_path / "BENCH.md").read_text()
    assert "<!-- eval:eyes_synthetic:start -->" in section and "lsr bench eyes" in section
    from landmarks.io.image_files import read_image

    figure = read_image(tmp_path / "eyes.png")  # driver | each bank, the hardest eye moments (one row each)
    assert figure.shape[1] == 256 * 4 and figure.shape[0] >= 256


def test_part_jitter_reads_a_part_moving_on_its_own_not_the_head():
    from landmarks.motion.head_pose import project_canonical
    from landmarks.motion.smooth import part_jitter

    face = project_canonical(0.0, 0.0, 0.0, (256, 256)).astype(np.float64)
    moving_head = np.stack([face + [3.0 * t, 0.0] for t in range(6)])  # the whole face slides: no part moves alone
    assert part_jitter(moving_head, slice(36, 48)) == pytest.approx(0.0, abs=1e-12)
    popping = moving_head.copy()
    popping[::2, 36:48, 1] += 2.0  # the eyes jump up and down every frame
    assert part_jitter(popping, slice(36, 48)) > 0.01 > part_jitter(popping, slice(48, 68))
    popping[3] = np.nan  # frames without a face break the pairs around them, nothing more
    assert np.isfinite(part_jitter(popping, slice(36, 48)))
    assert np.isnan(part_jitter(np.full((3, 68, 2), np.nan), slice(36, 48)))
