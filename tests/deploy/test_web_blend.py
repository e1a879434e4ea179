"""The warp-guided composite the web page runs itself (deploy/web/src/blend_wasm.ts, issue 65) against the model's:
``models_def.composite.blend_references`` then ``add_reference_detail``, the math the exported frame graph
runs, on G^s's outputs upsampled to the references' side."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from models_def.composite import INVALID_LOGIT_PENALTY, add_reference_detail, blend_references


def _inputs(rng, count: int, crop: int, size: int):
    """References (N, 3, C, C) with masks holding holes, and G^s's image and N + 1 logits at S, logits apart enough
    that every candidate wins somewhere."""
    references = rng.uniform(-1, 1, (count, 3, crop, crop)).astype(np.float32)
    references = (references + np.roll(references, 1, axis=-1)) / 2  # some detail to keep, some to drop
    masks = (rng.uniform(size=(count, crop, crop)) > 0.15).astype(np.float32)
    masks[:, : crop // 4, : crop // 4] = 0  # where no reference is valid: G^s's image alone
    network = np.concatenate([rng.uniform(-1, 1, (3, size, size)), rng.normal(0, 2, (count + 1, size, size))])
    return references, masks, network.astype(np.float32)


def _model(references, masks, network, sigma: float) -> np.ndarray:
    count, crop = references.shape[0], references.shape[-1]
    refs, valid = torch.from_numpy(references)[None], torch.from_numpy(masks)[:, None][None]
    generated, logits = torch.from_numpy(network[None, :3]), torch.from_numpy(network[None, 3:])
    image, weights = blend_references(refs, valid, generated, logits)
    if sigma > 0:
        image = add_reference_detail(image, refs, valid, weights[:, count:], sigma)
    assert image.shape == (1, 3, crop, crop)
    return image[0].numpy()


@pytest.mark.parametrize(("count", "sigma"), [(5, 3.0), (3, 2.0), (1, 4.5), (5, 0.0)])
def test_the_page_composites_as_the_model(web, rng, count, sigma):
    references, masks, network = _inputs(rng, count, 128, 32)
    got = web.call("composeReferences", references, masks, network, sigma)
    expected = _model(references, masks, network, sigma)
    assert got.shape == expected.shape
    assert np.abs(got - expected).max() <= 2e-5
    if sigma > 0:  # the detail step ran: without it the face is another
        assert np.abs(_model(references, masks, network, 0.0) - expected).max() > 0.05


def test_a_reference_masked_out_takes_no_weight(web, rng):
    """A reference invalid everywhere (its logit the highest) leaves the others' blend: the penalty is applied."""
    references, masks, network = _inputs(rng, 3, 64, 16)
    masks[0] = 0
    network[3] += 10.0  # its logit far above the others'
    got = web.call("composeReferences", references, masks, network, 0.0)
    alone = _model(references[1:], masks[1:], np.concatenate([network[:3], network[4:]]), 0.0)
    assert INVALID_LOGIT_PENALTY > 10.0 and np.abs(got - alone).max() <= 1e-4


def test_the_page_keeps_the_whole_graph_where_its_kernel_cannot_compose(web):
    """2 or 4 references (no median network), a crop 3x the network's, a detail split too narrow for half
    resolution: the site keeps the graph's own composite (lsr.export.graphs.page_composite_sigma says the same)."""
    cases = [(5, 256, 64, 2.9952), (5, 256, 64, 0.0), (1, 128, 32, 2.0), (2, 256, 64, 3.0), (4, 256, 64, 3.0),
             (5, 192, 64, 3.0), (5, 256, 64, 1.0), (5, 64, 64, 3.0), (5, 120, 30, 3.0)]
    got = web.calls(*(("composesInWasm", list(case)) for case in cases))
    assert got == [True, True, True, False, False, False, False, False, False]


def test_the_sites_graph_and_blend_draw_the_whole_graphs_face(web, site):
    """The page on the site's graph (ending at G^s) and its own blend against the page on the bundle's whole frame
    graph, the check frame (landmark image and references of noise): within one grey level."""
    import json

    from lsr.export.bundle import cached_bundle
    from lsr.export.bundle_cache import FRAME_GENERATOR_FILE
    from lsr.weights import resolve_weights

    config = json.loads((site.folder / "site.json").read_text())
    assert config["detail_sigma"] == pytest.approx(0.0117 * 256)
    whole = cached_bundle(resolve_weights(None)) / FRAME_GENERATOR_FILE
    ours = site.folder / "models" / "frame_generator.onnx"
    assert web.call("frameGraphsDifference", str(site.folder), str(whole), str(ours)) <= 1


def test_a_frame_that_fails_leaves_the_generator_drawing(web, site):
    """References of the wrong size: one clear error, and the frames after it are drawn (the failed frames free the
    two composites the generator takes in turn; a leak would hang the next run on them)."""
    got = web.call("generatorAfterABadFrame", str(site.folder))
    assert got["message"] == "the references must be (5, 256, 256, 3) and their masks (5, 256, 256)"
    assert got["drawn"] == 0  # the same frame twice, drawn each time


def test_the_references_go_in_as_the_network_takes_them(web, rng):
    """The warped references unpacked in the composite's module (four pixels at a time, v / 127.5 - 1 in float32)
    are lsr.core.images.to_network's values exactly, every byte value among them."""
    from lsr.core.images import to_network

    references = rng.integers(0, 256, (5, 64, 64, 3), dtype=np.uint8)
    references.reshape(-1)[:256] = np.arange(256)
    got = web.call("loadedReferences", references, 16, 2.0)
    expected = np.stack([to_network(picture) for picture in references])
    assert got.dtype == np.float32 and got.shape == expected.shape == (5, 3, 64, 64)
    np.testing.assert_array_equal(got, expected)
