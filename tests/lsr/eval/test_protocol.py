"""K-shot sampling, buckets and the protocol runner (lsr.eval.protocol) on constructed data."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.errors import ConfigError
from lsr.eval import protocol


def _landmarks(rng: np.random.Generator, count: int, size: int = 64) -> np.ndarray:
    base = rng.uniform(0.3 * size, 0.7 * size, size=(68, 2))
    base[36:42] = [0.35 * size, 0.4 * size]
    base[42:48] = [0.65 * size, 0.4 * size]
    return (base[None] + rng.normal(0, 1.0, size=(count, 68, 2))).astype(np.float32)


def _identity(rng: np.random.Generator, name: str, inputs: int = 8, holdouts: int = 4, size: int = 64) -> protocol.EvalIdentity:
    frames = rng.integers(0, 256, size=(inputs + holdouts, size, size, 3), dtype=np.uint8)
    points = _landmarks(rng, inputs + holdouts, size)
    return protocol.EvalIdentity(name, frames[:inputs], points[:inputs], frames[inputs:], points[inputs:])


class TestSampling:
    def test_deterministic_distinct_and_within_candidates(self):
        candidates = np.array([0, 2, 3, 5, 7, 11, 13])
        first = protocol.sample_shots(candidates, 4, seed=0, identity="id0")
        assert np.array_equal(first, protocol.sample_shots(candidates, 4, seed=0, identity="id0"))
        assert len(set(first.tolist())) == 4 and set(first.tolist()) <= set(candidates.tolist())
        others = {tuple(protocol.sample_shots(candidates, 4, seed=s, identity="id0")) for s in range(20)}
        assert len(others) > 5  # the seed matters

    def test_uniform_over_inputs(self):
        counts = np.zeros(32)
        for seed in range(2000):
            counts[protocol.sample_shots(np.arange(32), 1, seed=seed, identity="x")] += 1
        expected = 2000 / 32
        chi_square = float(np.sum((counts - expected) ** 2 / expected))
        assert chi_square < 70  # 31 degrees of freedom: p ~ 1e-4 at 70

    def test_all_shots_when_k_equals_inputs_and_error_beyond(self):
        assert np.array_equal(protocol.sample_shots(np.arange(32), 32, 0, "x"), np.arange(32))
        with pytest.raises(ConfigError):
            protocol.sample_shots(np.arange(4), 5, 0, "x")


class TestBuckets:
    def test_constructed_cases(self):
        labels = protocol.assign_buckets(np.array([0.01, 0.1, 0.2, 0.5, np.nan]), (0.1, 0.3))
        assert labels == ["low", "medium", "medium", "high", "unknown"]

    def test_terciles_split_evenly(self):
        distances = np.arange(1, 10, dtype=float)
        thresholds = protocol.bucket_thresholds(distances)
        labels = protocol.assign_buckets(distances, thresholds)
        assert [labels.count(b) for b in protocol.BUCKETS] == [3, 3, 3]


class _SpyMethod:
    """Outputs the inverted first shot and remembers every shot it was given."""

    name = "spy"

    def __init__(self):
        self.seen: list[np.ndarray] = []
        self.finetuned = 0

    def reenact(self, shots, shot_landmarks, target_landmarks):
        self.seen.extend(shots)
        return np.stack([255 - shots[0]] * len(target_landmarks))  # a new image: the fake detector finds no face

    def finetune(self, shots, shot_landmarks):
        self.finetuned += 1
        self.seen.extend(shots)
        return self


def test_runner_never_shows_holdouts_to_the_method(rng, no_face_detector):
    identities = [_identity(rng, "a"), _identity(rng, "b")]
    identities[0].holdout_landmarks[1] = np.nan  # a hold-out without a face: skipped and counted
    spy = _SpyMethod()
    run = protocol.run_protocol([spy], identities, [1, 4], protocol.FaceAnalysis(no_face_detector()),
                                max_holdouts=3, progress=False)
    holdouts = {frame.tobytes() for identity in identities for frame in identity.holdout_frames}
    inputs = {frame.tobytes() for identity in identities for frame in identity.input_frames}
    assert spy.seen and all(shot.tobytes() in inputs and shot.tobytes() not in holdouts for shot in spy.seen)
    assert spy.finetuned == 4  # 2 identities x 2 K values
    assert {r["method"] for r in run.records} == {"spy", "spy+ft"}
    assert run.counts["holdouts_without_face"] == {"a": 1, "b": 0}
    at_a = [r for r in run.records if r["identity"] == "a" and r["method"] == "spy" and r["k"] == 1]
    assert [r["frame"] for r in at_a] == [0, 2, 3]
    # the fake detector finds no face on any output: counted, NMKE missing, never dropped
    assert all(r["no_face"] and np.isnan(r["nmke"]) for r in run.records)
    assert len(run.cross_records) == 2 * 2 * 2 * 3  # variants x K x identities x frames
    assert all(r["bucket"] in protocol.BUCKETS for r in run.records)
    # noise against noise: about as much fine detail as the ground truth
    assert all(0.5 < r["sharpness"] < 2.0 for r in run.records)


def test_k_beyond_usable_inputs_is_capped_and_reported(rng, no_face_detector):
    identity = _identity(rng, "a", inputs=5, holdouts=2)
    identity.input_landmarks[0] = np.nan  # 4 usable inputs
    spy = _SpyMethod()
    run = protocol.run_protocol([spy], [identity], [8], protocol.FaceAnalysis(no_face_detector()),
                                cross_identity=False, finetune=False, progress=False)
    assert run.counts["k_capped"] == {"K=8 a": 4}
    assert len(spy.seen) == 4 and not any(np.array_equal(shot, identity.input_frames[0]) for shot in spy.seen)


def test_inputs_of_another_person_are_never_drawn(rng, no_face_detector, monkeypatch):
    identity = _identity(rng, "a", inputs=6, holdouts=2)
    others = {identity.input_frames[i].tobytes() for i in (1, 4)}
    # descriptors 1.0 apart for the two frames of "another person", identical for the rest
    from lsr.eval import analysis

    monkeypatch.setattr(analysis, "judged", lambda points, shape: True)  # FaceAnalysis.same_person's
    monkeypatch.setattr(protocol.idsim, "face_descriptor",
                        lambda image, points: np.full(128, 0.1 if image.tobytes() in others else 0.0))
    spy = _SpyMethod()
    run = protocol.run_protocol([spy], [identity], [8], protocol.FaceAnalysis(no_face_detector()),
                                cross_identity=False, finetune=False, progress=False)
    assert run.counts["inputs_of_another_person"] == {"a": 2}
    assert run.counts["k_capped"] == {"K=8 a": 4}
    assert len(spy.seen) == 4 and not any(shot.tobytes() in others for shot in spy.seen)


class _FixedFaceDetector:
    """Finds the same face on every image: the cross metrics get landmarks to measure (a real detector would not
    find faces on noise)."""

    kind, max_side, upsample, min_score = "fake", 64, 0, 0.0

    def __init__(self, landmarks: np.ndarray) -> None:
        self.face_landmarks = landmarks.astype(np.float32)

    def detect(self, image):
        from landmarks.detect.face_detector import Face

        return [Face(np.array([0, 0, 1, 1], np.float32), self.face_landmarks, 1.0)]


class _TargetSpy:
    """Pastes a grey face at every target and remembers the targets it was given."""

    def __init__(self, name: str):
        self.name, self.targets = name, []

    def reenact(self, shots, shot_landmarks, target_landmarks):
        self.targets.append(np.array(target_landmarks))
        return np.stack([np.full_like(shots[0], 90 + 3 * t) for t in range(len(target_landmarks))])


def _posed_identity(rng: np.random.Generator, name: str, size: int = 96, count: int = 5) -> protocol.EvalIdentity:
    from landmarks.motion.head_pose import project_canonical

    def face(yaw: float, mouth: float) -> np.ndarray:
        points = project_canonical(yaw, 0.0, 0.0, (size, size)).astype(np.float64)
        points[65:68, 1] += mouth
        return points

    inputs = np.stack([face(yaw, mouth) for yaw, mouth in zip((20.0, 2.0, -15.0, 8.0, 30.0), (0, 0, 6, 0, 0))])
    holdouts = np.stack([face(3.0 * t, 1.5 * t) for t in range(count)])
    frames = rng.integers(0, 256, size=(5 + count, size, size, 3), dtype=np.uint8)
    return protocol.EvalIdentity(name, frames[:5], inputs.astype(np.float32), frames[5:], holdouts.astype(np.float32))


def test_cross_identity_is_retargeted_composited_and_measured(rng):
    from landmarks.parts.eyes.lids import running_reference_gaps
    from landmarks.shape.expression import mouth_opening, pick_anchor
    from landmarks.motion.retarget_points import retarget_driving

    identities = [_posed_identity(rng, "a"), _posed_identity(rng, "b")]
    first, second = _TargetSpy("first"), _TargetSpy("second")
    analysis = protocol.FaceAnalysis(_FixedFaceDetector(identities[0].holdout_landmarks[2]))
    run = protocol.run_protocol([first, second], identities, [5], analysis, finetune=False, progress=False)
    # self re-enactment: the face region's numbers beside the whole frame's
    assert all(np.isfinite(r["psnr_face"]) and np.isfinite(r["ssim_face"]) for r in run.records)
    # identity "a" (all 5 shots at K = 5) is driven by "b": retargeted onto a's anchor, b's first frame the reference
    anchor = pick_anchor(identities[0].input_landmarks.astype(np.float64), (96, 96))
    driver = identities[1].holdout_landmarks.astype(np.float64)
    expected = retarget_driving(driver, driver[0], identities[0].input_landmarks[anchor].astype(np.float64),
                                running_reference_gaps(driver))  # the lids' reference: the median so far
    assert np.allclose(first.targets[1], expected) and np.allclose(second.targets[1], expected)  # [0]: self
    crossed = [r for r in run.cross_records if r["identity"] == "a" and r["method"] == "first"]
    assert [r["frame"] for r in crossed] == list(range(5)) and {r["driver"] for r in crossed} == {"b"}
    assert {r["anchor"] for r in crossed} == {anchor}
    keys = {"idsim_source", "nmke", "yaw_error", "pitch_error", "roll_error", "driver_mouth", "driver_eye",
            "output_mouth", "output_eye", "sharpness_face", "scene_mse", "scene_psnr", "scene_flicker", "no_face"}
    assert all(keys <= set(r) for r in run.cross_records) and not any(r["no_face"] for r in run.cross_records)
    assert all(np.isfinite([r["nmke"], r["yaw_error"], r["sharpness_face"]]).all() for r in crossed)
    assert np.allclose([r["driver_mouth"] for r in crossed], mouth_opening(driver))  # the real driver, not the targets
    # the composite leaves the scene as it was: bit-identical outside the head regions, no flicker there
    assert all(r["scene_psnr"] >= 30.0 for r in run.cross_records)
    assert all(r["scene_flicker"] == 0.0 for r in run.cross_records if r["frame"] > 0)


def test_each_identity_can_be_driven_by_several_others(rng):
    """--cross-drivers N: identity i is driven by i+1 ... i+N (at most all the others), one sequence per pair."""
    from lsr.eval.cross import summarise_cross

    identities = [_posed_identity(rng, name) for name in "abc"]
    analysis = protocol.FaceAnalysis(_FixedFaceDetector(identities[0].holdout_landmarks[2]))
    method = _TargetSpy("spy")
    run = protocol.run_protocol([method], identities, [5], analysis, finetune=False, progress=False, cross_drivers=5)
    pairs = {(r["identity"], r["driver"]) for r in run.cross_records}
    assert pairs == {(a, b) for a in "abc" for b in "abc" if a != b}
    assert run.settings["cross_drivers"] == 5
    assert summarise_cross(run.cross_records, ["spy"], [5])[0]["sequences"] == 6
    one = protocol.run_protocol([method], identities, [5], analysis, finetune=False, progress=False)
    assert {(r["identity"], r["driver"]) for r in one.cross_records} == {("a", "b"), ("b", "c"), ("c", "a")}
    with pytest.raises(ConfigError, match="cross_drivers"):
        protocol.run_protocol([method], identities, [5], analysis, progress=False, cross_drivers=0)


class _ReadsTargetDetector:
    """Reads back the hold-out landmarks whose row a test method wrote into the image's grey level."""

    kind, max_side, upsample, min_score = "fake", 64, 0, 0.0

    def __init__(self, holdout_landmarks: np.ndarray) -> None:
        self.table = holdout_landmarks.astype(np.float32)

    def detect(self, image):
        from landmarks.detect.face_detector import Face

        row = int(image[0, 0, 0]) - 10
        return [Face(np.array([0, 0, 1, 1], np.float32), self.table[row], 1.0)] if 0 <= row < len(self.table) else []


