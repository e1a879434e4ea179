"""Training a mouth generator (lsr.train.part_training): the pairs, the shots that leave the mouth beyond them, the loop."""

from __future__ import annotations

import json

import numpy as np
import pytest

from landmarks.parts.part_window import MOUTH, extract, to_window, window_transform
from lsr.train.part_training import (Adversary, _choose_shots, batch_tensors, clip_pairs, evaluate, load_pairs, part_loss,
                             train)


def test_closed_shots_come_from_the_least_open_mouths(rng):
    openings = np.linspace(0.0, 1.0, 20)
    pool = np.arange(20)
    closed = _choose_shots(openings, pool, 4, True, rng)
    assert len(closed) == 4 and openings[closed].max() <= openings[7]  # the 40% least open (8 of 20)
    anywhere = np.concatenate([_choose_shots(openings, pool, 4, False, rng) for _ in range(20)])
    assert openings[anywhere].max() > openings[7]


def test_clip_pairs_are_the_windows_of_the_synthesis_and_of_the_frame():
    import torch

    from lsr.data.synth import render_video
    from lsr.pipeline import Reenactor
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    reenactor = Reenactor(LSRModel(preset_config("tiny", variant="warp_guided")), crop_size=128)
    video = render_video(5, 6, 128)
    pairs = clip_pairs(reenactor, video.frames, video.landmarks, None, np.array([0, 1, 2]), np.array([4, 5]))
    assert pairs["synthesis"].shape == pairs["truth"].shape == (2, MOUTH.size, MOUTH.size, 3)
    transform = window_transform(video.landmarks[5])
    np.testing.assert_array_equal(pairs["truth"][1], extract(video.frames[5], transform, MOUTH.size))
    np.testing.assert_allclose(pairs["window_landmarks"][1], to_window(video.landmarks[5], transform), atol=1e-4)
    assert list(pairs["target_index"]) == [4, 5] and list(pairs["shots"]) == [0, 1, 2]


def _fake_pairs(folder, drawn_face, count: int, seed: int) -> None:
    """Pairs whose answer is known: a closed mouth in, the same face with an open dark mouth out."""
    import cv2

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    synthesis, truth, points, openings = [], [], [], []
    for _ in range(count):
        opening = float(rng.uniform(0.1, 0.4))
        closed_image, _ = drawn_face(mouth=0.0, inside=(150, 90, 90))
        open_image, face = drawn_face(mouth=opening, inside=(30, 20, 20))
        face = face * 0.5
        transform = window_transform(face)
        synthesis.append(extract(cv2.resize(closed_image, (256, 256), interpolation=cv2.INTER_AREA), transform, MOUTH.size))
        truth.append(extract(cv2.resize(open_image, (256, 256), interpolation=cv2.INTER_AREA), transform, MOUTH.size))
        points.append(to_window(face, transform).astype(np.float32))
        openings.append(opening)
    np.savez(folder / "fake.npz", synthesis=np.stack(synthesis), truth=np.stack(truth),
             window_landmarks=np.stack(points), target_openings=np.array(openings, np.float32),
             shot_openings=np.zeros(3, np.float32))


def test_training_resumes_keeps_the_best_and_learns_the_open_mouth(tmp_path, drawn_face):
    _fake_pairs(tmp_path / "pairs" / "train", drawn_face, 12, 0)
    _fake_pairs(tmp_path / "pairs" / "test", drawn_face, 4, 1)
    pairs = load_pairs(tmp_path / "pairs" / "test")
    assert len(pairs) == 4 and pairs.beyond.all()
    window, masks, truth, weight = batch_tensors(pairs, np.arange(2), np.array([True, False]))
    assert window.shape == (2, 3, MOUTH.size, MOUTH.size) and masks.shape == (2, 2, MOUTH.size, MOUTH.size)
    assert float(weight.max()) > 1.5  # the open mouth weighs more
    run = tmp_path / "run"
    first = train(tmp_path / "pairs", run, steps=4, batch=4, lr=3e-3, eval_every=2, save_every=2, threads=1)
    assert first["step"] == 4 and (run / "checkpoint.pt").is_file() and (run / "best" / "config.json").is_file()
    assert (run / "preview.png").is_file()
    resumed = train(tmp_path / "pairs", run, steps=40, batch=4, lr=3e-3, eval_every=20, save_every=20, threads=1)
    assert resumed["step"] == 40
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [entry["step"] for entry in log] == [2, 4, 20, 40]
    from models_def.part_generator import PartGenerator

    scores = evaluate(PartGenerator.from_pretrained(run / "best"), pairs)
    assert scores["psnr"] > scores["psnr_input"] + 1.0  # it learnt to open the mouth it was shown closed


def test_no_pairs_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="lsr parts pairs"):
        load_pairs(tmp_path)


