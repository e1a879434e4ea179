"""Fixtures of the deploy tests: ``web``, the web runtime's library (deploy/web) built for Node, to compare each
browser step with its Python reference: ``web.call("cropTransform", points, 256)``. numpy arrays go over as tensors
and come back as numpy. Skips without Node.js and npm."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
from typing import Any

import numpy as np
import pytest

import numpy as np

DTYPES = {"uint8": np.uint8, "int32": np.int32, "float32": np.float32, "float64": np.float64}


def _encode(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        if array.dtype.name not in DTYPES:
            array = array.astype(np.float64)
        return {"__tensor__": base64.b64encode(array.astype(array.dtype.newbyteorder("<")).tobytes()).decode(),
                "dtype": array.dtype.name, "shape": list(array.shape)}
    if isinstance(value, (list, tuple)):
        return [_encode(item) for item in value]
    if isinstance(value, dict):
        return {key: _encode(item) for key, item in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict) and "__tensor__" in value:
        data = np.frombuffer(base64.b64decode(value["__tensor__"]), DTYPES[value["dtype"]])
        return data.reshape(value["shape"]).copy()
    if isinstance(value, list):
        return [_decode(item) for item in value]
    if isinstance(value, dict):
        return {key: _decode(item) for key, item in value.items()}
    return value


class WebLibrary:
    """The built Node bundle (``deploy.web_build.ensure_built``)."""

    def __init__(self, bundle) -> None:
        self.bundle = bundle

    def calls(self, *calls: tuple[str, list]) -> list[Any]:
        """Several calls in one Node process: [(function name, [args...]), ...] -> their results."""
        request = json.dumps({"calls": [{"fn": name, "args": _encode(list(args))} for name, args in calls]})
        done = subprocess.run(["node", str(self.bundle)], input=request, capture_output=True, text=True, check=False)
        if done.returncode != 0 or not done.stdout:
            raise RuntimeError(f"node failed ({done.returncode}): {done.stderr[-2000:]}")
        reply = json.loads(done.stdout)
        if "error" in reply:
            raise RuntimeError(reply["error"])
        return _decode(reply["results"])

    def call(self, name: str, *args: Any) -> Any:
        return self.calls((name, list(args)))[0]


@pytest.fixture(scope="session")
def web() -> WebLibrary:
    from deploy.web_build import ensure_built

    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("Node.js and npm are needed for the web runtime's tests")
    return WebLibrary(ensure_built() / "lsr.node.mjs")


@pytest.fixture(scope="module")
def site(tmp_path_factory, web):
    """``lsr export --web``'s site of the shipped default, in a temp folder."""
    from lsr.export.web_site import write_site
    from lsr.weights import resolve_weights

    return write_site(resolve_weights(None), tmp_path_factory.mktemp("web") / "site")


@pytest.fixture(scope="module")
def python_session(site):
    """A factory of Python live sessions (``lsr.core.live_session.LiveSession``, the live tab's) on the site's person and
    scene layers (its 8-bit matte), unmarked: the reference of the browser's output. Its eyes come from the bank the
    site carries (``bank`` "all": ``lsr.export.web_site.read_eye_bank``), its shots' (``bank`` "shots": what the page
    banks for a user's photos) or none (``bank`` "none")."""
    from landmarks.scene.compositing import SceneLayers
    from lsr.core.live_session import LiveSession
    from lsr.export.bundle import cached_bundle
    from lsr.export.web_site import example_subject, read_eye_bank
    from lsr.weights import resolve_weights

    reenactor, subject, _ = example_subject(cached_bundle(resolve_weights(None)), site.k)
    person = site.folder / "person"
    shapes = json.loads((person / "subject.json").read_text())["shapes"]
    matte = np.frombuffer((person / "matte.u8").read_bytes(), np.uint8).reshape(shapes["matte"])
    plate = np.frombuffer((person / "plate.u8").read_bytes(), np.uint8).reshape(shapes["plate"])
    site_bank = read_eye_bank(person)  # the video's frames, as the site holds them

    def session(bank: str = "all", eye_bank=None) -> LiveSession:
        """bank: the scope; eye_bank: the bank of "all" (None: the site's)."""
        subject.banks["all"] = (site_bank if eye_bank is None else eye_bank, None)
        reenactor.bank = bank
        live = LiveSession(reenactor, subject, paste_back=True, smooth=True, with_layout=False, watermark=False)
        live.scene.layers = SceneLayers(matte.astype(np.float32) / 255, plate)
        return live

    return session


@pytest.fixture(scope="session")
def real_shots() -> tuple[np.ndarray, np.ndarray]:
    """10 crops (256 x 256) of frames of the bundled real video (lsr.examples.REAL_SOURCE, every 7th frame) and their
    68 points in crop pixels (the default detector): shots and targets of the reference warps."""
    from landmarks.align import crop_transform, transform_landmarks, warp_to_crop
    from landmarks.detect.registry import make_detector
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_SOURCE

    detector = make_detector()
    frames = [frame for index, frame in enumerate(iter_frames(REAL_SOURCE)) if index % 7 == 0][:10]
    crops, points = [], []
    for frame in frames:
        landmarks = detector.detect_one(frame).landmarks.astype(np.float64)
        matrix = crop_transform(landmarks, 256)
        crops.append(warp_to_crop(frame, matrix, 256))
        points.append(transform_landmarks(landmarks, matrix))
    return np.stack(crops), np.stack(points)


@pytest.fixture(scope="session")
def driver_frames():
    """count -> the first ``count`` frames (count, H, W, 3) of the bundled driver (lsr.examples.REAL_DRIVER)."""
    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_DRIVER

    return lambda count: np.stack([frame for _, frame in zip(range(count), iter_frames(REAL_DRIVER))])


@pytest.fixture(scope="module")
def bundled_drive():
    """indices -> (the bundled source's anchor crop (256, 256, 3), [(driver frame, its 68 points as tracked, the
    target retargeted onto the anchor in crop pixels)] at those frames of the bundled driver), as the live session
    drives it, unsmoothed."""
    from landmarks.align import crop_transform, transform_landmarks
    from landmarks.detect.registry import make_tracker
    from landmarks.motion.retarget_mesh import DriverReference
    from landmarks.motion.retarget_points import retarget_driving
    from landmarks.io.video import iter_frames
    from lsr.core.inputs import load_subject_shots
    from lsr.examples import REAL_DRIVER, REAL_SOURCE

    def drive(indices: tuple[int, ...], crop: int = 256):
        shots = load_subject_shots(REAL_SOURCE, crop, k=8)
        anchor = shots.landmarks[shots.anchor]
        tracker, reference, out = make_tracker("mesh"), DriverReference(), []
        for index, frame in enumerate(iter_frames(REAL_DRIVER)):
            if index > max(indices):
                break
            points = tracker.update(np.ascontiguousarray(frame))
            gaps, _ = reference.lids(points)
            crop_points = transform_landmarks(points, crop_transform(points, crop))
            reference.start(crop_points)
            if index in indices:
                out.append((frame, points, retarget_driving(crop_points, reference.landmarks, anchor, gaps)))
        return shots.frames[shots.anchor], out

    return drive