class _DrawsRows:
    """Writes target row t (or the rows in reverse) into its frames: the detector reads back that row's face."""

    def __init__(self, name: str, reverse: bool = False):
        self.name, self.reverse = name, reverse

    def reenact(self, shots, shot_landmarks, target_landmarks):
        count = len(target_landmarks)
        rows = range(count - 1, -1, -1) if self.reverse else range(count)
        return np.stack([np.full_like(shots[0], 10 + row) for row in rows])


def test_self_reenactment_correlates_the_outputs_expression_with_the_truth(rng):
    """Self re-enactment's mouth / eye corr: 1 for outputs that show the hold-outs' own faces, -1 in reverse order."""
    from lsr.eval import report

    identity = _posed_identity(rng, "a", count=6)
    holdouts = identity.holdout_landmarks.astype(np.float64)
    for t in range(len(holdouts)):  # the upper lids rise over the hold-outs, unevenly
        holdouts[t, [37, 38, 43, 44], 1] -= 0.6 * t + 0.3 * (t % 2)
    identity.holdout_landmarks = holdouts.astype(np.float32)
    analysis = protocol.FaceAnalysis(_ReadsTargetDetector(identity.holdout_landmarks))
    run = protocol.run_protocol([_DrawsRows("follows"), _DrawsRows("reversed", reverse=True)], [identity], [5],
                                analysis, cross_identity=False, finetune=False, progress=False)
    rows = {row["method"]: row for row in report.summarise(run)["rows"]}
    assert rows["follows"]["mouth_corr"] == pytest.approx(1.0) and rows["follows"]["eye_corr"] == pytest.approx(1.0)
    assert rows["reversed"]["mouth_corr"] < -0.9 and rows["reversed"]["eye_corr"] < 0
    text = report.markdown(report.summarise(run), "| machine | |")
    assert "| NMKE ↓ | mouth corr ↑ | eye corr ↑ | no face |" in text and "| 1.00 | 1.00 | 0 |" in text