def test_adversarial_training_keeps_its_discriminator_across_a_resume(tmp_path, drawn_face):
    import torch

    _fake_pairs(tmp_path / "pairs" / "train", drawn_face, 6, 0)
    _fake_pairs(tmp_path / "pairs" / "test", drawn_face, 2, 1)
    run = tmp_path / "run"
    adversary = Adversary(weight=0.1, feature_matching=1.0, r1=1.0, critic_lr=1.0, critic_width=8)
    train(tmp_path / "pairs", run, steps=2, batch=2, eval_every=2, save_every=2, threads=1, adversarial=adversary,
          widths=(8, 16), hole=-1)
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    assert "critic" in state and "critic_optimizer" in state
    assert (run / "steps" / "000002" / "config.json").is_file() and (run / "steps" / "000002.png").is_file()
    from models_def.part_generator import PartGenerator

    assert PartGenerator.from_pretrained(run / "best").config.widths == (8, 16)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert 0.0 <= log[-1]["open_sharpness"] and np.isfinite(log[-1]["psnr"])
    timed = train(tmp_path / "pairs", run / "timed", steps=10**6, batch=2, eval_every=10**6, threads=1,
                  minutes=1e-4)  # the wall-time budget ends the run (and writes its last evaluation)
    assert 1 <= timed["step"] < 10**6 and (run / "timed" / "best" / "config.json").is_file()
    resumed = train(tmp_path / "pairs", run / "next", steps=2, batch=2, eval_every=2, save_every=2, threads=1,
                    adversarial=0.1, init_from=run / "best")
    assert resumed["step"] == 2


def _open_mouth(size: int = 40):
    import torch

    masks = torch.zeros(2, 2, size, size)
    masks[:, 0, 12:28, 6:34] = 1.0  # outer lips
    masks[:, 1, 17:23, 10:30] = 1.0  # the open mouth inside
    return masks


def test_the_interior_loss_sees_the_cavity_darkness_not_its_detail():
    import torch

    truth = torch.zeros(2, 3, 40, 40)
    masks = _open_mouth()
    weight = torch.ones(2, 1, 40, 40)
    detail = truth.clone()
    detail[..., 17:23, 10:30] = 0.5 * (torch.arange(20) % 2 * 2 - 1).float()  # teeth-like stripes, zero mean
    darker = truth.clone()
    darker[..., 17:23, 10:30] = -0.5  # a darker cavity
    plain = part_loss(detail, truth, weight)
    low = part_loss(detail, truth, weight, masks, interior_sigma=2.0)
    assert low < 0.1 * plain  # the stripes' detail is the discriminator's, not the L1's
    assert part_loss(darker, truth, weight, masks, interior_sigma=2.0) > 0.5 * part_loss(darker, truth, weight)
    outside = truth.clone()
    outside[..., 0:5, :] = 0.5  # outside the open mouth the plain L1, a mean over the rest of the window
    expected = part_loss(outside, truth, weight * (1.0 - masks[:, 1:]))
    assert torch.isclose(part_loss(outside, truth, weight, masks, interior_sigma=2.0), expected)


def test_an_interior_discriminator_sees_only_the_open_mouth():
    import torch

    window = torch.ones(2, 3, 40, 40)
    masks = _open_mouth()
    view = Adversary(interior=True).view(window, masks)
    assert torch.equal(view[..., 17:23, 10:30], window[..., 17:23, 10:30])
    assert float(view[..., :10, :].abs().max()) == 0.0 and float(view[..., 17:23, :4].abs().max()) == 0.0
    assert torch.equal(Adversary().view(window, masks), window)


def test_an_interior_generator_trains_with_its_discriminator(tmp_path, drawn_face):
    from models_def.part_generator import PartGenerator

    _fake_pairs(tmp_path / "pairs" / "train", drawn_face, 6, 0)
    _fake_pairs(tmp_path / "pairs" / "test", drawn_face, 2, 1)
    run = tmp_path / "run"
    adversary = Adversary(weight=0.1, feature_matching=1.0, r1=1.0, critic_lr=1.0, critic_width=8, interior=True)
    result = train(tmp_path / "pairs", run, steps=2, batch=2, eval_every=2, save_every=2, threads=1,
                   adversarial=adversary, widths=(8, 16), hole=2, interior=True, interior_sigma=2.0)
    assert result["step"] == 2
    model = PartGenerator.from_pretrained(run / "best")
    assert model.config.interior and model.config.hole == 2
    pairs = load_pairs(tmp_path / "pairs" / "test")
    window, masks, _, _ = batch_tensors(pairs, np.arange(2))
    import torch

    with torch.no_grad():
        drawn = model(window, masks)
    far = torch.nn.functional.max_pool2d(masks[:, 1:], 7, stride=1, padding=3) == 0  # beyond the grown mouth
    assert torch.equal(drawn.expand_as(window)[far.expand_as(window)], window[far.expand_as(window)])
