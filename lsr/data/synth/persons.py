"""Random identity (who the head is) and per-video scene (background, framing jitter).

An ``Identity`` is drawn from one seed and never changes between its videos; a
``Scene`` (background) is drawn per video, as in VoxCeleb2 where one person appears
in several recordings. All sizes are factors around 1 applied to the head model of
``geometry.py``; colours are RGB floats in [0, 1].
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

HairStyle = Literal["short", "long", "bald", "fringe"]
HAIR_STYLES: tuple[str, ...] = ("short", "long", "bald", "fringe")
BackgroundKind = Literal["flat", "gradient", "textured"]

# Light to dark skin tones (RGB 0-255); a tone is interpolated between two neighbours.
_SKIN_TONES = np.array(
    [[250, 218, 190], [236, 188, 155], [220, 165, 125], [190, 130, 92], [140, 90, 60], [95, 62, 42]], np.float64
) / 255.0
_HAIR_COLOURS = np.array(
    [[28, 22, 20], [55, 38, 28], [100, 66, 42], [190, 150, 95], [140, 62, 34], [150, 150, 150], [70, 60, 55]], np.float64
) / 255.0
_IRIS_COLOURS = np.array([[70, 45, 25], [40, 28, 20], [60, 100, 140], [80, 110, 70], [110, 80, 50]], np.float64) / 255.0


@dataclasses.dataclass(frozen=True)
class Identity:
    """Shape and appearance of one synthetic person (factors ~1 scale the base head)."""

    head_width: float
    head_length: float
    jaw_width: float
    face_length: float
    nose_length: float
    nose_width: float
    nose_depth: float
    ear_size: float
    eye_size: float
    eye_spacing: float
    lip_size: float
    brow_thickness: float
    brow_arch: float
    skin: tuple[float, float, float]
    lip_colour: tuple[float, float, float]
    iris: tuple[float, float, float]
    hair_style: str
    hair_colour: tuple[float, float, float]
    hair_volume: float
    brow_colour: tuple[float, float, float]
    glasses: bool
    glasses_colour: tuple[float, float, float]
    beard: bool
    hat: bool
    hat_colour: tuple[float, float, float]
    cloth_colour: tuple[float, float, float]
    cloth_stripes: bool

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class Scene:
    """Per-video background and framing: kind, two colours, texture seed, scale/offset jitter."""

    background: str
    colour_a: tuple[float, float, float]
    colour_b: tuple[float, float, float]
    gradient_angle: float
    texture_seed: int
    scale_jitter: float
    offset_x: float
    offset_y: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _rgb(values: np.ndarray) -> tuple[float, float, float]:
    values = np.clip(values, 0.0, 1.0)
    return (float(values[0]), float(values[1]), float(values[2]))


def sample_identity(rng: np.random.Generator, hat_probability: float = 0.1) -> Identity:
    """Draw one identity. Every field is drawn in a fixed order, so a seed is a person."""
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    tone_pos = rng.uniform(0, len(_SKIN_TONES) - 1)
    low = int(np.floor(tone_pos))
    high = min(low + 1, len(_SKIN_TONES) - 1)
    skin = _SKIN_TONES[low] * (1 - (tone_pos - low)) + _SKIN_TONES[high] * (tone_pos - low)
    skin = skin * rng.uniform(0.95, 1.05, 3)
    lip = skin * np.array([0.82, 0.52, 0.52]) + np.array([0.08, 0.0, 0.02])
    hair = _HAIR_COLOURS[rng.integers(len(_HAIR_COLOURS))] * rng.uniform(0.85, 1.15)
    style = HAIR_STYLES[int(rng.choice(4, p=[0.4, 0.3, 0.12, 0.18]))]
    brow = np.minimum(hair * 0.8, skin * 0.45)
    return Identity(
        head_width=u(0.93, 1.07),
        head_length=u(0.95, 1.05),
        jaw_width=u(0.88, 1.1),
        face_length=u(0.92, 1.08),
        nose_length=u(0.85, 1.15),
        nose_width=u(0.85, 1.2),
        nose_depth=u(0.85, 1.2),
        ear_size=u(0.85, 1.2),
        eye_size=u(0.9, 1.12),
        eye_spacing=u(0.94, 1.06),
        lip_size=u(0.85, 1.2),
        brow_thickness=u(0.8, 1.3),
        brow_arch=u(0.5, 1.5),
        skin=_rgb(skin),
        lip_colour=_rgb(lip),
        iris=_rgb(_IRIS_COLOURS[rng.integers(len(_IRIS_COLOURS))]),
        hair_style=style,
        hair_colour=_rgb(hair),
        hair_volume=u(1.0, 1.12),
        brow_colour=_rgb(brow),
        glasses=bool(rng.random() < 0.2),
        glasses_colour=_rgb(rng.uniform(0.0, 0.35, 3)),
        beard=bool(rng.random() < 0.12),
        hat=bool(rng.random() < hat_probability),
        hat_colour=_rgb(rng.uniform(0.05, 0.9, 3)),
        cloth_colour=_rgb(rng.uniform(0.05, 0.95, 3)),
        cloth_stripes=bool(rng.random() < 0.25),
    )


def sample_scene(rng: np.random.Generator, jitter: float = 1.0) -> Scene:
    """Draw a background and a small framing jitter for one video."""
    kind = ("flat", "gradient", "textured")[int(rng.integers(3))]
    colour_a = rng.uniform(0.05, 0.95, 3)
    colour_b = np.clip(colour_a + rng.uniform(-0.4, 0.4, 3), 0, 1)
    return Scene(
        background=kind,
        colour_a=_rgb(colour_a),
        colour_b=_rgb(colour_b),
        gradient_angle=float(rng.uniform(0, 2 * np.pi)),
        texture_seed=int(rng.integers(2**31)),
        scale_jitter=float(rng.uniform(-0.05, 0.05) * jitter),
        offset_x=float(rng.uniform(-0.03, 0.03) * jitter),
        offset_y=float(rng.uniform(-0.03, 0.03) * jitter),
    )
