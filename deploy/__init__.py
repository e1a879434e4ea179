"""Torch-free LSR runtime over the ONNX bundle written by ``lsr export``.

``deploy.runtime.OnnxReenactor`` (numpy + onnxruntime + OpenCV + dlib via ``landmarks``) has the same API as
``lsr.pipeline.Reenactor``; both run the frame loop of ``deploy.engine`` and load inputs with
``deploy.sources``. Nothing heavy is imported here.
"""

MAX_K = 32  # most source shots averaged into a subject: the thesis evaluates K = 1..32 (Table 4.4)
