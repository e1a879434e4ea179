"""LPIPS (lsr.eval.lpips) and FID (lsr.eval.fid) on small self-made weights; both wired into the report."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from lsr.config import EvalConfig
from lsr.errors import ConfigError, WeightsError
from lsr.eval import fid, lpips

# ---- LPIPS ----------------------------------------------------------------------------------------


def _lpips_state(seed: int = 0, torchvision_keys: bool = False) -> dict[str, torch.Tensor]:
    """A random-init weights file in the lpips package's (or torchvision's) key names, heads >= 0 as trained ones."""
    torch.manual_seed(seed)
    model = lpips.Lpips()
    state: dict[str, torch.Tensor] = {}
    for index, *_ in lpips.ALEXNET_CONVS:
        slice_number = next(s for s, r in lpips.LPIPS_SLICES.items() if index in r)
        prefix = f"features.{index}" if torchvision_keys else f"net.slice{slice_number}.{index}"
        state[f"{prefix}.weight"] = model.features[index].weight.detach().clone()
        state[f"{prefix}.bias"] = model.features[index].bias.detach().clone()
    for layer, head in enumerate(model.heads):
        state[f"lin{layer}.model.1.weight"] = head.weight.detach().abs().clone()  # the paper clamps heads to >= 0
    state["scaling_layer.shift"] = torch.tensor(lpips.SCALING_SHIFT).view(1, 3, 1, 1)  # ignored, as in lpips files
    if torchvision_keys:
        state["classifier.1.weight"] = torch.zeros(4, 4)  # ignored
    return state


@pytest.fixture(scope="module")
def lpips_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("lpips") / "lpips_alex.pth"
    torch.save(_lpips_state(), path)
    return path


def test_lpips_identical_is_zero_and_grows_with_noise(lpips_file, rng):
    model = lpips.load_lpips(lpips_file)
    images = rng.integers(0, 256, size=(2, 64, 64, 3), dtype=np.uint8)
    assert np.all(lpips.lpips_distance(model, images, images) == 0.0)
    distances = []
    for sigma in (5, 20, 60):
        noisy = np.clip(images.astype(np.float64) + rng.normal(0, sigma, images.shape), 0, 255).astype(np.uint8)
        distances.append(lpips.lpips_distance(model, noisy, images))
    assert all(d.shape == (2,) for d in distances)
    assert np.all(distances[0] > 0) and np.all(distances[0] < distances[1]) and np.all(distances[1] < distances[2])


def test_lpips_matches_a_direct_computation(lpips_file, rng):
    model = lpips.load_lpips(lpips_file)
    state = torch.load(lpips_file, weights_only=True)
    first, second = (rng.integers(0, 256, size=(1, 48, 40, 3), dtype=np.uint8) for _ in range(2))
    x, y = (lpips.uint8_to_tensor(i) for i in (first, second))
    shift, scale = torch.tensor(lpips.SCALING_SHIFT).view(1, 3, 1, 1), torch.tensor(lpips.SCALING_SCALE).view(1, 3, 1, 1)
    x, y = (x - shift) / scale, (y - shift) / scale
    convs = {0: "net.slice1.0", 3: "net.slice2.3", 6: "net.slice3.6", 8: "net.slice4.8", 10: "net.slice5.10"}
    expected, layer = 0.0, 0
    for index, stride, padding, pool in ((0, 4, 2, True), (3, 1, 2, True), (6, 1, 1, False), (8, 1, 1, False), (10, 1, 1, False)):
        x, y = (torch.relu(torch.nn.functional.conv2d(t, state[convs[index] + ".weight"], state[convs[index] + ".bias"],
                                                      stride=stride, padding=padding)) for t in (x, y))
        nx, ny = (t / (t.pow(2).sum(1, keepdim=True).sqrt() + 1e-10) for t in (x, y))
        expected += float((state[f"lin{layer}.model.1.weight"] * (nx - ny) ** 2).sum(1).mean())
        layer += 1
        if pool:
            x, y = (torch.nn.functional.max_pool2d(t, 3, 2) for t in (x, y))
    assert lpips.lpips_distance(model, first, second)[0] == pytest.approx(expected, rel=1e-5)


def test_lpips_torchvision_keys_load_to_the_same_model(lpips_file, tmp_path, rng):
    from safetensors.torch import save_file

    path = tmp_path / "merged.safetensors"
    save_file(_lpips_state(torchvision_keys=True), str(path))
    images = rng.integers(0, 256, size=(2, 40, 40, 3), dtype=np.uint8)
    other = rng.integers(0, 256, size=(2, 40, 40, 3), dtype=np.uint8)
    from_lpips_keys = lpips.lpips_distance(lpips.load_lpips(lpips_file), images, other)
    from_torchvision_keys = lpips.lpips_distance(lpips.load_lpips(path), images, other)
    np.testing.assert_allclose(from_torchvision_keys, from_lpips_keys, rtol=1e-6)


def test_lpips_bad_files_raise_weights_error(tmp_path):
    with pytest.raises(WeightsError, match="not found.*lpips.LPIPS"):
        lpips.load_lpips(tmp_path / "absent.pth")
    state = _lpips_state()
    state["lin2.model.1.weight"] = torch.zeros(1, 100, 1, 1)
    torch.save(state, tmp_path / "shape.pth")
    with pytest.raises(WeightsError, match=r"wrong shapes.*heads\.2\.weight"):
        lpips.load_lpips(tmp_path / "shape.pth")
    state = _lpips_state()
    del state["net.slice3.6.weight"]
    state["net.slice1.3.weight"] = torch.zeros(1)  # index 3 is not in slice 1
    torch.save(state, tmp_path / "keys.pth")
    with pytest.raises(WeightsError, match=r"missing \['features\.6\.weight'\].*unexpected \['net\.slice1\.3\.weight'\]"):
        lpips.load_lpips(tmp_path / "keys.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(WeightsError, match="could not read LPIPS weights"):
        lpips.load_lpips(tmp_path / "junk.pth")


def test_lpips_rejects_bad_images(lpips_file):
    model = lpips.load_lpips(lpips_file)
    small = np.zeros((1, 16, 16, 3), np.uint8)
    with pytest.raises(ConfigError, match="at least 32"):
        lpips.lpips_distance(model, small, small)
    with pytest.raises(ConfigError, match="uint8"):
        lpips.lpips_distance(model, np.zeros((1, 32, 32, 3)), np.zeros((1, 32, 32, 3)))


# ---- FID ------------------------------------------------------------------------------------------


def test_frechet_distance_known_values(rng):
    # commuting (diagonal) covariances: |dmu|^2 + sum (sqrt(a) - sqrt(b))^2
    mean1, mean2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    var1, var2 = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 1.0])
    expected = 1 + 4 + (1 - 2) ** 2 + (2 - 1) ** 2 + (3 - 1) ** 2
    assert fid.frechet_distance(mean1, np.diag(var1), mean2, np.diag(var2)) == pytest.approx(expected, rel=1e-12)
    # non-commuting covariances against scipy's general sqrtm of the product
    scipy_linalg = pytest.importorskip("scipy.linalg")
    a, b = rng.normal(size=(5, 5)), rng.normal(size=(5, 5))
    cov1, cov2 = a @ a.T + 0.1 * np.eye(5), b @ b.T + 0.1 * np.eye(5)
    reference = np.trace(cov1) + np.trace(cov2) - 2 * np.trace(scipy_linalg.sqrtm(cov1 @ cov2).real)
    assert fid.frechet_distance(np.zeros(5), cov1, np.zeros(5), cov2) == pytest.approx(reference, rel=1e-9)


def test_fid_of_samples_self_zero_and_analytic(rng):
    features = rng.normal(size=(400, 4))
    assert fid.fid_from_features(features, features).value == pytest.approx(0.0, abs=1e-9)
    # two Gaussians N(0, I) and N(m, 4 I): FID = |m|^2 + 4 * (1 - 2)^2 = 1 + 4 = 5 for |m| = 1, D = 4
    shift = np.array([1.0, 0.0, 0.0, 0.0])
    first = rng.normal(size=(20000, 4))
    second = 2.0 * rng.normal(size=(20000, 4)) + shift
    result = fid.fid_from_features(first, second)
    assert result.value == pytest.approx(5.0, abs=0.15)
    assert (result.samples_first, result.samples_second, result.dims, result.eps) == (20000, 20000, 4, 0.0)


def test_fid_few_samples_uses_eps_and_reports_it(rng):
    few = rng.normal(size=(5, 16))
    result = fid.fid_from_features(few, few)
    assert result.eps == fid.FID_EPS and result.samples_first == 5
    assert result.value == pytest.approx(0.0, abs=1e-6)
    assert np.isfinite(fid.fid_from_features(few, rng.normal(size=(6, 16))).value)
    assert np.isnan(fid.fid_from_features(few[:1], few).value)


class _PoolLinear(nn.Module):
    """A tiny extractor: global average pool (N, 3, 299, 299) -> (N, 3), then linear -> (N, 8, 1, 1)."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(3, 8)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.linear(images.mean(dim=(2, 3)))[:, :, None, None]


