"""The web runtime's WebAssembly kernels (deploy/web/src/wasm.ts, remap_wasm.ts, tps_wasm.ts, blur_wasm.ts) against the
JavaScript they stand in for (remap.ts, tps.ts, composite.ts): the same bytes out, for the splines, the warps, the
blurs and the composite
(``useWebAssembly`` turns them off and on within one Node process)."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.scene import compositing as scene_module


def _both(web, name: str, *args):
    """(the JavaScript's result, the WebAssembly's) of one library call."""
    _, javascript, _, webassembly = web.calls(("useWebAssembly", [False]), (name, list(args)),
                                              ("useWebAssembly", [True]), (name, list(args)))
    return javascript, webassembly


def test_the_kernels_run_in_node(web):
    """Node 20 has WebAssembly SIMD: the comparisons below compare the kernels, not JavaScript with itself."""
    assert web.calls(("remapsInWasm", []), ("splinesInWasm", [])) == [True, True]


def test_splines_are_the_javascripts_at_every_kind_of_distance(web, rng):
    """The kernel row U(r) = r^2 log r^2 (the weights pick it out column by column) where the log's reduction turns:
    powers of two, about sqrt(2), within 2^-20 of one and just past it, tiny, huge, zero, and anywhere."""
    control = rng.uniform(-2, 2, (7, 2))
    offsets = [1.0, 2.0, 0.5, 2.0**-30, 1 + 2.0**-22, 1 - 2.0**-22, 1 + 2.0**-19, 1 - 2.0**-19, 2.0**-530, 1e-160, 1e150,
               0.0, np.sqrt(2.0), 3.0]
    points = [control[k % 7] + [np.sqrt(offset), 0.0] for k, offset in enumerate(offsets)]
    points += list(control[:3]) + list(rng.uniform(-3, 3, (200, 2))) + list(rng.uniform(-1e-3, 1e-3, (50, 2)))
    points = np.asarray(points, np.float64)
    one_hot = np.eye(7, 8)  # an odd count of control points; column 7 all zero
    for columns in (8, 2, 5):
        weights, affine = one_hot[:, :columns], rng.normal(size=(3, columns)) * (columns != 8)
        javascript, webassembly = _both(web, "splineAt", control, weights, affine, [0.25, -0.5], 1.5, points)
        np.testing.assert_array_equal(webassembly, javascript)
        assert np.isfinite(javascript[: len(offsets) - 3]).all()


def test_the_splines_log_is_within_an_ulp_of_the_platforms(web, rng):
    """tps_wasm.ts splineLog (fdlibm's reduction and polynomial, one path for every value, as its kernel computes it
    two lanes at a time) against libm's log, from 1e-300 to 1e300, about one and about sqrt(2)."""
    values = np.concatenate([np.exp(rng.uniform(-690, 690, 4000)), 1 + rng.uniform(-1e-3, 1e-3, 500),
                             np.sqrt(2.0) * (1 + rng.uniform(-1e-6, 1e-6, 500)), [1.0, 2.0, 0.5, np.sqrt(2.0), 1e-300]])
    got = np.asarray(web.calls(*[("splineLog", [float(v)]) for v in values]), np.float64)
    want = np.log(values)
    assert (np.abs(got - want) <= np.spacing(np.abs(want)) * 1.01 + (want == 0)).all()
    assert np.mean(got == want) > 0.95  # most are the same value


def test_blurs_are_the_javascripts(web, rng):
    """blur_wasm.ts (cv2.GaussianBlur's two passes two values at a time) against remap.ts's loops: one to four channels,
    odd and even sizes, kernels wider than the image (reflect-101 all the way), and the composite's shrunk blur."""
    for shape, sigma in [((37, 29), 2.0), ((8, 5), 3.0), ((16, 31, 3), 1.2), ((21, 14, 4), 5.5), ((9, 12, 2), 0.7),
                         ((61, 47, 4), 20.0), ((3, 1), 0.5)]:
        values = rng.normal(size=shape).astype(np.float32)
        javascript, webassembly = _both(web, "sceneBlur", values, sigma)
        np.testing.assert_array_equal(webassembly, javascript)


def test_spline_maps_are_the_javascripts(web, real_shots):
    """tpsMaps of one to five shots onto a target (2 to 10 columns of the shared spline) on grids of steps 1 to 5."""
    crops, points = real_shots
    for count, step in [(1, 4), (2, 1), (3, 5), (4, 4), (5, 3)]:
        sets = [points[k] for k in range(count)]
        javascript, webassembly = _both(web, "tpsMaps", sets, points[8], 256, 256, {"gridStep": step})
        for first, second in zip(javascript, webassembly):
            assert first["method"] == second["method"]
            np.testing.assert_array_equal(second["mapX"], first["mapX"])
            np.testing.assert_array_equal(second["mapY"], first["mapY"])


