"""``lsr.layout_view``: PCA colours (training previews; the numpy colouring matches the torch one) and the latent
layout as parts with a legend (the side-by-side, the app, the live tab)."""

from __future__ import annotations

import numpy as np
import pytest
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


def test_layout_parts_keep_a_colour_per_channel_and_the_legend_names_what_is_shown(tmp_path):
    import json

    from lsr.layout_view import LAYOUT_PALETTE, LEGEND_FILE, draw_layout_legend, layout_parts_rgb, load_layout_legend

    layout = np.zeros((5, 8, 8), np.float32)
    layout[2, :, :4] = 1.0  # channel 2 on the left half, channel 4 on the right
    layout[4, :, 4:] = 1.0
    rgb = layout_parts_rgb(layout)
    assert rgb.shape == (8, 8, 3) and (rgb[:, :4] == LAYOUT_PALETTE[2]).all() and (rgb[:, 4:] == LAYOUT_PALETTE[4]).all()
    assert (layout_parts_rgb(layout * 3.0 + 1.0) == rgb).all()  # the strongest channel, whatever the scale
    with pytest.raises(ValueError):
        layout_parts_rgb(layout[0])
    assert load_layout_legend(tmp_path) is None and load_layout_legend(None) is None
    (tmp_path / LEGEND_FILE).write_text(json.dumps({"channels": ["a", "b", "skin (cheeks)", "d", "lips"]}))
    legend = load_layout_legend(tmp_path)
    assert legend[2] == "skin (cheeks)"
    panel = np.kron(rgb, np.ones((32, 32, 1), np.uint8))  # 256 x 256
    drawn = draw_layout_legend(panel, layout, legend)
    assert drawn.shape == panel.shape and (drawn != panel).any() and (drawn[:100] == panel[:100]).all()  # bottom only
    (tmp_path / LEGEND_FILE).write_text("not json")
    assert load_layout_legend(tmp_path) is None


def test_legend_names_say_which_parts_a_channel_covers_and_where_skin_lies():
    from lsr.data.classes import SEG_CLASS_ID, SEG_CLASSES
    from lsr.bench.layout_legend import legend_names

    counts = np.zeros((3, len(SEG_CLASSES)), np.int64)
    counts[0, SEG_CLASS_ID["u_lip"]], counts[0, SEG_CLASS_ID["l_lip"]], counts[0, SEG_CLASS_ID["skin"]] = 40, 35, 25
    counts[1, SEG_CLASS_ID["skin"]] = 100
    names = legend_names(counts, np.array([1.0, -0.8, 0.0]))
    assert names[0] == "upper lip / lower lip"  # at most two parts, each of at least a fifth of the channel
    assert names[1] == "skin (forehead)" and names[2] == "unused"
