"""Named distributions of the generator: the default one and the hard cases.

A preset only changes *distributions* (pose range, framing, occluders, exposure, blur,
noise); identities stay those of the seed, so ``--preset`` re-renders the same people.
"""

from __future__ import annotations

import dataclasses

from lsr.errors import ConfigError


@dataclasses.dataclass(frozen=True)
class Preset:
    """Distribution knobs. Angles in degrees; ``face_scale`` multiplies the default framing."""

    name: str
    yaw_base_sd: float = 14.0  # per-video mean yaw ~ N(0, sd), clipped to yaw_limit
    yaw_swing: float = 14.0  # amplitude of the smooth "talking" yaw motion around the mean
    yaw_limit: float = 45.0  # soft limit (tanh): |yaw| stays below it
    pitch_base_sd: float = 6.0
    pitch_swing: float = 6.0
    pitch_limit: float = 20.0
    roll_base_sd: float = 4.0
    roll_swing: float = 5.0
    roll_limit: float = 15.0
    face_scale: tuple[float, float] = (0.95, 1.05)  # range of the per-video framing factor
    occluder_fraction: float = 0.1  # fraction of frames with a transient occluder
    occluder_size: float = 1.0
    exposure: tuple[float, float] = (0.9, 1.1)  # per-video gain range
    gamma: float = 1.0
    motion_blur_px: float = 0.0  # blur length at 128 px (scaled with the size), 0 = off
    noise_sd: float = 0.0  # Gaussian noise s.d. in [0, 255] units


PRESETS: dict[str, Preset] = {
    "default": Preset("default"),
    "extreme_pose": Preset(
        "extreme_pose", yaw_base_sd=50.0, yaw_swing=25.0, yaw_limit=60.0, pitch_base_sd=20.0,
        pitch_swing=12.0, pitch_limit=30.0, roll_base_sd=10.0, roll_swing=8.0, roll_limit=20.0,
    ),
    "tiny_face": Preset("tiny_face", face_scale=(0.45, 0.6)),
    "huge_face": Preset("huge_face", face_scale=(1.45, 1.7)),
    "heavy_occlusion": Preset("heavy_occlusion", occluder_fraction=0.6, occluder_size=1.5),
    "low_light": Preset("low_light", exposure=(0.18, 0.35), gamma=1.3, noise_sd=4.0),
    "overexposed": Preset("overexposed", exposure=(1.7, 2.4), gamma=0.8),
    "motion_blur": Preset("motion_blur", yaw_swing=20.0, motion_blur_px=5.0),
    "noise": Preset("noise", noise_sd=14.0),
}
PRESET_NAMES: tuple[str, ...] = tuple(PRESETS)


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise ConfigError(f"unknown synth preset {name!r}; choose one of {', '.join(PRESET_NAMES)}")
    return PRESETS[name]
