"""The shipped MediaPipe nets: provenance record, licence files, packaging, and a rebuild from the wheel.

The rebuild tests need the pinned MediaPipe wheel (``LSR_MEDIAPIPE_WHEEL``, /tmp/mp, or pip's cache) and the
``convert`` extra (tflite, ai-edge-litert); they skip, with the reason, when either is missing.
"""

from __future__ import annotations

import fnmatch
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from landmarks.detect import rebuild_mediapipe as cm
from landmarks.detect import mediapipe_mesh as mesh
from landmarks.scene import person_matte as segment

WHEEL_BYTES = 35_622_638  # size of the pinned wheel: finds it among pip's cache entries without hashing them all


def _pinned(path: Path) -> bool:
    return path.is_file() and path.stat().st_size == WHEEL_BYTES and cm.sha256_file(path) == cm.WHEEL_SHA256


def _pip_cache_candidates() -> list[Path]:
    """pip's HTTP cache keeps each download's body as a file of its own; find ours by size."""
    try:
        result = subprocess.run([sys.executable, "-m", "pip", "cache", "dir"], capture_output=True, text=True,
                                timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return []
    cache = Path(result.stdout.strip()) if result.returncode == 0 else None
    if cache is None or not cache.is_dir():
        return []
    found = []
    for folder, _, names in os.walk(cache):
        found += [Path(folder) / name for name in names if (Path(folder) / name).stat().st_size == WHEEL_BYTES]
    return found


@pytest.fixture(scope="module")
def wheel() -> Path:
    given = os.environ.get("LSR_MEDIAPIPE_WHEEL")
    if given:
        if not _pinned(Path(given)):
            pytest.skip(f"LSR_MEDIAPIPE_WHEEL={given} is not the pinned {cm.WHEEL_NAME} (sha256 {cm.WHEEL_SHA256})")
        return Path(given)
    for candidate in [Path("/tmp/mp") / cm.WHEEL_NAME, *_pip_cache_candidates()]:
        if _pinned(candidate):
            return candidate
    pytest.skip(f"{cm.WHEEL_NAME} not found (set LSR_MEDIAPIPE_WHEEL, or put it in /tmp/mp)")


@pytest.fixture(scope="module")
def convert_tools() -> None:
    pytest.importorskip("tflite", reason="the converter needs the tflite package (pip install '.[convert]')")
    pytest.importorskip("ai_edge_litert", reason="the check needs ai-edge-litert (pip install '.[convert]')")


@pytest.fixture(scope="module")
def rebuilt(wheel: Path, convert_tools: None, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The whole conversion + check into a temp folder, on 3 frames of one shared clip (random image without)."""
    out = tmp_path_factory.mktemp("mediapipe")
    cm.convert_wheel(wheel, out, cm.default_frames()[:1], frames_per_video=3)
    return out


def _strings(value: object) -> list[str]:
    if isinstance(value, dict):
        return [s for item in value.values() for s in _strings(item)]
    if isinstance(value, list):
        return [s for item in value for s in _strings(item)]
    return [value] if isinstance(value, str) else []


class TestShippedFiles:
    def test_sources_match_the_onnx_files(self):
        record = mesh.sources()
        assert record["source"]["sha256"] == cm.WHEEL_SHA256 and record["source"]["version"] == cm.VERSION
        shipped = sorted((mesh.DETECTOR_FILE, mesh.MESH_FILE, mesh.IRIS_FILE, segment.SEGMENTER_FILE))
        assert sorted(entry["onnx"] for entry in record["models"]) == shipped
        for entry in record["models"]:
            path = mesh.ASSETS / entry["onnx"]
            assert cm.sha256_file(path) == entry["onnx_sha256"], f"{path.name} is not the file SOURCES.json records"
            assert path.stat().st_size == entry["onnx_bytes"]
            assert len(entry["tflite_sha256"]) == 64 and entry["tflite"].endswith(".tflite")

    def test_graphs_use_only_fast_onnxruntime_ops(self):
        """PReLU is lowered to relu(x) - slope * relu(-x): onnxruntime's PRelu kernel took 60 % of the mesh net."""
        onnx = pytest.importorskip("onnx")
        for name in (mesh.DETECTOR_FILE, mesh.MESH_FILE, mesh.IRIS_FILE):
            ops = {node.op_type for node in onnx.load(str(mesh.ASSETS / name)).graph.node}
            assert "PRelu" not in ops and ops <= {"Conv", "Relu", "Neg", "Mul", "Sub", "Add", "MaxPool", "Pad",
                                                  "Transpose", "Identity", "Reshape", "Concat", "Sigmoid"}, ops

    def test_license_and_notice(self):
        record = mesh.sources()
        license_file = mesh.ASSETS / "LICENSE"
        assert cm.sha256_file(license_file) == record["source"]["license"]["sha256"]
        assert "Apache License" in license_file.read_text()
        notice = (mesh.ASSETS / "NOTICE").read_text()
        assert notice == cm.NOTICE and "MediaPipe 0.10.21" in notice and "Apache License" in notice

    def test_check_passed_within_tolerance_and_no_machine_paths(self):
        record = mesh.sources()
        worst = record["check"]["max"]
        assert worst["mesh_point_px"] <= cm.POINT_TOLERANCE and worst["iris_point_px"] <= cm.POINT_TOLERANCE
        assert worst["detection_score"] <= cm.SCORE_TOLERANCE and worst["presence_score"] <= cm.SCORE_TOLERANCE
        assert worst["matte"] <= cm.SCORE_TOLERANCE
        assert [m["onnx"] for m in record["models"]] == [name for _, name in cm.MODELS]
        assert not [s for s in _strings(record) if s.startswith("/") or "/work/" in s or "/tmp/" in s]

    def test_package_data_ships_every_asset(self):
        """pyproject's globs (setuptools: ``*`` stays inside one folder) cover every file in the assets folder."""
        tomllib = pytest.importorskip("tomllib", reason="reading pyproject.toml needs Python >= 3.11")
        config = tomllib.loads((Path(__file__).resolve().parents[3] / "pyproject.toml").read_text())
        patterns = config["tool"]["setuptools"]["package-data"]["landmarks"]
        package = mesh.ASSETS.parents[1]
        for path in mesh.ASSETS.iterdir():
            parts = path.relative_to(package).parts
            assert any(len(p.split("/")) == len(parts) and all(map(fnmatch.fnmatch, parts, p.split("/")))
                       for p in patterns), f"{path.name} would not be installed by pip install ."


class TestWithoutWheel:
    def test_unpinned_wheel_is_refused_in_one_line(self, tmp_path, capsys):
        from lsr.cli import main

        fake = tmp_path / cm.WHEEL_NAME
        fake.write_bytes(b"not the wheel")
        code = main(["face-models", "convert", "--wheel", str(fake), "--out", str(tmp_path / "out")])
        message = capsys.readouterr().err.strip()
        assert code != 0 and message.startswith("lsr: error:") and "sha256" in message and "\n" not in message
        assert not (tmp_path / "out").exists()

    def test_missing_frames_are_refused_before_work(self, tmp_path):
        with pytest.raises(cm.InputFileError, match="no such video"):
            cm.convert_wheel(tmp_path / "absent.whl", tmp_path / "out", [tmp_path / "absent.mp4"])

    def test_record_paths_are_relative(self):
        assert cm.display_path(Path("/somewhere/else/clip.mp4")) == "clip.mp4"
        assert cm.display_path(cm.REPO_ROOT / "landmarks" / "detect" / "mediapipe_mesh.py") == "landmarks/detect/mediapipe_mesh.py"
        assert cm.display_path(cm.REPO_ROOT.parent / "shared" / "data" / "x.mp4") == "../shared/data/x.mp4"


class TestRebuildFromWheel:
    def test_rebuild_is_byte_identical_to_the_shipped_files(self, rebuilt):
        for name in (mesh.DETECTOR_FILE, mesh.MESH_FILE, mesh.IRIS_FILE, segment.SEGMENTER_FILE, "LICENSE", "NOTICE"):
            assert cm.sha256_file(rebuilt / name) == cm.sha256_file(mesh.ASSETS / name), name
        record = json.loads((rebuilt / "SOURCES.json").read_text())
        assert record["models"] == mesh.sources()["models"]
        assert record["check"]["max"]["mesh_point_px"] <= cm.POINT_TOLERANCE
        assert record["check"]["max"]["iris_point_px"] <= cm.POINT_TOLERANCE

    def test_failed_check_writes_nothing(self, wheel, convert_tools, tmp_path, monkeypatch):
        monkeypatch.setattr(cm, "POINT_TOLERANCE", 0.0)  # any real difference now fails
        with pytest.raises(cm.ParityError, match="mesh points differ"):
            cm.convert_wheel(wheel, tmp_path / "out", [], frames_per_video=1)
        assert not (tmp_path / "out").exists()

    def test_unknown_op_is_refused_by_name(self, wheel, tmp_path):
        """The full-range detector stores sparse weights behind DENSIFY, which the converter does not translate."""
        pytest.importorskip("tflite", reason="the converter needs the tflite package (pip install '.[convert]')")
        from landmarks.detect.tflite_onnx import ConversionError, convert

        sparse = tmp_path / "face_detection_full_range_sparse.tflite"
        sparse.write_bytes(cm.read_member(wheel, "mediapipe/modules/face_detection/face_detection_full_range_sparse.tflite"))
        with pytest.raises(ConversionError, match="DENSIFY"):
            convert(sparse)

    def test_the_selfie_segmenter_converts_and_matches_its_original(self, wheel, convert_tools, tmp_path):
        """MediaPipe's person segmenter (for a matte of what moves with the head: issue 40, item 4): its squeeze-and-
        excite blocks (HARD_SWISH, LOGISTIC, AVERAGE_POOL_2D, MUL), RESIZE_BILINEAR and the custom transposed
        convolution convert, and the ONNX graph's matte matches the TFLite original's on a real frame."""
        import onnxruntime as ort
        from ai_edge_litert.interpreter import Interpreter

        from landmarks.detect.tflite_onnx import convert
        from landmarks.io.video import iter_frames
        from lsr.examples import REAL_SOURCE

        source = tmp_path / "selfie_segmentation.tflite"
        source.write_bytes(cm.read_member(wheel, "mediapipe/modules/selfie_segmentation/selfie_segmentation.tflite"))
        model = convert(source)
        assert {"HardSwish", "AveragePool", "Resize", "ConvTranspose", "Sigmoid"} <= {n.op_type for n in model.graph.node}
        frame = next(iter(iter_frames(REAL_SOURCE)))
        tensor = (cv2.resize(frame, (256, 256), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0)[None]
        original = Interpreter(model_path=str(source))
        original.allocate_tensors()
        original.set_tensor(original.get_input_details()[0]["index"], tensor)
        original.invoke()
        expected = original.get_tensor(original.get_output_details()[0]["index"])
        session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
        matte = session.run(None, {session.get_inputs()[0].name: tensor})[0]
        assert matte.shape == expected.shape == (1, 256, 256, 1)
        assert np.abs(matte - expected).max() < 1e-3
        person = matte[0, :, :, 0] > 0.5  # the speaker, hair included, against a blue wall
        assert 0.15 < person.mean() < 0.6 and person[200:, 128].all() and not person[:20, :20].any()
