"""Torch-free LSR runtime over the ONNX bundle written by ``lsr export``.

``deploy.runtime.OnnxReenactor`` (numpy + onnxruntime + OpenCV via ``landmarks``; no dlib by default) has the same API as
``lsr.pipeline.Reenactor``; both run the frame loop of the inference core ``lsr.core`` (``lsr.core.engine``,
inputs from ``lsr.core.inputs``). Nothing heavy is imported here.
"""
