"""The torch-free inference core: the frame loop shared by the torch pipeline and the ONNX runtime.

``lsr.core.inputs`` loads subject shots and drivers (images, folders, videos, landmark files);
``lsr.core.engine`` runs decode -> landmarks -> crop -> synthesise through a backend -> paste back;
``lsr.core.provenance`` marks its outputs as synthetic. They import numpy, OpenCV and ``landmarks`` only (no torch),
so ``deploy``'s ONNX runtime and ``lsr.pipeline``'s torch backend share them. Nothing heavy is imported here.
"""

MAX_K = 32  # most source shots averaged into a subject: the thesis evaluates K = 1..32 (Table 4.4)

# Adam lr of subject fine-tuning (thesis §4.3.5) for lsr reenact, lsr finetune, lsr eval, the app and the benches:
# a tenth of the training lr. On the warp-guided default, 10 steps at 1e-3 cost 0.05 dB on the validation people
# while 1e-4 keeps (slightly raises) PSNR (`lsr bench finetune --finetune-lr`, MODEL_CARD.md).
DEFAULT_FINETUNE_LR = 1e-4
