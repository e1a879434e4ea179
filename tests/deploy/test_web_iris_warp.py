"""The web runtime's warped eyes (deploy/web/src/iris_warp.ts, gaze.ts, references.ts) against landmarks.parts.eyes.iris_shift,
landmarks.parts.eyes.iris, lsr.core.finish and landmarks.warp.tps.warp_references; the site's eyes (lsr.export.web_site)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from landmarks.warp import tps
from landmarks.parts.eyes.iris import find_irises, gaze_offsets, retarget_gaze
from landmarks.shape.measures import eye_axes
from landmarks.parts.eyes.iris_shift import _eye_box, align_irises, iris_along
from landmarks.shape.mesh68 import MAPPING_FILE
from lsr.core import finish as parts

SIDE = 256  # the side of conftest.py's real_shots
ASSETS = str(MAPPING_FILE.parent)  # landmarks/assets: the iris net the page's tracker runs


def _psnr(first: np.ndarray, second: np.ndarray) -> float:
    error = np.mean((first.astype(np.float64) - second.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else float(10 * np.log10(255**2 / error))


@pytest.fixture(scope="module")
def irises_of_shots(real_shots) -> np.ndarray:
    """The first 8 real shots' iris centres (K, 2, 2) as the engine finds them (lsr.core.finish.shot_irises)."""
    crops, points = real_shots
    return parts.shot_irises(crops[:8], points[:8])


def _target_gaze(real_shots, index: int, along: float = 0.1) -> np.ndarray:
    """Shot ``index``'s own gaze (its irises by the iris net), moved ``along`` eye widths along the corner line."""
    crops, points = real_shots
    gaze = gaze_offsets(find_irises(crops[index], points[index]), points[index])
    gaze[:, 0] += along
    return gaze


