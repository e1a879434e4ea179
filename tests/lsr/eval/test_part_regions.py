"""lsr.eval.part_regions: the moving parts' regions and scores, beyond-the-shots flags, the independent judge and the
summaries of ``lsr eval``."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from lsr.eval import part_regions as parts


def test_part_masks_cover_the_mouth_and_both_eyes_and_nothing_between(drawn_face):
    image, points = drawn_face(mouth=0.2)
    masks = parts.part_masks(points, image.shape[:2])
    mouth_centre = np.round(points[60:68].mean(0)).astype(int)
    for first in (36, 42):
        centre = np.round(points[first:first + 6].mean(0)).astype(int)
        assert masks["eyes"][centre[1], centre[0]] and not masks["mouth"][centre[1], centre[0]]
    assert masks["mouth"][mouth_centre[1], mouth_centre[0]] and not masks["eyes"][mouth_centre[1], mouth_centre[0]]
    nose = np.round(points[30]).astype(int)
    assert not masks["eyes"][nose[1], nose[0]] and not masks["mouth"][nose[1], nose[0]]
    empty = parts.part_masks(np.full((68, 2), np.nan), image.shape[:2])
    assert not empty["mouth"].any() and not empty["eyes"].any()
    with pytest.raises(ValueError, match="68, 2"):
        parts.part_masks(np.zeros((2, 68, 2)), image.shape[:2])


def test_region_scores_see_a_blurred_mouth_and_leave_the_eyes_alone(drawn_face):
    image, points = drawn_face(mouth=0.25)
    image = np.ascontiguousarray(image + np.random.default_rng(0).integers(0, 12, image.shape, dtype=np.uint8))
    masks = parts.part_masks(points, image.shape[:2])
    blurred = image.copy()
    blurred[masks["mouth"]] = cv2.GaussianBlur(image, (9, 9), 3)[masks["mouth"]]
    (same,), (soft,) = (parts.self_part_scores(o[None], image[None], points[None]) for o in (image, blurred))
    assert math.isinf(same["psnr_mouth"]) and same["ssim_mouth"] == pytest.approx(1.0, abs=1e-5)
    assert same["sharpness_mouth"] == pytest.approx(1.0) and same["sharpness_eyes"] == pytest.approx(1.0)
    assert np.isfinite(soft["psnr_mouth"]) and soft["ssim_mouth"] < 0.95 and soft["sharpness_mouth"] < 0.5
    assert math.isinf(soft["psnr_eyes"]) and soft["sharpness_eyes"] == pytest.approx(1.0)
    assert parts.self_part_scores(image[:0], image[:0], points[None][:0]) == []


def test_beyond_flags_mark_the_hold_outs_no_shot_covers(drawn_face):
    shots = [drawn_face(mouth=m) for m in (0.0, 0.1)]
    targets = [drawn_face(mouth=0.05), drawn_face(mouth=0.35), drawn_face((0.2,), mouth=0.05)]
    flags = parts.beyond_flags([s[0] for s in shots], np.stack([s[1] for s in shots]),
                               np.stack([t[0] for t in targets]), np.stack([t[1] for t in targets]))
    assert [f["beyond_mouth"] for f in flags] == [False, True, False]
    assert [f["beyond_gaze"] for f in flags] == [False, False, True]
    assert [f["beyond_any"] for f in flags] == [False, True, True]
    assert not any(f["beyond_eyes"] or f["beyond_yaw"] for f in flags)


def test_the_judge_reads_a_real_face_and_boxes_where_its_detector_finds_none():
    import skimage.data

    astronaut = skimage.data.astronaut()
    judge = parts.Judge()
    found = judge.landmarks(astronaut)
    assert found.shape == (68, 2) and judge.boxed == 0
    blank = np.full_like(astronaut, 128)
    assert judge.landmarks(blank) is None and judge.boxed == 0
    assert judge.landmarks(blank.copy(), fallback=found) is None  # the same content: memoised, not asked again
    hidden = astronaut.copy()
    hidden[40:200, 100:330] = 128  # the upper face covered: dlib's detector misses it, the fallback's box is used
    assert not judge.detector.detect(hidden)
    assert judge.landmarks(hidden, fallback=found).shape == (68, 2) and judge.boxed == 1


def _cross_record(identity: str, frame: int, driver: float, output: float, cavity: float = math.nan) -> dict:
    opened = not math.isnan(cavity)
    return {"method": "m", "k": 8, "identity": identity, "driver": "d", "frame": frame, "judge_no_face": False,
            "driver_mouth": 2 * driver + 0.01 * (frame % 2), "driver_eye": 0.1 + 3 * driver,  # the driving detector's
            "judge_driver_mouth": driver, "judge_output_mouth": output, "judge_driver_eye": 0.1 + driver,
            "judge_output_eye": 0.1 + 0.5 * driver, "judge_driver_gaze": driver, "judge_output_gaze": -driver,
            "driver_gaze": 0.5 * driver + 0.01 * (frame % 3),  # the iris net's reading, with its own jitter
            "output_mouth": 4 * output, "output_eye": 0.2 + driver,  # the driving detector's reading of the outputs
            "iris_contrast": 0.5 + frame / 10, "output_cavity": cavity,
            "driver_cavity": 0.3 if opened else math.nan, "output_teeth": 0.0 if opened else math.nan,
            "driver_teeth": 0.2 if opened else math.nan}


def test_the_gaze_is_judged_where_the_driver_eyes_are_open():
    """A shut eye has no iris: where the judge reads the driver's eyes shut, neither gaze counts (the output's, nor the
    agreement row's iris net against the judge)."""
    records = [_cross_record("a", t, 0.01 * t, 0.0) for t in range(10)]
    for t in (3, 6, 7):  # blinks: the judge reads the lids shut, and the gaze there is noise
        records[t].update(judge_driver_eye=0.02, judge_output_gaze=0.5 * (-1) ** t, judge_driver_gaze=-0.4,
                          driver_gaze=0.3 * (-1) ** t)
    row, agreement = parts.summarise_cross(records, ["m"], [8])
    assert row["gaze_corr"] == pytest.approx(-1.0)  # the output looks the other way, on every open frame
    opened = [r for t, r in enumerate(records) if t not in (3, 6, 7)]
    assert 0.8 < agreement["gaze_corr"] == pytest.approx(parts.summarise_cross(opened, ["m"], [8])[1]["gaze_corr"])
    assert parts.gaze_pairs({("a", "d"): records}, "judge_driver_gaze", "judge_output_gaze")[0][0][[3, 6, 7]] == \
        pytest.approx([np.nan] * 3, nan_ok=True)
    assert parts.summarise_cross(opened, ["m"], [8])[0]["gaze_corr"] == pytest.approx(row["gaze_corr"])