@pytest.fixture(scope="module")
def extractor_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fid")
    torch.manual_seed(0)
    module = _PoolLinear().eval()
    example = torch.rand(2, 3, fid.INPUT_SIZE, fid.INPUT_SIZE)
    torch.jit.trace(module, example).save(str(folder / "tiny.pt"))
    export_kwargs = {"dynamo": False} if "dynamo" in torch.onnx.export.__code__.co_varnames else {}
    torch.onnx.export(module, (example,), str(folder / "tiny.onnx"), input_names=["images"],
                      dynamic_axes={"images": {0: "n"}}, **export_kwargs)
    return module, folder / "tiny.pt", folder / "tiny.onnx"


def test_torchscript_and_onnx_extractors_load_and_agree(extractor_files, rng):
    module, torchscript_path, onnx_path = extractor_files
    images = rng.integers(0, 256, size=(3, 64, 48, 3), dtype=np.uint8)
    scripted = fid.image_features(fid.load_feature_extractor(torchscript_path), images, batch_size=2)
    exported = fid.image_features(fid.load_feature_extractor(onnx_path), images, batch_size=2)
    assert scripted.shape == exported.shape == (3, 8)
    mean_colour = torch.from_numpy(images).double().mean(dim=(1, 2)) / 255.0  # bilinear resize keeps the mean ~
    with torch.no_grad():
        direct = module.linear(mean_colour.float()).double().numpy()
    np.testing.assert_allclose(scripted, direct, atol=5e-3)
    np.testing.assert_allclose(exported, scripted, atol=1e-5)
    assert fid.fid_from_features(scripted, scripted).value == pytest.approx(0.0, abs=1e-6)