def _eye_pixels(images: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """(N, S, S, 3) -> (N, P): the pixels of both eyes' boxes that the irises' warps may change."""
    boxes = [_eye_box(*eye_axes(landmarks, eye)) for eye in range(2)]
    return np.concatenate([images[:, y0:y1, x0:x1].reshape(len(images), -1) for x0, y0, x1, y1 in boxes], axis=1)


def test_references_with_irises_match_python(web, real_shots, irises_of_shots):
    """The shots' irises carried to a gaze (the target's own, moved aside), and with no gaze to the nearest shot's:
    the same references and masks as Python's, and inside the eyes not those without irises."""
    crops, points = real_shots
    shots, shot_points = crops[:8], points[:8]
    gaze = _target_gaze(real_shots, 8)
    half = gaze.copy()
    half[1] = np.nan  # one eye's gaze not known: there the nearest shot's iris leads
    cases = [(points[8], gaze, 8), (points[8], None, 8), (points[9], half, 8), (points[9], gaze, 3)]
    results = web.calls(*(("warpReferences", [shots[:k], shot_points[:k], target, 5, 4, irises_of_shots[:k], g])
                          for target, g, k in cases),
                        ("warpReferences", [shots, shot_points, points[8], 5]))
    for (target, g, k), got in zip(cases, results):
        warped, masks, indices = tps.warp_references(shots[:k], shot_points[:k], target, 5, irises=irises_of_shots[:k],
                                                     gaze=g)
        assert got["indices"] == indices.tolist()
        assert got["warped"].shape == (5, SIDE, SIDE, 3) and got["warped"].dtype == np.uint8
        values = [_psnr(a, b) for a, b in zip(warped, got["warped"])]
        eyes = [_psnr(a, b) for a, b in zip(_eye_pixels(warped, target), _eye_pixels(got["warped"], target))]
        print(f"gaze {'none' if g is None else np.round(g[:, 0], 3).tolist()}, K = {k}: PSNR against Python (dB) "
              f"{np.round(values, 1).tolist()}, in the eyes {np.round(eyes, 1).tolist()}")
        assert min(values) >= 40 and min(eyes) >= 40, (values, eyes)
        assert np.mean(masks == got["masks"]) >= 0.99
    # the irises moved: inside the eyes the warps are not those without irises (Python's and the page's alike)
    plain, moved = results[-1]["warped"], results[0]["warped"]
    inside = [_psnr(a, b) for a, b in zip(_eye_pixels(plain, points[8]), _eye_pixels(moved, points[8]))]
    assert max(inside) < 35, inside


def test_align_irises_moves_an_iris_as_python(web, real_shots):
    """Synthetic maps (the identity, and a smooth bend) and a rolled eye: the bent maps and where the irises land."""
    points = real_shots[1][8]
    centre, axis, width = eye_axes(points, 0)
    ys, xs = np.mgrid[0:SIDE, 0:SIDE].astype(np.float32)
    identity = (xs.copy(), ys.copy())
    bent = (xs + 2.0 * np.sin(ys / 23.0).astype(np.float32), ys + 1.5 * np.cos(xs / 31.0).astype(np.float32))
    irises = np.full((2, 2, 2), np.nan)
    irises[0, 0] = centre + 0.05 * width * axis
    irises[1, 0] = centre - 0.08 * width * axis
    irises[0, 1] = eye_axes(points, 1)[0]
    irises[1, 1] = eye_axes(points, 1)[0] + [1.5, 0.5]
    angle = np.deg2rad(18)  # a rolled head: the eye's axis is not the image's
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    rolled = (points - 128) @ rotation.T + 128
    cases = [(irises, points, np.array([[0.1, 0.0], [np.nan, np.nan]])), (irises, points, None),
             (((irises - 128) @ rotation.T + 128), rolled, np.array([[-0.12, 0.0], [0.07, 0.0]]))]
    maps = [identity, bent]
    got = web.calls(*(("alignIrises", [[{"mapX": x, "mapY": y} for x, y in maps], shot_irises, landmarks, gaze])
                      for shot_irises, landmarks, gaze in cases))
    for (shot_irises, landmarks, gaze), result in zip(cases, got):
        expected = align_irises(maps, shot_irises, landmarks, gaze)
        for (map_x, map_y), pair in zip(expected, result):
            np.testing.assert_allclose(pair["mapX"], map_x, atol=2e-3)
            np.testing.assert_allclose(pair["mapY"], map_y, atol=2e-3)
        changed = [not np.array_equal(pair["mapX"], x) for pair, (x, _) in zip(result, maps)]
        assert any(changed)
        for eye in range(2):  # every found iris lands where the gaze (or the first reference's) says
            landed = [iris_along(pair["mapX"], pair["mapY"], shot_irises[k, eye], landmarks, eye)
                      for k, pair in enumerate(result)]
            wanted = gaze[eye, 0] if gaze is not None and np.isfinite(gaze[eye, 0]) else landed[0]
            np.testing.assert_allclose(landed, wanted, atol=0.01)
    # where a shot's iris was not found, its map stays as it was; with no iris found nothing moves
    none = web.call("alignIrises", [{"mapX": identity[0], "mapY": identity[1]}], np.full((1, 2, 2), np.nan), points,
                    None)
    np.testing.assert_array_equal(none[0]["mapX"], identity[0])


def test_gaze_and_driver_gaze_match_python(web, real_shots, monkeypatch):
    """gazeOffsets, retargetGaze and DriverGaze (its aperture history, the closing eye, the relative reference and a
    recentre) over a sequence longer than its history, within 1e-9."""
    rng = np.random.default_rng(7)
    count = 170
    landmarks = real_shots[1][np.arange(count) % 10] + rng.normal(0, 0.3, (count, 68, 2))
    irises = np.zeros((count, 2, 4))
    for t in range(count):
        for eye in range(2):
            centre, axis, width = eye_axes(landmarks[t], eye)
            along, across = rng.uniform(-0.15, 0.15), rng.uniform(-0.08, 0.08)
            irises[t, eye, :2] = centre + width * (along * axis + across * np.array([-axis[1], axis[0]]))
            irises[t, eye, 2:] = [0.2 * width, 0.3 + 0.1 * t / count + rng.normal(0, 0.01)]
    irises[[20, 21, 90], 0, 3] = 0.15  # the left eye closing: no gaze there
    irises[40] = np.nan  # no irises found
    irises[41, 1] = np.nan
    # where the tracker's irises are not all found Python's DriverGaze looks again (find_irises), and the page's
    # tracker side does (gaze.ts trackedIrises): here neither finds any
    monkeypatch.setattr(parts, "find_irises", lambda frame, points: np.full((2, 4), np.nan))
    looked = irises.copy()
    looked[~np.isfinite(irises).all(axis=(1, 2))] = np.nan
    source = np.array([[0.04, -0.1], [np.nan, -0.09]])  # the anchor's gaze, its right eye's along not found
    recentre = [100]
    expected = {}
    for name, anchor in (("absolute", None), ("relative", source)):
        gazes, driver = [], parts.DriverGaze(anchor)
        for t in range(count):
            if t in recentre:
                driver.reference = None
            gazes.append(driver(None, landmarks[t], irises[t]))
        expected[name] = np.stack(gazes)
    opened = np.array([0.32, 0.31])
    got = web.calls(("driverGazes", [None, looked, landmarks, recentre]),
                    ("driverGazes", [source, looked, landmarks, recentre]),
                    *(("gazeOffsets", [irises[t], landmarks[t], opened]) for t in (0, 20, 40)),
                    ("retargetGaze", [irises[0, :, :2].ravel(), source.ravel() * 2, source.ravel()]))
    np.testing.assert_allclose(got[0], expected["absolute"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got[1], expected["relative"], rtol=0, atol=1e-9)
    assert np.isnan(expected["relative"][[20, 40, 41]]).all(axis=(1, 2)).tolist() == [False, True, True]
    assert np.isnan(expected["relative"][20, 0]).all() and np.isfinite(expected["relative"][100]).all()
    for t, offsets in zip((0, 20, 40), got[2:5]):
        np.testing.assert_allclose(offsets.reshape(2, 2), gaze_offsets(irises[t], landmarks[t], opened), atol=1e-9)
    np.testing.assert_allclose(got[5].reshape(2, 2), retarget_gaze(irises[0, :, :2], source * 2, source), atol=1e-12)


def test_shot_irises_match_python(web, real_shots, monkeypatch):
    """Each shot's irises by the page's iris net (as encode.ts finds them) against lsr.core.finish.shot_irises, and
    the closing rule against the median aperture on given irises."""
    crops, points = real_shots
    got = web.call("shotIrisesFromAssets", ASSETS, crops[:8], points[:8])
    expected = np.stack([find_irises(crop, p) for crop, p in zip(crops[:8], points[:8])])
    np.testing.assert_array_equal(np.isnan(got["irises"]), np.isnan(expected))
    np.testing.assert_allclose(got["irises"], expected, atol=0.01, equal_nan=True)
    centres = parts.shot_irises(crops[:8], points[:8])
    np.testing.assert_array_equal(np.isnan(got["centres"]), np.isnan(centres))
    np.testing.assert_allclose(got["centres"], centres, atol=0.01, equal_nan=True)

    given = np.tile(expected[:1], (6, 1, 1))
    given[:, :, 3] = [[0.3, 0.31], [0.2, 0.32], [np.nan, 0.3], [0.29, 0.1], [0.31, np.nan], [0.33, 0.3]]
    given[5, 1, :2] = np.nan
    for rows in (given, np.full((3, 2, 4), np.nan)):
        monkeypatch.setattr(parts, "find_irises", lambda frame, landmarks, rows=rows: rows[int(frame)])
        reference = parts.shot_irises(np.arange(len(rows)), np.zeros((len(rows), 68, 2)))
        centres = web.call("shotIrisCentres", rows)
        np.testing.assert_array_equal(centres.reshape(-1, 2, 2), reference)


@pytest.mark.slow
def test_the_site_carries_warped_eyes(site):
    """site.json says eyes "warped"; subject.json holds the shots' irises and the anchor's gaze (null: not found)."""
    config = json.loads((site.folder / "site.json").read_text())
    assert config["eyes"] == "warped"
    subject = json.loads((site.folder / "person" / "subject.json").read_text())
    shot_irises = np.array(subject["shot_irises"], np.float64)  # None -> NaN
    anchor_gaze = np.array(subject["anchor_gaze"], np.float64)
    assert shot_irises.shape == (site.k, 2, 2) and anchor_gaze.shape == (2, 2)
    shots = np.frombuffer((site.folder / "person" / "shots.u8").read_bytes(), np.uint8).reshape(subject["shapes"]["shots"])
    landmarks = np.array(subject["shot_landmarks"], np.float64)
    np.testing.assert_allclose(shot_irises, parts.shot_irises(shots, landmarks), atol=1e-4, equal_nan=True)
    anchor = subject["anchor"]
    np.testing.assert_allclose(anchor_gaze, gaze_offsets(find_irises(shots[anchor], landmarks[anchor]),
                                                         landmarks[anchor]), atol=1e-6, equal_nan=True)
    assert np.isfinite(shot_irises).any()
