"""lsr bench lids (lsr.bench.bench_lids): the lids asked for, and how far a synthesis is read to follow them."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from lsr.eval import protocol
from lsr.bench import bench_lids

SIZE = 96


@pytest.fixture(scope="module")
def synthetic_identities() -> list[protocol.EvalIdentity]:
    """Two synthetic people (lsr.data.synth), 5 inputs + 3 hold-outs each, with the mesh detector's landmarks and
    meshes (as ``attach_meshes`` gives them)."""
    from landmarks.detect.mediapipe_tracker import MeshDetector
    from lsr.data.synth import render_video

    detector = MeshDetector()
    identities = []
    for seed in (0, 1):
        frames = render_video(seed, 8, SIZE).frames
        landmarks, meshes = protocol.detect_faces(list(frames), detector)
        assert meshes is not None and np.isfinite(meshes[:, 0, 0]).sum() >= 6
        identities.append(protocol.EvalIdentity(f"synth{seed}", frames[:5], landmarks[:5], frames[5:], landmarks[5:],
                                                input_meshes=meshes[:5], holdout_meshes=meshes[5:]))
    return identities


def _found(identity: protocol.EvalIdentity, role: str) -> tuple[np.ndarray, np.ndarray]:
    landmarks, meshes = getattr(identity, f"{role}_landmarks"), getattr(identity, f"{role}_meshes")
    row = int(np.flatnonzero(np.isfinite(landmarks).all(axis=(1, 2)) & np.isfinite(meshes).all(axis=(1, 2)))[0])
    return landmarks[row].astype(np.float64), meshes[row].astype(np.float64)


def test_the_targets_ask_for_each_share_and_move_only_the_upper_lids(synthetic_identities):
    from landmarks.parts.eyes.driver_lids import aperture_share
    from landmarks.parts.eyes.lids import MESH_LIDS, POINTS_68_LIDS, lid_gaps

    shot_points, shot_mesh = _found(synthetic_identities[0], "input")
    points, mesh = _found(synthetic_identities[0], "holdout")
    rest, mesh_rest = lid_gaps(shot_points), lid_gaps(shot_mesh)
    shares = (0.0, 0.5, 1.0, 1.5)
    asked, asked_meshes = bench_lids.lid_targets(points, mesh, rest, mesh_rest, shares)
    assert asked.shape == (4, 68, 2) and asked_meshes.shape == (4, 468, 3)
    np.testing.assert_allclose([aperture_share(p, rest) for p in asked], shares, atol=1e-9)
    np.testing.assert_allclose([aperture_share(m, mesh_rest) for m in asked_meshes], shares, atol=1e-9)
    for moved, original, lids in ((asked, points, POINTS_68_LIDS), (asked_meshes, mesh, MESH_LIDS)):
        upper = sorted({index for eye in lids.eyes for index in eye[2]})
        still = np.setdiff1d(np.arange(len(original)), upper)
        np.testing.assert_array_equal(moved[:, still], np.broadcast_to(original[still], moved[:, still].shape))
    assert np.all(np.diff(asked[:, 37, 1]) < 0)  # the upper lid rises as the share grows (image y points down)


def test_pooled_slope_takes_one_intercept_per_row_and_leaves_out_what_cannot_count():
    x = np.array([[0.0, 1.0, 2.0], [0.0, 1.0, 2.0]])
    y = np.array([[5.0, 5.5, 6.0], [-3.0, -2.5, -2.0]])  # slope 0.5 in both rows, far-apart intercepts
    assert bench_lids.pooled_slope(x, y) == pytest.approx(0.5)
    assert bench_lids.pooled_slope(x, y[:, ::-1]) == pytest.approx(-0.5)
    with_nan = y.copy()
    with_nan[0, 2] = np.nan
    assert bench_lids.pooled_slope(x, with_nan) == pytest.approx(0.5)  # the NaN pair is left out
    assert np.isnan(bench_lids.pooled_slope(np.ones((2, 3)), y))  # nothing varies: no slope
    ragged_x, ragged_y = [np.array([0.0, 2.0]), np.array([1.0])], [np.array([0.0, 4.0]), np.array([9.0])]
    assert bench_lids.pooled_slope(ragged_x, ragged_y) == 2.0  # a row of one pair adds nothing


class _Reenactor:
    warp_references, lids = 4, "drawn"


class _Method:
    """Stands in for ``LsrModelMethod``: each output frame is a blank frame marked by a hash, and what it was asked
    for is kept, so the readers below can give back the landmarks a synthesis would be read at."""

    def __init__(self, follows: float) -> None:
        self.reenactor = _Reenactor()
        self.follows = follows  # 1: draws the lids asked for; 0: keeps the shots' (share 1)
        self.drawn: dict[bytes, np.ndarray] = {}

    def reenact(self, shots, shot_landmarks, target_landmarks, **_):
        from landmarks.parts.eyes.lids import lid_gaps, set_lid_gaps

        rest = lid_gaps(shot_landmarks[0])
        frames = []
        for index, points in enumerate(target_landmarks):
            frame = np.full((SIZE, SIZE, 3), 100, np.uint8)
            frame[0, :8, 0] = np.frombuffer(hashlib.blake2b(points.tobytes() + bytes([index]), digest_size=8).digest(),
                                            np.uint8)
            gaps = rest + self.follows * (lid_gaps(points) - rest)
            self.drawn[frame.tobytes()] = set_lid_gaps(points.astype(np.float64), gaps)
            frames.append(frame)
        return np.stack(frames)


def _sweep(identities, method: _Method, judged: bool = True) -> bench_lids.LidSweep:
    def read(image, fallback):
        return method.drawn.get(image.tobytes())  # the warped shots are not drawn here: not read (NaN)

    def judge(image, fallback):  # reads the drawn lids, or (real frames) the stored points it is given
        return method.drawn.get(image.tobytes(), fallback)

    return bench_lids.sweep(method, identities, k=2, holdouts=2, shares=(0.0, 0.5, 1.0, 1.5), lids=("drawn", "shots"),
                            read=read, judge=judge if judged else None, progress=False)


def test_a_synthesis_that_draws_the_asked_lids_reads_at_slope_one_and_one_that_keeps_them_at_zero(synthetic_identities):
    # the shots' rest is the median of K = 2 shots, the fake keeps the first shot's: exact only where they agree
    identities = [protocol.EvalIdentity(i.name, i.input_frames[[0, 0]], i.input_landmarks[[0, 0]], i.holdout_frames,
                                        i.holdout_landmarks, input_meshes=i.input_meshes[[0, 0]],
                                        holdout_meshes=i.holdout_meshes) for i in synthetic_identities]
    following = _sweep(identities, _Method(1.0))
    keeping = _sweep(identities, _Method(0.0))
    for result, slope in ((following, 1.0), (keeping, 0.0)):
        assert result.output["drawn"].shape == (2, 2, 4) and np.isfinite(result.output["drawn"]).all()
        assert np.isnan(result.reference).all()  # the fake readers do not read the warped shots
        closing, opening = bench_lids._slopes(result, result.output["drawn"])
        assert closing == pytest.approx(slope, abs=1e-6) and opening == pytest.approx(slope, abs=1e-6)
        synthesised, real = bench_lids.judged_ratio(result, "drawn")
        assert real == pytest.approx(1.0)  # real frames: the judge is given the driving detector's points
        assert synthesised == pytest.approx(slope, abs=1e-6)
    np.testing.assert_allclose(following.output["drawn"][0, 0], [0.0, 0.5, 1.0, 1.5], atol=1e-5)  # float32 points
    text = bench_lids.sweep_markdown(following, {"data": "d", "k": 2, "seed": 0, "weights": "w"}, "machine")
    assert "| output, lids drawn | 0.00 | 0.50 | 1.00 | 1.50 | 1.00 | 1.00 |" in text
    assert "| lids shots | 1.00 | 1.00 | 1.00 |" in text
    assert "Judged" not in bench_lids.sweep_markdown(_sweep(identities, _Method(1.0), judged=False),
                                                     {"data": "d", "k": 2, "seed": 0, "weights": "w"}, "machine")


def test_the_real_model_and_detectors_give_a_table_and_a_figure(synthetic_identities, tmp_path):
    from landmarks.detect.registry import make_detector
    from lsr.eval.model_method import LsrModelMethod
    from lsr.weights import resolve_weights

    detector = make_detector("mesh")

    def read(image, fallback):
        found = protocol.detect_faces([image], detector)[0][0]
        return found.astype(np.float64) if np.isfinite(found).all() else None

    result = bench_lids.sweep(LsrModelMethod(resolve_weights(None)), synthetic_identities[:1], k=3, holdouts=1,
                              shares=(0.0, 1.0, 1.5), lids=("drawn",), read=read, judge=None, progress=False)
    assert np.isfinite(result.output["drawn"]).sum() >= 2  # the mesh finds the synthesised faces
    assert len(result.strips["drawn"]) == 1 and result.strips["drawn"][0].dtype == np.uint8
    bench_lids.write_figure(result, tmp_path / "lids.png")
    bench_lids.save_sweep(result, tmp_path / "lids.npz")
    assert (tmp_path / "lids.png").stat().st_size > 0
    np.testing.assert_array_equal(np.load(tmp_path / "lids.npz")["output_drawn"], result.output["drawn"])


def test_the_command_refuses_shares_that_do_not_reach_both_sides_of_the_shots(capsys):
    from lsr.cli import main

    assert main(["bench", "lids", "--shares", "0.2", "0.8"]) == 2
    assert "--shares must reach below 1 and above 1" in capsys.readouterr().err


@pytest.mark.slow
def test_the_command_prints_its_table_and_writes_its_section_figure_and_readings(tmp_path, capsys):
    import torch

    from lsr.config import BenchLidsConfig
    from lsr.data.synth import generate_dataset
    from lsr.bench.bench_lids import run_bench_lids
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    data = tmp_path / "data"
    generate_dataset(data, identities=2, videos_per_identity=1, frames=8, size=SIZE, seed=5, test_fraction=0.5,
                     progress=False)
    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "warp")
    cfg = BenchLidsConfig(weights=weights, data=data, out=tmp_path / "out", k=2, holdouts=1, shares=(0.0, 1.0, 1.5),
                          lids=("drawn",), judge=False, figure=tmp_path / "lids.png", out_md=tmp_path / "BENCH.md",
                          progress=False)
    cfg.validate()
    result = run_bench_lids(cfg)
    assert result.output["drawn"].shape == (1, 1, 3)
    printed = capsys.readouterr().out
    assert "| first warped shot |" in printed and "| output, lids drawn |" in printed
    section = (tmp_path / "BENCH.md").read_text()
    assert "<!-- eval:lids:start -->" in section and "lsr bench lids --weights" in section
    assert "shut (left) to wide (right)](lids.png)" in section  # the figure, linked relative to the section
    assert (tmp_path / "lids.png").is_file() and (tmp_path / "out" / "lids.npz").is_file()
