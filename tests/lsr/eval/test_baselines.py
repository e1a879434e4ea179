"""The no-learning baselines (lsr.eval.baselines): the nearest-shot choice and tps_mean3."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape import measures
from landmarks.warp import tps
from landmarks.motion.head_pose import project_canonical
from lsr.eval import metrics
from lsr.eval.baselines import NearestShot, TpsMean3, TpsWarp, nearest_shot_indices

SIZE = 64


def _face(yaw: float = 0.0, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """(68, 2) float64 landmarks of the canonical face in a SIZE x SIZE frame."""
    return project_canonical(yaw, 0.0, 0.0, (SIZE, SIZE), translation=shift).astype(np.float64)


def _flat_shots(values: list[int]) -> list[np.ndarray]:
    """One flat colour per shot: any warp (borders replicated) keeps it, so the output shows which shots were used."""
    return [np.full((SIZE, SIZE, 3), value, np.uint8) for value in values]


def test_nearest_shot_indices_agree_with_nearest_shots_and_nmke(rng):
    shot_landmarks = np.stack([_face(yaw, (dx, 0.0)) for yaw, dx in rng.uniform([-20, -4], [20, 4], size=(7, 2))])
    shot_landmarks[2] = np.nan  # a shot without a face
    targets = np.stack([_face(yaw) for yaw in rng.uniform(-20, 20, size=5)] + [np.full((68, 2), np.nan)])
    indices, distances = nearest_shot_indices(shot_landmarks, targets)
    assert indices.shape == (6,) and distances.shape == (6,)
    for index, distance, target in zip(indices, distances, targets):
        assert index == measures.nearest_shots(shot_landmarks, target, 1)[0]
        np.testing.assert_equal(distance, measures.landmark_distance(shot_landmarks[index], target))
    # the same choice as the NMKE of lsr.eval.metrics (what the baselines used before)
    by_nmke = np.nan_to_num(metrics.nmke(shot_landmarks[None], targets[:5, None]), nan=np.inf)  # (5, 7)
    np.testing.assert_array_equal(indices[:5], np.argmin(by_nmke, axis=1))
    assert indices[5] == 0 and np.isnan(distances[5])  # a target without landmarks: index 0, distance NaN


class TestTpsMean3:
    def test_single_shot_equals_tps(self, rng):
        shots = [rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8)]
        shot_landmarks = _face(10.0)[None]
        targets = np.stack([_face(-10.0), _face(0.0, (3.0, -2.0))])
        single, mean3 = TpsWarp(), TpsMean3()
        expected = single.reenact(shots, shot_landmarks, targets)
        outputs = mean3.reenact(shots, shot_landmarks, targets)
        assert outputs.shape == (2, SIZE, SIZE, 3) and outputs.dtype == np.uint8
        np.testing.assert_array_equal(outputs, expected)
        assert mean3.warp_counts == single.warp_counts and sum(mean3.warp_counts.values()) == 2

    def test_means_exactly_the_three_nearest_shots(self):
        target = _face()
        offsets = [8.0, 1.0, 30.0, 2.0, 3.0]  # nearest: shots 1, 3, 4
        shot_landmarks = np.stack([target + [offset, 0.0] for offset in offsets])
        method = TpsMean3()
        outputs = method.reenact(_flat_shots([0, 10, 200, 40, 130]), shot_landmarks, np.stack([target, target]))
        assert outputs.shape == (2, SIZE, SIZE, 3) and outputs.dtype == np.uint8
        assert np.all(outputs == 60)  # (10 + 40 + 130) / 3; all five would give 76, the first three by index 70
        assert sum(method.warp_counts.values()) == 2 * 3

    def test_fewer_shots_than_three_are_not_repeated(self):
        target = _face()
        shot_landmarks = np.stack([target + [1.0, 0.0], target + [5.0, 0.0]])
        outputs = TpsMean3().reenact(_flat_shots([10, 40]), shot_landmarks, target[None])
        assert np.all(outputs == 25)  # repeating the nearest would give (10 + 10 + 40) / 3 = 20

    def test_identical_landmarks_give_the_pixel_mean_of_the_first_three(self, rng):
        shots = [rng.integers(0, 256, size=(SIZE, SIZE, 3), dtype=np.uint8) for _ in range(5)]
        landmarks = _face(5.0)
        outputs = TpsMean3().reenact(shots, np.stack([landmarks] * 5), landmarks[None])
        expected = np.rint(np.mean(shots[:3], axis=0))  # equal distances: ties go by index
        assert np.abs(outputs[0].astype(int) - expected).max() <= 1  # each warp is the identity up to remap rounding

    def test_bad_inputs_raise(self):
        with pytest.raises(ValueError):
            TpsMean3().reenact(_flat_shots([10, 20]), _face()[None], _face()[None])  # 2 shots, 1 landmark set


def test_nearest_shot_and_tps_keep_their_outputs():
    target = _face()
    shot_landmarks = np.stack([target + [9.0, 0.0], target + [0.5, 0.0], target + [-5.0, 0.0]])
    shots = _flat_shots([10, 20, 30])
    assert np.all(NearestShot().reenact(shots, shot_landmarks, target[None]) == 20)
    assert np.all(TpsWarp().reenact(shots, shot_landmarks, np.stack([target, target - [4.0, 0.0]]))[1] == 30)
