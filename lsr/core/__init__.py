"""The torch-free inference core: the frame loop shared by the torch pipeline and the ONNX runtime.

``lsr.core.sources`` loads subject shots and drivers (images, folders, videos, landmark files);
``lsr.core.engine`` runs decode -> landmarks -> crop -> synthesise through a backend -> paste back, and writes
provenance. It imports numpy, OpenCV and ``landmarks`` only (no torch), so ``deploy``'s ONNX runtime and
``lsr.pipeline``'s torch backend share it. Nothing heavy is imported here.
"""

MAX_K = 32  # most source shots averaged into a subject: the thesis evaluates K = 1..32 (Table 4.4)