def test_summarise_cross_judges_correlation_gain_gaze_contrast_and_the_inside():
    records = [_cross_record("a", t, 0.02 * t, 0.01 * t + 0.05, cavity=0.7 if t >= 3 else math.nan) for t in range(6)]
    row, agreement = parts.summarise_cross(records, ["m"], [8])
    assert row["judge_mouth_corr"] == pytest.approx(1.0) and row["judge_mouth_gain"] == pytest.approx(0.5)
    assert row["judge_eye_gain"] == pytest.approx(0.5) and row["gaze_corr"] == pytest.approx(-1.0)
    assert row["iris_contrast"] == pytest.approx(0.75) and row["open_frames"] == 3
    assert (row["output_cavity"], row["driver_cavity"], row["output_teeth"], row["driver_teeth"]) == \
        pytest.approx((0.7, 0.3, 0.0, 0.2))
    # the two detectors on the drivers' frames: the judge reads half the driving detector's mouth, with its jitter
    assert agreement["method"] == parts.AGREEMENT and agreement["frames"] == 6
    assert 0.9 < agreement["judge_mouth_corr"] < 1.0 and agreement["judge_mouth_gain"] == pytest.approx(0.5, abs=0.05)
    assert agreement["judge_eye_corr"] == pytest.approx(1.0) and agreement["judge_eye_gain"] == pytest.approx(1 / 3)
    assert 0.8 < agreement["gaze_corr"] < 1.0  # the judge's gaze against the iris net's, whose jitter it lacks
    # read alike: the judge reads the drawn mouth at a quarter, the drawn eyes at half the driving detector's reading
    assert row["read_mouth_gain"] == pytest.approx(0.25) and row["read_eye_gain"] == pytest.approx(0.5)
    assert (agreement["read_mouth_gain"], agreement["read_eye_gain"]) == (agreement["judge_mouth_gain"],
                                                                        agreement["judge_eye_gain"])
    assert parts.summarise_cross(records, ["other"], [8]) == []
    lines = "\n".join(parts.markdown([], [row, agreement], lambda value, digits=3: f"{value:.{digits}f}"))
    assert f"| {parts.AGREEMENT} | 8 | 6 | " in lines and "| 0.25, 0.50 | 3 | 0 |" in lines
    assert f"| {agreement['judge_eye_gain']:.2f} | {agreement['gaze_corr']:.2f} | – | – | – | " in lines


