"""``lsr synth``: procedural 3D talking heads with exact ground truth (CPU, numpy, seeded).

Public API: ``render_video`` -> ``SynthClip``, ``generate_dataset`` (writes ``lsr.data.format``),
``write_preview`` (contact sheet), ``benchmark``. Modules: identity (who), motion (per-frame
pose/expression/light), features (2D feature curves shared by landmarks and paint), geometry
(head ellipsoids, camera, landmarks), render (ray-caster), effects (occluders, exposure, blur,
noise), presets (hard cases).
"""

from lsr.data.synth.generate import (
    SynthClip,
    align_clip,
    benchmark,
    generate_dataset,
    identity_seed_of,
    render_framed,
    render_video,
)
from lsr.data.synth.distributions import PRESET_NAMES, PRESETS, Preset, get_preset

__all__ = [
    "PRESETS",
    "PRESET_NAMES",
    "Preset",
    "SynthClip",
    "benchmark",
    "generate_dataset",
    "get_preset",
    "identity_seed_of",
    "render_video",
    "render_framed",
    "align_clip",
    "write_preview",
]


def write_preview(*args, **kwargs):
    """See ``lsr.data.synth.preview.write_preview`` (imported lazily: it needs landmarks.shape.raster)."""
    from lsr.data.synth.preview import write_preview as _write_preview

    return _write_preview(*args, **kwargs)
