"""ID-SIM with dlib embeddings on real frames (lsr.eval.idsim)."""

from __future__ import annotations

import numpy as np
import pytest

from lsr.eval import idsim


def test_cosine_similarity_basics():
    assert idsim.cosine_similarity(np.array([1.0, 0.0]), np.array([2.0, 0.0])) == pytest.approx(1.0)
    assert idsim.cosine_similarity(np.array([1.0, 0.0]), np.array([0.0, 3.0])) == pytest.approx(0.0)
    mean = idsim.mean_embedding(np.array([[1.0, 0.0], [0.0, 1.0], [np.nan, 0.0]]))
    np.testing.assert_allclose(mean, [2**-0.5, 2**-0.5])


@pytest.mark.slow
def test_same_identity_is_more_similar_than_different(shared_data):
    from landmarks.detect.face_detector import DlibDetector
    from landmarks.io.image_files import read_image

    root = shared_data / "fsth_eval_sample"
    if not root.is_dir():
        pytest.skip("fsth_eval_sample not in the shared data")
    identities = sorted(p for p in (root / "train").iterdir() if p.is_dir())[:2]
    detector = DlibDetector(upsample=1)
    embeddings = {}
    for identity in identities:
        frames = sorted(identity.glob("*/combined/*_rgb.png"))
        for name, path in (("first", frames[0]), ("last", frames[-1])):
            image = read_image(path)
            embeddings[identity.name, name] = idsim.face_embedding(image, detector.detect_one(image).landmarks)
    (a, b) = (identity.name for identity in identities)
    same_a = idsim.cosine_similarity(embeddings[a, "first"], embeddings[a, "last"])
    same_b = idsim.cosine_similarity(embeddings[b, "first"], embeddings[b, "last"])
    across = idsim.cosine_similarity(embeddings[a, "first"], embeddings[b, "first"])
    assert embeddings[a, "first"].shape == (idsim.EMBEDDING_SIZE,)
    assert min(same_a, same_b) > across