def test_the_agreement_row_names_a_driver_the_detectors_read_apart():
    """Pooled, a driver that moves a lot hides one whose mouth the two detectors read apart (real015's lower teeth: the
    mesh reads the inner lip on them); the row keeps each driver's own gains, and the report says them."""
    records = []
    for driver, judged in (("wide", 0.5), ("teeth", 3.0)):  # the judge reads half / three times the driving detector
        for source in ("a", "b"):
            for t in range(6):
                record = _cross_record(source, t, 0.01 * t, 0.0)
                scale = 4.0 if driver == "wide" else 0.2  # how far the driving detector reads each driver's mouth move
                record.update(driver=driver, driver_mouth=scale * 0.01 * t,
                              judge_driver_mouth=judged * scale * 0.01 * t, driver_eye=0.01 * t,
                              judge_driver_eye=(0.5 if driver == "wide" else 1.0) * 0.01 * t)
                records.append(record)
    agreement = parts.summarise_cross(records, ["m"], [8])[1]
    assert agreement["by_driver"]["wide"] == pytest.approx({"mouth_gain": 0.5, "eye_gain": 0.5, "mouth_range": 0.2,
                                                            "eye_range": 0.05})
    assert agreement["by_driver"]["teeth"] == pytest.approx({"mouth_gain": 3.0, "eye_gain": 1.0, "mouth_range": 0.01,
                                                             "eye_range": 0.05})
    assert agreement["judge_mouth_gain"] < 0.6  # pooled, the wide driver's motion sets the number
    lines = "\n".join(parts.markdown([], [agreement], lambda value, digits=3: f"{value:.{digits}f}"))
    assert "noise): teeth 3.00 / 1.00 (moving 0.01 / 0.05), wide 0.50 / 0.50 (moving 0.20 / 0.05)." in lines
    at_each_k = [r | {"k": k} for k in (1, 8) for r in records]  # the same drivers' frames at two K: said once
    lines = "\n".join(parts.markdown([], parts.summarise_cross(at_each_k, ["m"], [1, 8]),
                                     lambda value, digits=3: f"{value:.{digits}f}"))
    assert lines.count("one by one") == 1 and "one by one, K = 1, 8 (" in lines
    one = [r for r in records if r["driver"] == "wide"]  # one driver: the pooled row says it all, no line
    assert "one by one" not in "\n".join(parts.markdown([], parts.summarise_cross(one, ["m"], [8]),
                                                         lambda value, digits=3: f"{value:.{digits}f}"))


