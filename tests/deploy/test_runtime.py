"""deploy.runtime.OnnxReenactor: torch-free (checked in a subprocess where importing torch fails) and at parity with torch."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

skimage_data = pytest.importorskip("skimage.data")
REPO_ROOT = Path(__file__).resolve().parents[2]


def face_frame(shift: int = 0) -> np.ndarray:
    return np.ascontiguousarray(skimage_data.astronaut()[20:276, 100 - shift : 356 - shift])


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    """A tiny random model (latent_layout variant, so the frame graph has the layout output) and its ONNX bundle."""
    import torch

    from lsr.export.bundle import export_graphs
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("bundle")
    model = LSRModel(preset_config("tiny")).eval()
    model.save_pretrained(folder / "weights")
    export_graphs(model, folder / "onnx")
    return folder


def test_bundle_metadata(bundle):
    import onnx

    for name in ("subject_encoder.onnx", "frame_generator.onnx"):
        model = onnx.load(str(bundle / "onnx" / name))
        props = {p.key: p.value for p in model.metadata_props}
        assert props["preset"] == "tiny" and props["resolution"] == "64" and props["layout_kind"] == "latent"
        assert props["landmark_format"] == "ibug68-contour-rgb" and props["lsr_version"]
        assert model.opset_import[0].version == 17
    outputs = [o.name for o in onnx.load(str(bundle / "onnx" / "frame_generator.onnx")).graph.output]
    assert outputs == ["image", "layout"]


def test_torch_onnx_parity_fp32(bundle, rng):
    """Both graphs: subject encoder with K=3 (dynamic K) and frame generator with B=2 (dynamic batch), within 1e-4."""
    from deploy.runtime import OnnxBackend
    from lsr.pipeline import Reenactor

    torch_backend = Reenactor(bundle / "weights").backend
    onnx_backend = OnnxBackend(bundle / "onnx")
    shots = rng.uniform(-1, 1, (1, 3, 3, 64, 64)).astype(np.float32)
    shot_landmarks = rng.uniform(-1, 1, (1, 3, 3, 64, 64)).astype(np.float32)
    for a, b in zip(torch_backend.encode_subject(shots, shot_landmarks), onnx_backend.encode_subject(shots, shot_landmarks)):
        np.testing.assert_allclose(a, b, atol=1e-4, rtol=0)
    landmark_image = rng.uniform(-1, 1, (2, 3, 64, 64)).astype(np.float32)
    latents = [rng.standard_normal((2, 16)).astype(np.float32) for _ in range(2)]
    torch_image, torch_layout = torch_backend.synthesize(landmark_image, *latents, True)
    onnx_image, onnx_layout = onnx_backend.synthesize(landmark_image, *latents, True)
    np.testing.assert_allclose(onnx_image, torch_image, atol=1e-4, rtol=0)
    np.testing.assert_allclose(onnx_layout, torch_layout, atol=1e-4, rtol=0)


def test_missing_bundle_is_a_clear_error(bundle, tmp_path):
    from deploy.runtime import BundleError, OnnxReenactor

    with pytest.raises(BundleError, match="subject_encoder.onnx not found.*lsr export"):
        OnnxReenactor(tmp_path)
    with pytest.raises(BundleError, match="frame_generator.int8.onnx not found.*--int8"):
        OnnxReenactor(bundle / "onnx", int8=True)


TORCH_FREE_SCRIPT = r"""
import importlib.abc, json, sys

class NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch.") or name in ("torchvision", "kornia"):
            raise ImportError(f"{name} is blocked: deploy must run without torch")
        return None

sys.meta_path.insert(0, NoTorch())
import numpy as np
from deploy.runtime import OnnxReenactor

bundle, image_path, driver_path = sys.argv[1:4]
from landmarks.io.image_files import read_image
reenactor = OnnxReenactor(bundle)
subject = reenactor.encode_subject(read_image(image_path))
frames = list(reenactor(driver_path, landmark_space="crop", mode="absolute", smooth=False))
loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith(("torch.", "lsr", "models_def"))
                and m != "lsr" and not m.startswith("lsr.core"))  # the inference core is torch-free and shared
print(json.dumps({"frames": len(frames), "shape": list(frames[0].image.shape), "loaded": loaded,
                  "metadata": reenactor.metadata["preset"], "sum": int(sum(int(f.image.sum()) for f in frames))}))
"""


def test_runtime_runs_where_torch_cannot_be_imported(bundle, tmp_path):
    from landmarks.io.image_files import write_image
    from lsr.pipeline import Reenactor

    image = tmp_path / "face.png"
    write_image(image, face_frame(0))
    reference = Reenactor(bundle / "weights")
    subject = reference.encode_subject(image)
    driver = tmp_path / "driver.npy"
    np.save(driver, np.stack([subject.shots.landmarks[0], subject.shots.landmarks[0] + 1.5]))
    expected = sum(int(f.image.sum()) for f in reference(driver, landmark_space="crop", mode="absolute", smooth=False))

    result = subprocess.run(
        [sys.executable, "-c", TORCH_FREE_SCRIPT, str(bundle / "onnx"), str(image), str(driver)],
        cwd=REPO_ROOT, capture_output=True, text=True, env={"PYTHONPATH": str(REPO_ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["loaded"] == [] and report["frames"] == 2 and report["shape"] == [64, 64, 3]
    assert report["metadata"] == "tiny"
    # Same frames as the torch runtime up to uint8 rounding of fp32 differences (< 1 grey level per pixel on average).
    assert abs(report["sum"] - expected) <= 2 * 64 * 64 * 3 * 0.05


def test_example_embed_runs_without_torch(bundle, tmp_path):
    from landmarks.io.image_files import write_image

    sys_path_runner = r"""