def test_extractor_errors(tmp_path):
    with pytest.raises(WeightsError, match="not found.*--fid-weights"):
        fid.load_feature_extractor(tmp_path / "absent.pt")
    torch.save({"weight": torch.zeros(2)}, tmp_path / "state.pt")  # a pickle, not TorchScript
    with pytest.raises(WeightsError, match="could not load FID feature extractor"):
        fid.load_feature_extractor(tmp_path / "state.pt")
    (tmp_path / "model.bin").write_bytes(b"x")
    with pytest.raises(WeightsError, match="unknown extractor format"):
        fid.load_feature_extractor(tmp_path / "model.bin")


# ---- wiring into `lsr eval` -----------------------------------------------------------------------


def test_config_checks_weight_files(tmp_path):
    with pytest.raises(ConfigError, match="--lpips-weights"):
        EvalConfig(data=tmp_path, lpips_weights=tmp_path / "absent.pth").validate()
    with pytest.raises(ConfigError, match="--fid-weights"):
        EvalConfig(data=tmp_path, fid_weights=tmp_path / "absent.pt").validate()


def test_report_with_lpips_and_fid(tmp_path, lpips_file, extractor_files, capsys, monkeypatch, no_face_detector):
    from landmarks.detect import registry as detectors
    from lsr.data.synth.generate import generate_dataset
    from lsr.eval import report

    monkeypatch.setattr(detectors, "make_detector", no_face_detector)  # face detection is not what this test is about
    root = tmp_path / "synth"
    generate_dataset(root, identities=4, videos_per_identity=1, frames=10, size=64, test_fraction=0.5, progress=False)
    cfg = EvalConfig(data=root, out=tmp_path / "out", k=(1,), inputs=6, holdouts=4, progress=False, examples=0,
                     cross_identity=False, lpips_weights=lpips_file, fid_weights=extractor_files[1])
    cfg.validate()
    summary = report.run_eval(cfg)
    capsys.readouterr()
    rows = {row["method"]: row for row in summary["rows"]}
    assert all(np.isfinite(row["lpips"]) and row["lpips"] > 0 for row in rows.values())
    assert all(np.isfinite(row["fid"]) and row["fid_samples"] == 8 for row in rows.values())
    assert "AlexNet LPIPS" in summary["lpips"] and "N <= D" in summary["fid"]  # 8 samples, D = 8: eps used
    stored = json.loads((tmp_path / "out" / "eval_report.json").read_text())
    assert "not computed" not in stored["lpips"] and "not computed" not in stored["fid"]
    assert "| tps | 1 | 8 |" in (tmp_path / "out" / "eval_report.md").read_text()