def test_summarise_self_splits_all_hold_outs_from_those_beyond():
    base = {"method": "m", "k": 8, "psnr_eyes": 30.0, "ssim_eyes": 0.9, "sharpness_eyes": 1.0,
            "beyond_eyes": False, "beyond_yaw": False, "beyond_gaze": False}
    records = [{**base, "psnr_mouth": 30.0, "ssim_mouth": 0.9, "sharpness_mouth": 1.0, "beyond_mouth": False,
                "beyond_any": False}] * 3
    records += [{**base, "psnr_mouth": 20.0, "ssim_mouth": 0.5, "sharpness_mouth": 0.5, "beyond_mouth": True,
                 "beyond_any": True, "psnr_inside": 15.0, "psnr_lips": 25.0}]
    (row,) = parts.summarise_self(records, ["m"], [8])
    assert (row["frames"], row["beyond_frames"], row["counts"]["mouth"]) == (4, 1, 1)
    assert row["all"]["psnr_mouth"] == pytest.approx(27.5) and row["mouth_beyond"]["psnr_mouth"] == 20.0
    assert row["eyes_beyond"] == {}
    assert row["all"]["psnr_inside"] == 15.0 and row["mouth_beyond"]["psnr_lips"] == 25.0
    text = "\n".join(parts.markdown([row], [], lambda v, digits=3: "–" if v is None else f"{v:.{digits}f}"))
    assert ("| m | 8 | beyond: 1 (mouth 1, eyes 0, pose 0, gaze 0) | 20.00 | 0.500 | 0.50 | 15.00 | 25.00 | – | – | – |"
            in text)


def test_the_mouth_split_scores_the_inside_of_an_open_mouth_apart_from_its_lips(drawn_face):
    image, points = drawn_face(mouth=0.3)
    split = parts.mouth_split(points, image.shape[:2])
    inner = np.round(points[60:68].mean(0)).astype(int)
    lower_lip = np.round(points[57] * 0.7 + points[66] * 0.3).astype(int)
    assert split["inside"][inner[1], inner[0]] and not split["lips"][inner[1], inner[0]]
    assert split["lips"][lower_lip[1], lower_lip[0]] and not split["inside"][lower_lip[1], lower_lip[0]]
    darker = image.copy()
    darker[split["inside"]] //= 2  # a wrong inside, right lips
    (score,) = parts.self_part_scores(darker[None], image[None], points[None])
    assert np.isfinite(score["psnr_inside"]) and math.isinf(score["psnr_lips"])
    assert score["psnr_inside"] < score["psnr_mouth"]
    closed_image, closed = drawn_face(mouth=0.0)
    assert not parts.mouth_split(closed, closed_image.shape[:2])["inside"].any()
    (shut,) = parts.self_part_scores(closed_image[None] // 2, closed_image[None], closed[None])
    assert math.isnan(shut["psnr_inside"]) and np.isfinite(shut["psnr_lips"])
    assert not parts.mouth_split(np.full((68, 2), np.nan), image.shape[:2])["lips"].any()
    with pytest.raises(ValueError, match="68, 2"):
        parts.mouth_split(np.zeros((2, 68, 2)), image.shape[:2])


def test_the_drivers_shut_eyes_are_cut_against_their_lids_at_rest():
    import types

    from lsr.data.synth import render_video
    from lsr.eval.part_regions import driver_eye_inputs

    clip = render_video(44, 8, 256)  # open, closing, shut, shut, opening, open ...
    sequence = types.SimpleNamespace(driver_frames=clip.frames, driver_landmarks=clip.landmarks)
    (inputs,) = driver_eye_inputs([sequence])
    eyes = inputs["driver_eyes"]
    assert len(eyes) == 8 and eyes[0] is None and eyes[7] is None
    assert eyes[2] is not None and eyes[2].strength == pytest.approx(1.0)  # the lids at rest: the faces ahead's