import importlib.abc, runpy, sys
class NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch blocked")
sys.meta_path.insert(0, NoTorch())
sys.argv = ["example_embed.py", *sys.argv[1:]]
runpy.run_path("deploy/example_embed.py", run_name="__main__")
"""
    image = tmp_path / "face.png"
    write_image(image, face_frame(0))
    out = tmp_path / "frames"
    result = subprocess.run(
        [sys.executable, "-c", sys_path_runner, str(bundle / "onnx"), str(image), str(image), str(out)],
        cwd=REPO_ROOT, capture_output=True, text=True, env={"PYTHONPATH": str(REPO_ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert len(list(out.glob("*.png"))) == 1


@pytest.mark.slow
def test_int8_bundle_runs_and_reports_error(bundle, tmp_path):
    """`lsr export --int8` path: quantised convolutions present, the int8 graph runs in OnnxReenactor, its error is finite."""
    import shutil

    import onnx

    from lsr.core.engine import to_network
    from deploy.runtime import OnnxReenactor
    from landmarks.shape.raster import draw_landmarks
    from lsr.export.bundle import graph_error, quantize_frame_generator
    from lsr.pipeline import Reenactor

    folder = tmp_path / "onnx"
    shutil.copytree(bundle / "onnx", folder)
    reference = Reenactor(bundle / "weights")
    subject = reference.encode_subject([face_frame(0), face_frame(10)])
    feeds = [{"landmark_image": to_network(draw_landmarks(points + shift, 64))[None],
              "layout_latent": subject.layout_latent, "style_latent": subject.style_latent}
             for points in subject.shots.landmarks for shift in (0.0, 1.0)]
    int8_path = quantize_frame_generator(folder / "frame_generator.onnx", folder / "frame_generator.int8.onnx", feeds)
    assert any(node.op_type == "QLinearConv" for node in onnx.load(str(int8_path)).graph.node)
    max_abs, mean_abs = graph_error(folder / "frame_generator.onnx", int8_path, feeds)
    assert np.isfinite(max_abs) and 0 < mean_abs <= max_abs
    runtime = OnnxReenactor(folder, int8=True)
    runtime.encode_subject(subject.shots)
    frames = list(runtime(subject.shots.landmarks, landmark_space="crop", mode="absolute"))
    assert len(frames) == 2 and frames[0].image.shape == (64, 64, 3)


def test_warp_guided_torch_and_onnx_give_the_same_frames(tmp_path):
    """A warp-guided model: crops at twice its resolution, warps the nearest shots per frame, same output in both runtimes."""
    import torch

    from deploy.runtime import OnnxReenactor
    from lsr.export.bundle import export_graphs
    from lsr.pipeline import Reenactor
    from models_def import LSRModel, preset_config

    torch.manual_seed(0)
    model = LSRModel(preset_config("tiny", variant="warp_guided")).eval()
    model.save_pretrained(tmp_path / "weights")
    export_graphs(model, tmp_path / "onnx")
    source = [face_frame(0), face_frame(10), face_frame(20)]
    outputs = []
    for runtime in (Reenactor(tmp_path / "weights"), OnnxReenactor(tmp_path / "onnx", threads=1)):
        assert runtime.crop_size == 128 and runtime.resolution == 64
        runtime.encode_subject(source)
        driver = runtime.subject.shots.landmarks[::-1] + 2.0
        frames = list(runtime(driver, landmark_space="crop", mode="absolute", smooth=False, with_layout=True))
        assert all(f.image.shape == (128, 128, 3) and f.layout.shape[1:] == (64, 64) for f in frames)
        outputs.append(np.stack([f.image for f in frames]))
    assert np.abs(outputs[0].astype(int) - outputs[1]).max() <= 1


@pytest.mark.slow
def test_export_int8_calibrates_on_the_bundled_example_without_shared_data(tmp_path, monkeypatch, capsys):
    """`lsr export --int8` with no calibration clip given: the bundled example person and driver calibrate it (never an
    evaluation clip), so it works from a clean checkout without ../shared/data."""
    import onnx

    from lsr.cli import main

    monkeypatch.setenv("LSR_SHARED_DATA", str(tmp_path / "absent"))
    assert main(["export", "--int8", "--out", str(tmp_path / "onnx"), "--calibration-frames", "4"]) == 0
    int8_path = tmp_path / "onnx" / "frame_generator.int8.onnx"
    assert any(node.op_type == "QLinearConv" for node in onnx.load(str(int8_path)).graph.node)
    assert re.search(r"over 4 calibration frame\(s\): max abs error [0-9.e-]+", capsys.readouterr().out)