def test_warps_are_the_javascripts(web, real_shots):
    """The nearest shots' references, plain and with their irises carried to a gaze (or to the nearest shot's), with
    repeats of fewer shots: the same warped shots, masks and indices."""
    from lsr.core import finish as parts

    crops, points = real_shots
    shots, shot_points = crops[:8], points[:8]
    irises = parts.shot_irises(shots, shot_points)
    gaze = np.array([[0.08, 0.0], [np.nan, np.nan]])
    cases = [(shots, shot_points, points[8], 5, 4, None, None), (shots, shot_points, points[9], 5, 4, irises, gaze),
             (shots[:3], shot_points[:3], points[8], 5, 4, irises[:3], None),
             (shots, shot_points, points[9] * 0.5 + 40, 4, 2, None, None)]
    for case in cases:
        javascript, webassembly = _both(web, "warpReferences", *case)
        assert webassembly["indices"] == javascript["indices"]
        np.testing.assert_array_equal(webassembly["warped"], javascript["warped"])
        np.testing.assert_array_equal(webassembly["masks"], javascript["masks"])


def test_remaps_are_the_javascripts_at_every_border(web, rng):
    """The bicubic kernel (float32 lanes, the replicated border in the kernel, the other borders and far-off or NaN
    positions left to remap.ts) against remap.ts alone, on positions inside, at the edges to the last float32 below
    them, just outside, far outside and undefined; and both against OpenCV within a grey level up to 6 pixels outside
    (further out OpenCV 5 reflects otherwise: remap.ts borderIndex)."""
    import cv2

    height, width = 19, 23
    image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    below = lambda value: float(np.nextafter(np.float32(value), np.float32(-np.inf)))  # noqa: E731
    edges = [1.0, below(1.0), width - 2.0, below(width - 2.0), height - 2.0, below(height - 2.0), 0.0, -1e-30, -0.5,
             -1.0, -2.5, width - 1.0, width + 0.25, height + 3.5, -40.0, 60.0, 9.99e6, -9.99e6, 1e7, -2e8]
    xs = np.concatenate([rng.uniform(-6, width + 6, 3000), edges, rng.uniform(1, width - 2, 500), [np.nan, 5.0, np.inf]])
    ys = np.concatenate([rng.uniform(-6, height + 6, 3000), edges[::-1], rng.uniform(1, height - 2, 500),
                         [3.0, np.nan, 2.0]])
    map_x, map_y = xs.astype(np.float32), ys.astype(np.float32)
    modes = {"replicate": cv2.BORDER_REPLICATE, "reflect": cv2.BORDER_REFLECT, "reflect101": cv2.BORDER_REFLECT_101,
             "constant": cv2.BORDER_CONSTANT}
    for border, code in modes.items():
        javascript, webassembly = _both(web, "remapImage", image, map_x, map_y, border)
        np.testing.assert_array_equal(webassembly, javascript)
        near = (map_x >= -6) & (map_x <= width + 6) & (map_y >= -6) & (map_y <= height + 6)
        opencv = cv2.remap(image, map_x[near][None], map_y[near][None], cv2.INTER_CUBIC, borderMode=code)[0]
        apart = np.abs(opencv.astype(int) - javascript[near].astype(int))
        assert apart.max() <= 1 and (apart == 0).mean() > 0.999, (border, apart.max(), (apart == 0).mean())


@pytest.fixture(scope="module")
def real_frames() -> tuple[np.ndarray, np.ndarray]:
    """Two frames of the bundled real video (360 x 288) and their 68 points (the default detector)."""
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    detector = make_detector()
    frames = [frame for index, frame in enumerate(iter_frames(REAL_SOURCE)) if index in (0, 40)]
    return np.stack(frames), np.stack([detector.detect_one(frame).landmarks.astype(np.float64) for frame in frames])


def test_the_composite_is_the_javascripts(web, real_frames):
    """A head moved in the frame with a person matte and plate and without, moved until its box is cut by the frame's
    edge (the edge fade), and small: the same frame and face alpha."""
    from landmarks.align import crop_transform, warp_to_crop

    frames, landmarks = real_frames
    scene, points = frames[0], landmarks[0]
    matrix = crop_transform(landmarks[1], 256)
    face = warp_to_crop(frames[1], matrix, 256)
    centre = points.mean(0)
    turned = (points - centre) @ np.array([[0.99, -0.1], [0.1, 0.99]]).T + centre + [6.0, -4.0]
    matte = np.clip(1.2 - np.hypot(*((np.mgrid[0:288, 0:360][::-1] - centre[:, None, None]) / 90.0)), 0, 1)
    layers = scene_module.background_plate(scene, points, matte.astype(np.float32))
    layer_args = [{"matte": layers.matte, "plate": layers.plate}]
    cases = [(turned, layer_args), (turned, []), (points + [70.0, 40.0], layer_args),
             ((points - centre) * 0.5 + centre + [-3.0, 2.0], [])]
    for target, extra in cases:
        javascript, webassembly = _both(web, "compositeFace", scene, points, target, face,
                                        list(crop_transform(target, 256).ravel()), *extra)
        assert webassembly["box"] == javascript["box"]
        np.testing.assert_array_equal(webassembly["frame"], javascript["frame"])
        np.testing.assert_array_equal(webassembly["faceAlpha"], javascript["faceAlpha"])
