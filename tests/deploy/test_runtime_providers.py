"""deploy.runtime's onnxruntime providers: the choice (``choose_providers``: CUDA where there is one, the CPU always
last), and a session that cannot be made on the chosen GPU made on the CPU instead, the reason logged."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from deploy.runtime import CPU_PROVIDER, BundleError, choose_providers, onnx_session

CUDA = "CUDAExecutionProvider"


@pytest.mark.parametrize(("available", "asked", "expected"), [
    ([CPU_PROVIDER], None, [CPU_PROVIDER]),
    (["AzureExecutionProvider", CPU_PROVIDER], None, [CPU_PROVIDER]),
    ([CUDA, CPU_PROVIDER], None, [CUDA, CPU_PROVIDER]),
    ([CUDA, CPU_PROVIDER], [CPU_PROVIDER], [CPU_PROVIDER]),  # asking for the CPU keeps a GPU idle
    ([CPU_PROVIDER], [CUDA], [CPU_PROVIDER]),  # asked, but not in this onnxruntime
    ([CUDA, "DmlExecutionProvider", CPU_PROVIDER], ["DmlExecutionProvider", CUDA], ["DmlExecutionProvider", CUDA, CPU_PROVIDER]),
    ([CUDA, CPU_PROVIDER], [CPU_PROVIDER, CUDA], [CUDA, CPU_PROVIDER]),  # the CPU is the fallback: last
])
def test_the_providers_are_the_available_ones_asked_then_the_cpu(available, asked, expected):
    assert choose_providers(available, asked) == expected


@pytest.fixture
def identity_graph(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "identity",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [2])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    path = tmp_path / "identity.onnx"
    onnx.save(model, str(path))
    return path


def test_the_session_says_where_it_runs(identity_graph, caplog):
    with caplog.at_level(logging.INFO, logger="deploy.runtime"):
        session = onnx_session(identity_graph)
    assert session.get_providers()[-1] == CPU_PROVIDER
    assert f"identity.onnx runs on {', '.join(session.get_providers())}" in caplog.text
    np.testing.assert_array_equal(session.run(["y"], {"x": np.array([1.0, 2.0], np.float32)})[0], [1.0, 2.0])


def test_a_gpu_that_fails_leaves_the_session_on_the_cpu(identity_graph, monkeypatch, caplog):
    import onnxruntime

    made = []
    real_session = onnxruntime.InferenceSession

    def session_failing_on_cuda(path, options=None, providers=None):
        made.append(list(providers))
        if CUDA in providers:
            raise RuntimeError("CUDA driver version is insufficient")
        return real_session(path, options, providers=providers)

    monkeypatch.setattr(onnxruntime, "get_available_providers", lambda: [CUDA, CPU_PROVIDER])
    monkeypatch.setattr(onnxruntime, "InferenceSession", session_failing_on_cuda)
    with caplog.at_level(logging.INFO, logger="deploy.runtime"):
        session = onnx_session(identity_graph)
    assert made == [[CUDA, CPU_PROVIDER], [CPU_PROVIDER]]
    assert session.get_providers() == [CPU_PROVIDER]
    assert "CUDA driver version is insufficient" in caplog.text and "loading it on the CPU" in caplog.text
    assert f"identity.onnx runs on {CPU_PROVIDER}" in caplog.text


def test_a_broken_graph_fails_on_every_provider_with_a_bundle_error(tmp_path):
    path = tmp_path / "broken.onnx"
    path.write_bytes(b"not a graph")
    with pytest.raises(BundleError, match="re-run `lsr export`"):
        onnx_session(path)
