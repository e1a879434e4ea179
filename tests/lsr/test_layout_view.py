"""``lsr.layout_view.LayoutPCA.rgb``: the numpy colouring a live stream uses matches the torch one."""

from __future__ import annotations

import numpy as np
import torch

from lsr.layout_view import LayoutPCA, images_to_uint8


def test_numpy_colours_match_torch_and_keep_the_first_fit():
    generator = torch.Generator().manual_seed(0)
    first, second = torch.randn(2, 1, 19, 16, 16, generator=generator)
    pca, reference = LayoutPCA(), LayoutPCA()
    for layout in (first, second):  # both fitted on the first layout, then kept
        expected = images_to_uint8(reference(layout))[0]
        got = pca.rgb(layout[0].numpy())
        assert got.shape == (16, 16, 3) and got.dtype == np.uint8
        assert np.abs(got.astype(int) - expected.astype(int)).max() <= 1
    two = LayoutPCA().rgb(np.random.default_rng(0).normal(size=(2, 8, 8)).astype(np.float32))
    assert (two[..., 2] == 128).all()  # C < 3: the missing component is zero (mid grey)