def test_moving_parts_are_scored_and_judged_beside_the_other_metrics(rng):
    identities = [_posed_identity(rng, "a"), _posed_identity(rng, "b")]
    analysis = protocol.FaceAnalysis(_FixedFaceDetector(identities[0].holdout_landmarks[2]))
    run = protocol.run_protocol([_TargetSpy("first")], identities, [3], analysis, finetune=False, progress=False)
    part_keys = {f"{score}_{region}" for score in ("psnr", "ssim", "sharpness") for region in ("mouth", "eyes")}
    beyond_keys = {f"beyond_{name}" for name in ("mouth", "eyes", "yaw", "gaze", "any")}
    assert all(part_keys | beyond_keys <= set(r) for r in run.records)
    # the hold-outs turn up to 12 degrees and open the mouth: some lie beyond 3 shots, flagged from the truth
    assert any(r["beyond_any"] for r in run.records)
    judge_keys = {"judge_driver_mouth", "judge_output_mouth", "judge_driver_eye", "judge_output_eye",
                  "judge_driver_gaze", "judge_output_gaze", "iris_contrast", "output_cavity", "driver_cavity",
                  "judge_no_face"}
    assert all(judge_keys <= set(r) for r in run.cross_records)
    assert "judge_boxed" in run.counts
    unjudged = protocol.run_protocol([_TargetSpy("first")], identities, [3], analysis, finetune=False,
                                     progress=False, judge=False)
    assert not any("judge_no_face" in r for r in unjudged.cross_records) and "judge_boxed" not in unjudged.counts


