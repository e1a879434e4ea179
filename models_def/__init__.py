"""LSR networks (nn.Modules only; imports torch, kornia and safetensors).

Entry points: ``ModelConfig`` / ``preset_config`` to describe a model, ``LSRModel`` (SubjectEncoder +
FrameGenerator) and ``Discriminator`` to build it, ``save_pretrained`` / ``from_pretrained`` to store it.
"""

from models_def.config import NUM_SEG_CLASSES, VARIANTS, ModelConfig, ModelConfigError
from models_def.discriminator import Discriminator, minibatch_stddev_group
from models_def.encoder import SubjectEncoder, TwoHeadedEncoder, encode_k_shots
from models_def.lsr_model import FrameGenerator, FrameOutputs, LSRModel, LSROutputs
from models_def.presets import PRESET_NAMES, PRESETS, preset_config

__all__ = [
    "NUM_SEG_CLASSES",
    "PRESETS",
    "PRESET_NAMES",
    "VARIANTS",
    "Discriminator",
    "FrameGenerator",
    "FrameOutputs",
    "LSRModel",
    "LSROutputs",
    "ModelConfig",
    "ModelConfigError",
    "SubjectEncoder",
    "TwoHeadedEncoder",
    "encode_k_shots",
    "minibatch_stddev_group",
    "preset_config",
]
