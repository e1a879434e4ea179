"""FID (Heusel et al. 2017): Fréchet distance between Gaussian fits of backbone features of the
outputs and of the ground truth (thesis Table 4.4, §4.4 "Metrics").

No backbone can be downloaded by this project, so FID exists only when the user passes a feature
extractor with ``--fid-weights``, as

  * a TorchScript file (``.pt``, ``.pth``, ``.ts``, ``.jit``, ``.torchscript``), read with
    ``torch.jit.load`` (never an arbitrary pickle), or
  * an ONNX file (``.onnx``), run with onnxruntime.

E.g. pytorch-fid's InceptionV3 pool3, exported on a machine with internet (``pip install pytorch-fid``)::

    import torch
    from pytorch_fid.inception import InceptionV3

    class Pool3(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.net = InceptionV3([3], normalize_input=True).eval()

        def forward(self, images):  # (N, 3, 299, 299) in [0, 1]
            return self.net(images)[0]  # (N, 2048, 1, 1)

    example = torch.rand(2, 3, 299, 299)
    torch.jit.trace(Pool3().eval(), example).save("inception_pool3.pt")
    torch.onnx.export(Pool3().eval(), example, "inception_pool3.onnx", input_names=["images"],
                      dynamic_axes={"images": {0: "n"}})

Contract of the extractor: (N, 3, 299, 299) float32 RGB in [0, 1] -> (N, D) or (N, D, 1, 1).
Images are resized to 299x299 here (bilinear, no corner alignment), as pytorch-fid does.

The Fréchet distance ``|mu1 - mu2|^2 + tr(S1) + tr(S2) - 2 tr((sqrt(S1) S2 sqrt(S1))^1/2)`` uses the
symmetric form, so both square roots are of symmetric PSD matrices and come from ``numpy.linalg.eigh``
(negative round-off eigenvalues clipped to 0) -- no scipy, no complex parts to discard. With at most
D samples the covariances are singular; ``FID_EPS`` is then added to their diagonals and reported.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from lsr.errors import ConfigError, WeightsError

INPUT_SIZE = 299
FID_EPS = 1e-6
TORCHSCRIPT_SUFFIXES = (".pt", ".pth", ".ts", ".jit", ".torchscript")

WEIGHTS_HELP = (
    "FID needs a feature extractor (N, 3, 299, 299) in [0, 1] -> (N, D), e.g. pytorch-fid's InceptionV3 pool3, "
    "exported on a machine with internet with torch.jit.trace(...).save('inception_pool3.pt') or "
    "torch.onnx.export(..., 'inception_pool3.onnx') (see lsr/eval/fid.py); pass --fid-weights FILE, "
    "or leave it unset (the report then says FID was not computed)."
)


class FeatureExtractor:
    """A user-supplied backbone. __call__(images: (N, 3, 299, 299) float32 in [0, 1]) -> (N, D) float64."""

    def __init__(self, path: Path, device: str = "cpu") -> None:
        path = Path(path)
        if not path.is_file():
            raise WeightsError(f"FID feature extractor not found: {path}. {WEIGHTS_HELP}")
        self.path = path
        self.device = device
        self.kind = "onnx" if path.suffix.lower() == ".onnx" else "torchscript"
        if self.kind == "torchscript" and path.suffix.lower() not in TORCHSCRIPT_SUFFIXES:
            raise WeightsError(f"{path}: unknown extractor format {path.suffix!r}; use TorchScript "
                               f"({', '.join(TORCHSCRIPT_SUFFIXES)}) or .onnx. {WEIGHTS_HELP}")
        self._module: Any = None
        self._session: Any = None
        try:
            if self.kind == "onnx":
                import onnxruntime

                available = onnxruntime.get_available_providers()
                wanted = ["CUDAExecutionProvider"] if device.startswith("cuda") else []
                providers = [p for p in wanted if p in available] + ["CPUExecutionProvider"]
                self._session = onnxruntime.InferenceSession(str(path), providers=providers)
                self._input_name = self._session.get_inputs()[0].name
            else:
                import torch

                self._module = torch.jit.load(str(path), map_location=device).eval()
        except Exception as exc:  # any reader failure means "not a usable extractor file"
            raise WeightsError(f"could not load FID feature extractor {path} as {self.kind}: {exc}. {WEIGHTS_HELP}") from exc

    def __call__(self, images: np.ndarray) -> np.ndarray:
        if images.ndim != 4 or images.shape[1:] != (3, INPUT_SIZE, INPUT_SIZE):
            raise ConfigError(f"extractor input must be (N, 3, {INPUT_SIZE}, {INPUT_SIZE}), got {images.shape}")
        images = np.ascontiguousarray(images, dtype=np.float32)
        try:
            if self._session is not None:
                features = np.asarray(self._session.run(None, {self._input_name: images})[0])
            else:
                import torch

                with torch.no_grad():
                    result = self._module(torch.from_numpy(images).to(self.device))
                if isinstance(result, (list, tuple)):
                    result = result[0]
                features = result.detach().cpu().numpy()
        except Exception as exc:  # the user's graph failed on our input: say what it got
            raise WeightsError(f"FID feature extractor {self.path} failed on a {images.shape} batch: {exc}. {WEIGHTS_HELP}") from exc
        if features.ndim == 4 and features.shape[2:] == (1, 1):
            features = features[:, :, 0, 0]  # (N, D, 1, 1) -> (N, D), pytorch-fid's pool3 shape
        if features.ndim != 2 or features.shape[0] != images.shape[0]:
            raise WeightsError(f"FID feature extractor {self.path} returned {features.shape} for {images.shape[0]} "
                               f"images; expected (N, D) or (N, D, 1, 1). {WEIGHTS_HELP}")
        return features.astype(np.float64)


def load_feature_extractor(path: Path, device: str = "cpu") -> FeatureExtractor:
    """The extractor in ``path`` (TorchScript or ONNX, by suffix); WeightsError when missing or unreadable."""
    return FeatureExtractor(path, device)


def image_features(extractor: FeatureExtractor, images: np.ndarray, batch_size: int = 16) -> np.ndarray:
    """Features of uint8 RGB images. images: (N, H, W, 3) uint8 -> (N, D) float64."""
    import torch
    import torch.nn.functional as F

    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ConfigError(f"FID images must be (N, H, W, 3) uint8 RGB, got {images.shape} {images.dtype}")
    chunks = []
    for start in range(0, len(images), batch_size):
        batch = torch.from_numpy(np.ascontiguousarray(images[start : start + batch_size]))
        batch = batch.permute(0, 3, 1, 2).to(torch.float32) / 255.0  # (B, H, W, 3) -> (B, 3, H, W) in [0, 1]
        batch = F.interpolate(batch, size=(INPUT_SIZE, INPUT_SIZE), mode="bilinear", align_corners=False)
        chunks.append(extractor(batch.numpy()))
    return np.concatenate(chunks) if chunks else np.zeros((0, 0))


def sqrtm_psd(matrix: np.ndarray) -> np.ndarray:
    """Square root of a symmetric PSD matrix by eigen-decomposition. (D, D) -> (D, D) symmetric."""
    symmetric = (matrix + matrix.T) / 2
    eigenvalues, eigenvectors = np.linalg.eigh(symmetric)
    return (eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))) @ eigenvectors.T


def frechet_distance(mean1: np.ndarray, cov1: np.ndarray, mean2: np.ndarray, cov2: np.ndarray) -> float:
    """Fréchet distance of N(mean1, cov1) and N(mean2, cov2). means: (D,), covs: (D, D) PSD -> float >= 0."""
    mean1, mean2 = np.asarray(mean1, np.float64), np.asarray(mean2, np.float64)
    cov1, cov2 = np.asarray(cov1, np.float64), np.asarray(cov2, np.float64)
    dims = mean1.shape[0]
    if mean1.shape != (dims,) or mean2.shape != (dims,) or cov1.shape != (dims, dims) or cov2.shape != (dims, dims):
        raise ConfigError(f"means must be (D,) and covariances (D, D); got {mean1.shape}, {cov1.shape}, {mean2.shape}, {cov2.shape}")
    root1 = sqrtm_psd(cov1)
    # tr sqrt(S1 S2) = tr sqrt(sqrt(S1) S2 sqrt(S1)); the latter is symmetric PSD, so eigh is stable
    cross_trace = np.trace(sqrtm_psd(root1 @ cov2 @ root1))
    value = float(np.sum((mean1 - mean2) ** 2) + np.trace(cov1) + np.trace(cov2) - 2.0 * cross_trace)
    return max(value, 0.0)  # round-off can make identical fits slightly negative


@dataclasses.dataclass
class FidResult:
    """FID of two feature sets; ``eps`` is what was added to the covariance diagonals (0 when N > D)."""

    value: float
    samples_first: int
    samples_second: int
    dims: int
    eps: float


def fid_from_features(first: np.ndarray, second: np.ndarray, eps: float = FID_EPS) -> FidResult:
    """FID of two feature sets. first: (N1, D), second: (N2, D) -> FidResult (value NaN with < 2 samples)."""
    first, second = np.asarray(first, np.float64), np.asarray(second, np.float64)
    if first.ndim != 2 or second.ndim != 2 or first.shape[1] != second.shape[1]:
        raise ConfigError(f"feature sets must be (N1, D) and (N2, D), got {first.shape} and {second.shape}")
    count1, count2, dims = first.shape[0], second.shape[0], first.shape[1]
    if min(count1, count2) < 2:  # a covariance needs two samples
        return FidResult(float("nan"), count1, count2, dims, 0.0)
    cov1, cov2 = np.cov(first, rowvar=False).reshape(dims, dims), np.cov(second, rowvar=False).reshape(dims, dims)
    used_eps = eps if min(count1, count2) <= dims else 0.0  # rank <= N - 1 < D: singular covariances
    if used_eps:
        cov1, cov2 = cov1 + used_eps * np.eye(dims), cov2 + used_eps * np.eye(dims)
    value = frechet_distance(first.mean(axis=0), cov1, second.mean(axis=0), cov2)
    return FidResult(value, count1, count2, dims, used_eps)