def test_covering_shots_are_the_ones_lsr_reenact_would_choose(rng):
    from lsr.core.inputs import choose_shots

    identity = _posed_identity(rng, "a")
    spy = _SpyMethod()
    protocol.run_protocol([spy], [identity], [3], protocol.FaceAnalysis(_FixedFaceDetector(identity.input_landmarks[1])),
                          finetune=False, cross_identity=False, progress=False, shot_choice="cover", judge=False)
    expected = choose_shots(list(identity.input_frames), list(identity.input_landmarks), 3)
    assert [shot.tobytes() for shot in spy.seen[:3]] == [identity.input_frames[i].tobytes() for i in expected]
    spread = _SpyMethod()
    protocol.run_protocol([spread], [identity], [3], protocol.FaceAnalysis(_FixedFaceDetector(identity.input_landmarks[1])),
                          finetune=False, cross_identity=False, progress=False, shot_choice="spread", judge=False)
    assert [shot.tobytes() for shot in spread.seen[:3]] == [identity.input_frames[i].tobytes() for i in (0, 2, 4)]
    with pytest.raises(ConfigError, match="shot_choice"):
        protocol.run_protocol([spy], [identity], [3], protocol.FaceAnalysis(_FixedFaceDetector(identity.input_landmarks[1])),
                              progress=False, shot_choice="evenly")


