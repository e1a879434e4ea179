"""Layouts and images as pictures for people: a layout map as RGB (PCA of its channels, kept over a video, or argmax
class colours), images in [-1, 1] as uint8. Used by inference (the side-by-side of ``lsr reenact``, the app) and by
training previews (``lsr.train.visualize``), so it lives outside ``lsr.train``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from lsr.data.classes import NUM_SEG_CLASSES, colorize_segmentation


def images_to_uint8(images: Tensor) -> np.ndarray:
    """(B, 3, H, W) float in [-1, 1] -> (B, H, W, 3) uint8."""
    if images.ndim != 4 or images.shape[1] != 3:
        raise ValueError(f"images must be (B, 3, H, W); got {tuple(images.shape)}")
    array = ((images.detach().float().clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8)
    return array.permute(0, 2, 3, 1).cpu().numpy()


class LayoutPCA:
    """Colours a layout map by its 3 principal components, with the basis fitted once and then kept.

    Fitted on the first call (a batch, or a video's first frame) and reused after, so a colour keeps its meaning
    from frame to frame: refitting per frame flips eigenvector signs and swaps colours. Each component is scaled
    by its robust (99th percentile) range at fit time. C < 3 is zero-padded.
    """

    def __init__(self) -> None:
        self.mean: Tensor | None = None
        self.basis: Tensor | None = None
        self.scale: Tensor | None = None
        self._numpy: tuple | None = None  # the fitted basis as numpy arrays, for ``rgb``

    @staticmethod
    def _pixels(layout: Tensor) -> Tensor:
        if layout.ndim != 4:
            raise ValueError(f"layout must be (B, C, H, W); got {tuple(layout.shape)}")
        return layout.detach().float().permute(0, 2, 3, 1).reshape(-1, layout.shape[1])  # (B*H*W, C)

    def fit(self, layout: Tensor) -> LayoutPCA:
        pixels = self._pixels(layout)
        self.mean = pixels.mean(dim=0, keepdim=True)
        centred = pixels - self.mean
        channels = centred.shape[1]
        # Principal axes from the C x C covariance (cheap: C is small), largest variance first.
        covariance = centred.T @ centred / max(1, centred.shape[0] - 1)
        _, eigenvectors = torch.linalg.eigh(covariance.double())
        basis = eigenvectors[:, -min(3, channels):].flip(1).float()  # (C, <=3)
        # Fix each axis' sign (eigh's is arbitrary): its largest-magnitude entry is positive.
        signs = torch.sign(basis.gather(0, basis.abs().argmax(dim=0, keepdim=True)))
        self.basis = basis * torch.where(signs == 0, torch.ones_like(signs), signs)
        self.scale = (centred @ self.basis).abs().quantile(0.99, dim=0).clamp_min(1e-6)
        return self

    def __call__(self, layout: Tensor) -> Tensor:
        """(B, C, H, W) -> (B, 3, H, W) in [-1, 1]; fits on this layout first when not fitted yet."""
        if self.basis is None:
            self.fit(layout)
        batch, channels, height, width = layout.shape
        if channels != self.basis.shape[0]:
            raise ValueError(f"layout has {channels} channels; this LayoutPCA was fitted on {self.basis.shape[0]}")
        projected = ((self._pixels(layout) - self.mean) @ self.basis / self.scale).clamp(-1, 1)
        if projected.shape[1] < 3:
            projected = torch.cat([projected, projected.new_zeros(projected.shape[0], 3 - projected.shape[1])], dim=1)
        return projected.reshape(batch, height, width, 3).permute(0, 3, 1, 2)  # (B, 3, H, W)


    def rgb(self, layout: np.ndarray) -> np.ndarray:
        """One layout (C, H, W) float -> (H, W, 3) uint8, as ``images_to_uint8(self(...))`` gives it but in numpy
        once fitted (the first call fits with torch): a live stream colours a layout per frame without waking
        torch's thread pool, whose idle spinning took a core from the network beside it (76 against 236 ms/frame)."""
        layout = np.asarray(layout, np.float32)
        if self.basis is None:
            self.fit(torch.from_numpy(np.ascontiguousarray(layout))[None])
        if getattr(self, "_numpy", None) is None or self._numpy[0] is not self.basis:
            self._numpy = (self.basis, self.mean.numpy(), self.basis.numpy(), self.scale.numpy())
        _, mean, basis, scale = self._numpy
        channels, height, width = layout.shape
        if channels != basis.shape[0]:
            raise ValueError(f"layout has {channels} channels; this LayoutPCA was fitted on {basis.shape[0]}")
        projected = np.clip((layout.reshape(channels, -1).T - mean) @ basis / scale, -1.0, 1.0)
        if projected.shape[1] < 3:
            projected = np.pad(projected, ((0, 0), (0, 3 - projected.shape[1])))
        return np.round((projected.reshape(height, width, 3) + 1.0) * 127.5).astype(np.uint8)


def layout_pca_rgb(layout: Tensor) -> Tensor:
    """Project a layout map's channels onto their 3 principal components -> (B, 3, H, W) in [-1, 1].

    layout: (B, C, H, W) float. One PCA basis is fitted on the whole batch so colours are comparable
    across the row (``LayoutPCA`` keeps a basis across calls, e.g. over a video).
    """
    return LayoutPCA()(layout)


def layout_argmax_rgb(layout: Tensor) -> Tensor:
    """Argmax over the layout's class channels coloured with ``SEG_PALETTE`` -> (B, 3, H, W) in [-1, 1]."""
    if layout.ndim != 4 or layout.shape[1] != NUM_SEG_CLASSES:
        raise ValueError(f"layout must be (B, {NUM_SEG_CLASSES}, H, W) class scores; got {tuple(layout.shape)}")
    return segmentation_rgb(layout.detach().argmax(dim=1))


def segmentation_rgb(segmentation: Tensor, ignore_index: int = -1) -> Tensor:
    """Class map (B, H, W) int -> palette colours (B, 3, H, W) in [-1, 1]; ignored pixels are grey."""
    maps = segmentation.detach().cpu().numpy()
    coloured = np.stack([colorize_segmentation(np.where(m == ignore_index, 0, m).astype(np.uint8)) for m in maps])
    coloured[maps == ignore_index] = 128
    return torch.from_numpy(coloured).permute(0, 3, 1, 2).float() / 127.5 - 1


# A fixed colour per latent-layout channel (tab20's colours, then four more): a channel keeps its colour over a
# video, between people and between runs, unlike PCA colours, which depend on the frame they were fitted on.
LAYOUT_PALETTE = np.array(
    [
        [31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [140, 86, 75],
        [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207], [174, 199, 232], [255, 187, 120],
        [152, 223, 138], [255, 152, 150], [197, 176, 213], [196, 156, 148], [247, 182, 210], [199, 199, 199],
        [219, 219, 141], [158, 218, 229], [90, 40, 20], [20, 60, 110], [240, 230, 80], [0, 0, 0],
    ],
    dtype=np.uint8,
)  # (24, 3) RGB
LEGEND_FILE = "layout_legend.json"
"""A model folder's names for its layout channels (``lsr bench layout-legend``): {"channels": [name, ...], ...}."""


def layout_parts_rgb(layout: np.ndarray) -> np.ndarray:
    """A latent layout as parts: each pixel's strongest channel in ``LAYOUT_PALETTE``, at the layout's own
    resolution (enlarge it with nearest-neighbour, not blurred). layout: (C, H, W) float -> (H, W, 3) uint8."""
    layout = np.asarray(layout)
    if layout.ndim != 3:
        raise ValueError(f"layout must be (C, H, W); got {layout.shape}")
    return LAYOUT_PALETTE[layout.argmax(axis=0) % len(LAYOUT_PALETTE)]


def load_layout_legend(folder) -> list[str] | None:
    """The channel names of model folder ``folder`` (``LEGEND_FILE``), or None when it has none or it is unreadable."""
    import json
    from pathlib import Path

    if folder is None:
        return None
    try:
        names = json.loads((Path(folder) / LEGEND_FILE).read_text())["channels"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return [str(name) for name in names] if isinstance(names, list) else None


def draw_layout_legend(panel: np.ndarray, layout: np.ndarray, legend: list[str] | None, min_share: float = 0.02,
                       rows: int = 6) -> np.ndarray:
    """``panel`` (S, S, 3) uint8, a ``layout_parts_rgb`` picture enlarged, with a legend in its lower left corner:
    a swatch and a name (``legend``'s, else "channel i") for up to ``rows`` channels covering at least ``min_share``
    of this layout (C, H, W), largest first. Returns a new array."""
    import cv2

    strongest = np.asarray(layout).argmax(axis=0)
    shares = np.bincount(strongest.ravel(), minlength=layout.shape[0]) / strongest.size
    shown = [c for c in np.argsort(shares)[::-1] if shares[c] >= min_share][:rows]
    result = panel.copy()
    size = panel.shape[0]
    scale = max(0.3, size / 560)
    line = max(10, int(round(26 * scale)))
    y = size - line * len(shown) - 4
    for channel in shown:
        name = legend[channel] if legend is not None and channel < len(legend) else f"channel {channel}"
        colour = tuple(int(v) for v in LAYOUT_PALETTE[channel % len(LAYOUT_PALETTE)])
        cv2.rectangle(result, (4, y), (4 + line - 3, y + line - 3), colour, -1)
        cv2.rectangle(result, (4, y), (4 + line - 3, y + line - 3), (255, 255, 255), 1)
        for ink, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):  # outlined text: readable on any colour
            cv2.putText(result, name, (4 + line, y + line - 5), cv2.FONT_HERSHEY_SIMPLEX, scale, ink, width, cv2.LINE_AA)
        y += line
    return result
