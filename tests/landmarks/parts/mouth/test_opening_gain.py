"""landmarks.parts.mouth.opening_gain: a shot's mouth carried further where the target opens it wider."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.parts.mouth import opening_gain as expression_gain
from landmarks.warp import piecewise_affine as mesh_warp
from landmarks.shape.expression import CLOSED_MOUTH, mouth_opening
from landmarks.shape.mesh68 import mesh_to_68
from landmarks.motion.mesh_rotation import canonical

SIZE = 128


def _mesh(scale: float = 0.6, centre: tuple[float, float] = (64.0, 60.0), turn: float = 0.0) -> np.ndarray:
    """(468, 3) float64: the canonical mesh turned by ``turn`` degrees about the vertical axis and placed in a
    SIZE x SIZE frame."""
    vertices = canonical()[0] - canonical()[0].mean(0)
    angle = np.radians(turn)
    rotation = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    return vertices @ rotation.T * scale + np.array([*centre, 0.0])


def _opened(mesh: np.ndarray, amount: float) -> np.ndarray:
    """``mesh`` with its jaw dropped by ``amount`` pixels: the vertices below the inner lips' centre that are not
    rigid (``landmarks.motion.mesh_rotation``'s, which a talking face moves least), weighted by the mouth region."""
    moved = mesh.copy()
    moved[:, 1] += amount * _jaw(mesh) * expression_gain.mouth_weights()
    return moved


def _jaw(mesh: np.ndarray) -> np.ndarray:
    """(468,) bool: the non-rigid vertices below the inner lips' centre."""
    return (mesh[:, 1] > mesh_to_68(mesh)[60:68, 1].mean()) & ~canonical()[1]


def test_the_mouth_region_is_around_the_lips_and_leaves_the_eyes():
    weights = expression_gain.mouth_weights()
    points = mesh_to_68(canonical()[0][:, :2])
    nearest_lip = np.argmin(np.linalg.norm(canonical()[0][:, :2] - points[62], axis=1))
    assert weights.shape == (468,) and weights.min() == 0.0 and weights.max() == 1.0
    assert weights[nearest_lip] == 1.0
    assert weights[[33, 263, 133, 362]].max() == 0.0  # the eyes' corners do not move ...
    assert weights[1] < 0.5  # ... and the nose tip little


def test_the_gain_grows_with_how_much_wider_the_target_opens():
    shot = mesh_to_68(_mesh())
    assert mouth_opening(_opened_68 := mesh_to_68(_opened(_mesh(), 6.0))) > mouth_opening(shot) + CLOSED_MOUTH
    assert expression_gain.mouth_gain(shot, _opened_68, 1.5) == pytest.approx(1.5)
    assert expression_gain.mouth_gain(_opened_68, shot, 1.5) == 1.0  # a closing mouth is warped as measured
    assert expression_gain.mouth_gain(shot, shot, 1.5) == 1.0
    half = mesh_to_68(_opened(_mesh(), 1.0))
    excess = (mouth_opening(half) - mouth_opening(shot)) / CLOSED_MOUTH
    assert 0 < excess < 1
    assert expression_gain.mouth_gain(shot, half, 1.5) == pytest.approx(1 + 0.5 * excess)
    assert expression_gain.mouth_gain(np.full((68, 2), np.nan), shot, 1.5) == 1.0


class TestAmplify:
    def test_a_gain_of_one_or_a_missing_mesh_leaves_the_shot(self):
        shot, target = _mesh(), _opened(_mesh(), 5.0)
        np.testing.assert_array_equal(expression_gain.amplify_mouth(shot, target, 1.0), shot)
        missing = np.full((468, 3), np.nan)
        np.testing.assert_array_equal(expression_gain.amplify_mouth(shot, missing, 1.5), shot)

    def test_a_head_motion_is_not_expression(self):
        """The same face turned, scaled and moved: nothing to amplify."""
        shot, target = _mesh(), _mesh(scale=0.7, centre=(70.0, 58.0), turn=20.0)
        np.testing.assert_allclose(expression_gain.amplify_mouth(shot, target, 1.5), shot, atol=1e-6)

    @pytest.mark.parametrize("turn", [0.0, 25.0])
    def test_the_mouth_moves_back_by_the_extra_gain(self, turn):
        """The warp shot -> target then carries the lips gain times as far: the shot's vertices move back by
        (gain - 1) times the jaw drop, in the shot's own head frame, and the vertices outside the mouth stay."""
        shot = _mesh(turn=turn)
        target = _opened(_mesh(scale=0.65, centre=(60.0, 62.0)), 6.0)
        moved = expression_gain.amplify_mouth(shot, target, 1.5)
        # the target's jaw drop as seen on the shot's head: 6 px down at the target's scale, at the shot's scale
        weights = expression_gain.mouth_weights()
        drop = 6.0 * (0.6 / 0.65) * weights * _jaw(_mesh())
        np.testing.assert_allclose(moved[:, 1], shot[:, 1] - 0.5 * weights * drop, atol=1e-6)
        np.testing.assert_allclose(moved[:, 0], shot[:, 0], atol=1e-6)
        still = expression_gain.mouth_weights() == 0
        np.testing.assert_allclose(moved[still], shot[still], atol=1e-6)


def test_references_open_the_mouth_wider_only_where_the_target_opens_it(rng):
    """warp_references_mesh with a gain: the warped shot differs around the mouth only, and only when the target
    opens its mouth wider than the shot."""
    image = rng.integers(0, 256, (SIZE // 4, SIZE // 4, 3), dtype=np.uint8).repeat(4, 0).repeat(4, 1)
    shots, meshes = image[None], _mesh()[None]
    landmarks = mesh_to_68(meshes).astype(np.float64)
    opened = _opened(_mesh(), 6.0)

    def warped(target: np.ndarray, gain: float) -> np.ndarray:
        images, _, _ = mesh_warp.warp_references_mesh(shots, meshes, landmarks, target, mesh_to_68(target), 1,
                                                      expression_gain=gain)
        return images[0].astype(np.int16)

    difference = np.abs(warped(opened, 1.5) - warped(opened, 1.0)).max(axis=-1)
    lips = mesh_to_68(opened)[48:68]
    mouth_box = np.zeros((SIZE, SIZE), bool)
    x0, y0 = np.floor(lips.min(0) - 12).astype(int)
    x1, y1 = np.ceil(lips.max(0) + 12).astype(int)
    mouth_box[max(y0, 0):y1, max(x0, 0):x1] = True
    assert difference[mouth_box].max() > 50  # the texture moved there
    assert difference[~mouth_box].max() <= 2  # sub-pixel resampling where the mesh and the TPS are feathered
    brows = int(mesh_to_68(opened)[17:27, 1].min())
    assert difference[:brows].max() == 0
    closing = _mesh()  # the opened shot's mouth closes onto this target: warped as measured
    np.testing.assert_array_equal(warped(closing, 1.5), warped(closing, 1.0))