class _GazeSpy(_TargetSpy):
    """A method with drawn eyes: the protocol passes it where each target looks."""

    uses_gazes = True

    def __init__(self, name: str):
        super().__init__(name)
        self.gazes = []

    def reenact(self, shots, shot_landmarks, target_landmarks, target_gazes=None):
        self.gazes.append(np.array(target_gazes))
        return super().reenact(shots, shot_landmarks, target_landmarks)


def test_drawn_eyes_get_the_holdouts_gaze_and_cross_identity_the_drivers_relative_gaze(rng, monkeypatch):
    import lsr.core.finish

    def fake_gazes(frames, landmarks):  # each frame's mean grey as its gaze: distinct per frame, no iris net
        values = np.array([frame.mean() / 255.0 for frame in frames])
        return np.repeat(values[:, None, None], 2, axis=1) * np.array([1.0, 0.5])

    monkeypatch.setattr(lsr.core.finish, "sequence_gazes", fake_gazes)  # read at each call (lsr.eval.part_regions.gaze_inputs)
    identities = [_posed_identity(rng, "a"), _posed_identity(rng, "b")]
    spy, plain = _GazeSpy("eyes"), _TargetSpy("plain")
    analysis = protocol.FaceAnalysis(_FixedFaceDetector(identities[0].holdout_landmarks[2]))
    protocol.run_protocol([spy, plain], identities, [5], analysis, finetune=False, progress=False)
    self_a, cross_a = spy.gazes[0], spy.gazes[1]  # identity a: self, then driven by b
    np.testing.assert_allclose(self_a, fake_gazes(identities[0].holdout_frames, None))
    from landmarks.shape.expression import pick_anchor

    anchor = pick_anchor(identities[0].input_landmarks.astype(np.float64), (96, 96))
    driver = fake_gazes(identities[1].holdout_frames, None)
    source = fake_gazes(identities[0].input_frames[anchor][None], None)[0]
    np.testing.assert_allclose(cross_a, source + driver - driver[0])  # relative, as lsr reenact moves it
    assert len(plain.targets) == len(spy.targets)  # a method without drawn eyes is called as before
