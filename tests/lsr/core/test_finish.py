"""The mouth drawn by a part generator (lsr.core.finish, the engine's ``mouth = "drawn"``), torch and ONNX."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape.expression import set_mouth_opening
from landmarks.motion.head_pose import project_canonical
from lsr.core.finish import draw_mouth, mouth_inputs
from landmarks.exceptions import InputFileError

SIDE = 256


def _face(opening: float = 0.3) -> np.ndarray:
    return set_mouth_opening(project_canonical(0, 0, 5, (SIDE, SIDE), scale=0.5).astype(np.float64), opening)


def test_draw_mouth_pastes_what_the_generator_draws_around_the_lips_only(rng):
    image = rng.integers(60, 200, (SIDE, SIDE, 3), dtype=np.uint8)
    face = _face()
    seen = {}

    def black(window, masks):
        seen["window"], seen["masks"] = window, masks
        return -np.ones_like(window)

    drawn = draw_mouth(image, face, black)
    assert seen["window"].shape == (1, 3, 80, 80) and seen["masks"].shape == (1, 2, 80, 80)
    assert -1.0 <= seen["window"].min() and seen["window"].max() <= 1.0
    lip = np.round(face[57]).astype(int)
    assert (drawn[lip[1], lip[0]] <= 3).all()  # the lower lip: wholly drawn (black)
    for far in (face[36], face[45], face[8], face[0]):  # eyes, chin, jaw: untouched
        x, y = np.round(far).astype(int)
        assert (drawn[y, x] == image[y, x]).all()


def test_draw_mouth_leaves_a_frame_without_landmarks_alone(rng):
    image = rng.integers(0, 256, (SIDE, SIDE, 3), dtype=np.uint8)
    face = _face()
    face[10] = np.nan
    assert mouth_inputs(image, face) is None
    assert draw_mouth(image, face, lambda w, m: -np.ones_like(w)) is image


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    import torch

    from models_def import LSRModel, preset_config
    from models_def.part_generator import MOUTH_FOLDER, PartGenerator

    torch.manual_seed(0)
    with_mouth = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path_factory.mktemp("w") / "w")
    mouth = PartGenerator()
    torch.nn.init.normal_(mouth.out.weight, std=0.05)  # not the identity: the drawn mouth differs from the blend
    mouth.save_pretrained(with_mouth / MOUTH_FOLDER)
    return with_mouth


def _shots(seed: int = 3, side: int = SIDE):
    from lsr.data.synth import render_video
    from lsr.pipeline import subject_shots_from_training

    video = render_video(seed, 4, side)
    return subject_shots_from_training(video.frames, video.landmarks)


def test_a_model_with_a_mouth_generator_draws_the_mouth_by_default_and_can_be_told_not_to(folders, tmp_path):
    from lsr.pipeline import Reenactor
    from models_def.part_generator import MOUTH_FOLDER

    reenactor = Reenactor(folders, crop_size=SIDE)
    assert reenactor.mouth == "drawn" and reenactor.backend.mouth_generator_size == 80
    reenactor.encode_subject(_shots())
    target = reenactor.subject.shots.landmarks[1]
    drawn = reenactor.synthesize_crop(target)[0]
    reenactor.mouth = "nearest"
    nearest = reenactor.synthesize_crop(target)[0]
    difference = np.abs(drawn.astype(int) - nearest.astype(int)).max(axis=-1)
    assert difference.max() > 0
    ys, xs = np.nonzero(difference)
    assert np.hypot(xs - target[48:60, 0].mean(), ys - target[48:60, 1].mean()).max() < 0.8 * np.ptp(target[:, 0])
    with pytest.raises(ValueError, match="mouth"):
        reenactor.mouth = "teeth"
    plain = tmp_path / "plain"
    plain.mkdir()
    for name in ("config.json", "model.safetensors"):
        (plain / name).write_bytes((folders / name).read_bytes())
    without = Reenactor(plain, crop_size=SIDE)
    assert without.mouth == "nearest" and not (plain / MOUTH_FOLDER).exists()
    with pytest.raises(InputFileError, match="mouth generator"):
        without.mouth = "drawn"


def test_the_onnx_bundle_draws_the_same_mouth(folders, tmp_path):
    pytest.importorskip("onnxruntime")
    from deploy.runtime import MOUTH_GENERATOR_FILE, OnnxReenactor
    from lsr.export.bundle import export_graphs
    from lsr.pipeline import Reenactor, load_model, load_mouth

    result = export_graphs(load_model(folders), tmp_path / "bundle", mouth_generator=load_mouth(folders))
    assert (tmp_path / "bundle" / MOUTH_GENERATOR_FILE).is_file() and "mouth_generator" in result.metadata
    torch_side, onnx_side = Reenactor(folders), OnnxReenactor(tmp_path / "bundle")
    assert onnx_side.mouth == "drawn"
    shots = _shots(side=onnx_side.crop_size)  # the bundle's crop side (its references' size)
    for side in (torch_side, onnx_side):
        side.crop_size = onnx_side.crop_size
        side.encode_subject(shots)
    target = shots.landmarks[2]
    images = [side.synthesize_crop(target)[0].astype(int) for side in (torch_side, onnx_side)]
    assert np.abs(images[0] - images[1]).max() <= 2


def test_drawn_eyes_change_the_eyes_only_and_only_with_a_gaze(folders):
    import cv2

    from landmarks.parts.eyes.iris import PATCH, IrisDonor
    from landmarks.shape.measures import EYE_RINGS
    from lsr.pipeline import Reenactor

    reenactor = Reenactor(folders, crop_size=SIDE)
    assert reenactor.eyes == "warped"  # the default: the shots' irises warped (MODEL_CARD); drawn is opt-in
    reenactor.eyes = "blend"
    reenactor.encode_subject(_shots())
    patch = np.full((PATCH, PATCH, 3), 230, np.uint8)
    cv2.circle(patch, (PATCH // 2, PATCH // 2), PATCH // 3, (20, 20, 20), -1)
    reenactor.subject._irises = (IrisDonor(np.stack([patch, patch]), np.array([0.2, 0.2]), np.array([230.0, 230.0]), 0),
                                 np.zeros((2, 2)))
    target = reenactor.subject.shots.landmarks[1]
    gaze = np.array([[0.1, 0.0], [0.1, 0.0]])
    blend = reenactor.synthesize_crop(target, gaze=gaze)[0]
    reenactor.eyes = "drawn"
    assert (reenactor.synthesize_crop(target)[0] == blend).all()  # no gaze (a landmark driver): the blend
    drawn = reenactor.synthesize_crop(target, gaze=gaze)[0]
    changed = np.abs(drawn.astype(int) - blend.astype(int)).max(axis=-1) > 0
    assert changed.any()
    eyes = np.zeros_like(changed)
    for ring in EYE_RINGS:
        lids = target[list(ring)]
        x0, y0 = np.floor(lids.min(axis=0)).astype(int) - 1
        x1, y1 = np.ceil(lids.max(axis=0)).astype(int) + 2
        eyes[y0:y1, x0:x1] = True
    assert not (changed & ~eyes).any()
    with pytest.raises(ValueError, match="eyes"):
        reenactor.eyes = "googly"


def test_the_driver_mouth_interior_goes_inside_the_lips_by_default_and_can_be_told_not_to(folders):
    from landmarks.parts.mouth.interior import cut_driver_mouth
    from lsr.pipeline import Reenactor

    reenactor = Reenactor(folders, crop_size=SIDE)
    assert reenactor.mouth_interior == "driver"
    reenactor.encode_subject(_shots())
    target = set_mouth_opening(reenactor.subject.shots.landmarks[1], 0.3)
    driver = np.full((SIDE, SIDE, 3), 12, np.uint8)  # a driver whose open mouth is a dark cavity
    mouth = cut_driver_mouth(driver, target)
    plain = reenactor.synthesize_crop(target)[0]  # a landmark driver: no frame, no interior
    inside = reenactor.synthesize_crop(target, driver_mouth=mouth)[0]
    changed = np.abs(inside.astype(int) - plain.astype(int)).max(axis=-1) > 0
    ys, xs = np.nonzero(changed)
    assert len(ys) and (xs >= target[48:60, 0].min() - 2).all() and (xs <= target[48:60, 0].max() + 2).all()
    assert (ys >= target[48:60, 1].min() - 2).all() and (ys <= target[48:60, 1].max() + 2).all()
    y, x = np.round(target[[62, 66]].mean(axis=0)).astype(int)[::-1]
    assert inside[y, x].max() < plain[y, x].max()  # darker where the driver's cavity is
    reenactor.mouth_interior = "shots"
    assert (reenactor.synthesize_crop(target, driver_mouth=mouth)[0] == plain).all()
    with pytest.raises(ValueError, match="mouth_interior"):
        reenactor.mouth_interior = "tongue"


def _encoded_with_shut_eyes(folders):
    """(a reenactor with the shots encoded, a shot's own open-eyed landmarks, the same with the lids shut)."""
    from landmarks.parts.eyes.lids import closed_gaps, lid_gaps, set_lid_gaps
    from lsr.pipeline import Reenactor

    reenactor = Reenactor(folders, crop_size=SIDE)
    reenactor.encode_subject(_shots())
    target = reenactor.subject.shots.landmarks[1]
    return reenactor, target, set_lid_gaps(target, closed_gaps(lid_gaps(target)))


def test_the_driver_shut_eyes_go_over_the_eyes_when_asked_and_can_be_told_not_to(folders):
    from landmarks.parts.eyes.driver_lids import cut_driver_eyes
    from landmarks.parts.eyes.lids import lid_gaps

    reenactor, target, shut = _encoded_with_shut_eyes(folders)
    assert reenactor.lids == "drawn"
    reenactor.lids = "driver"
    rest = lid_gaps(target)
    driver = np.full((SIDE, SIDE, 3), 150, np.uint8)  # a driver whose shut eyes are plain skin
    eyes = cut_driver_eyes(driver, shut, rest)
    assert eyes is not None and eyes.strength == pytest.approx(1.0)
    plain = reenactor.synthesize_crop(target)[0]  # a landmark driver: no frame, no lids laid in
    laid = reenactor.synthesize_crop(target, driver_eyes=eyes)[0]
    changed = np.abs(laid.astype(int) - plain.astype(int)).max(axis=-1) > 0
    ys, xs = np.nonzero(changed)
    reach = 0.7 * np.ptp(target[36:48, 0])  # the eyes' ellipses and their feather, no further
    assert len(ys) and (xs >= target[36:48, 0].min() - reach).all() and (xs <= target[36:48, 0].max() + reach).all()
    assert (ys <= target[48:68, 1].min()).all()  # nothing from the mouth down
    reenactor.lids = "shots"
    assert (reenactor.synthesize_crop(target, driver_eyes=eyes)[0] == plain).all()
    with pytest.raises(ValueError, match="lids"):
        reenactor.lids = "wink"


def test_with_no_driver_frame_the_subject_lids_are_drawn_where_the_target_shuts_them(folders):
    from landmarks.parts.eyes.drawn_lids import draw_lids

    reenactor, open_target, shut = _encoded_with_shut_eyes(folders)
    reenactor.lids = "shots"
    warped_only = reenactor.synthesize_crop(shut)[0]
    for lids in ("driver", "drawn"):  # a landmark driver's shut eyes: no frame to take them from, so drawn
        reenactor.lids = lids
        drawn = reenactor.synthesize_crop(shut)[0]
        np.testing.assert_array_equal(drawn, draw_lids(warped_only, shut, reenactor.subject.lid_gaps))
        ys, xs = np.nonzero(np.abs(drawn.astype(int) - warped_only.astype(int)).max(axis=-1) > 0)
        assert len(ys) and (ys <= shut[48:68, 1].min()).all()  # the eyes, nothing from the mouth down
    reenactor.lids = "drawn"  # open eyes stay as the warps give them
    drawn_open = reenactor.synthesize_crop(open_target)[0]
    reenactor.lids = "shots"
    np.testing.assert_array_equal(drawn_open, reenactor.synthesize_crop(open_target)[0])


def test_set_parts_sets_what_is_given_and_names_what_is_wrong():
    from lsr.core.engine import ReenactorBase
    from lsr.core.finish import set_parts

    reenactor = ReenactorBase.__new__(ReenactorBase)  # the settings are class attributes: no backend needed
    set_parts(reenactor, eyes="blend", lids=None, bank="shots")
    assert (reenactor.eyes, reenactor.lids, reenactor.bank) == ("blend", "drawn", "shots")
    with pytest.raises(ValueError, match="lids"):
        set_parts(reenactor, lids="closed")
    with pytest.raises(ValueError, match="hair"):
        set_parts(reenactor, hair="long")
