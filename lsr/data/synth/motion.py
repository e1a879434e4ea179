"""Smooth per-frame "talking" motion: head pose, expression, gaze and light.

Every signal is a sum of a few random sinusoids (smooth, bounded, deterministic from the
rng) around a per-video mean; the mouth follows a syllable rhythm (3-5 Hz) under a slower
speech/pause envelope; blinks are short dips of eye openness at random times.

Pose conventions are those of ``landmarks.motion.head_pose``: yaw > 0 turns the face towards the image
right (the nose tip moves right), pitch > 0 tilts it up, roll > 0 rotates it clockwise on
screen. Angles in degrees.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lsr.data.synth.distributions import Preset


@dataclasses.dataclass
class Motion:
    """Per-frame state, each an (N,) float64 array unless noted.

    yaw, pitch, roll: degrees; shift_x, shift_y: head translation in head units;
    mouth_open, smile, brow_raise in [0, 1]; eye_open in [0, 1] (0 = closed);
    gaze_x, gaze_y in [-1, 1]; light_dir (N, 3) unit vectors pointing from the light towards
    the scene (camera axes: x right, y down, z away from the camera); light, ambient: intensities.
    """

    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    shift_x: np.ndarray
    shift_y: np.ndarray
    mouth_open: np.ndarray
    smile: np.ndarray
    brow_raise: np.ndarray
    eye_open: np.ndarray
    gaze_x: np.ndarray
    gaze_y: np.ndarray
    light_dir: np.ndarray
    light: np.ndarray
    ambient: np.ndarray

    def __len__(self) -> int:
        return len(self.yaw)

    def pose(self) -> np.ndarray:
        """(N, 3) float32 yaw, pitch, roll in degrees."""
        return np.stack([self.yaw, self.pitch, self.roll], axis=1).astype(np.float32)

    def frame(self, index: int) -> dict[str, float | np.ndarray]:
        return {f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)}


def smooth_signal(rng: np.random.Generator, times: np.ndarray, amplitude: float, freq_range: tuple[float, float], terms: int = 3) -> np.ndarray:
    """Sum of ``terms`` random sinusoids with total peak amplitude ``amplitude``: (N,)."""
    freqs = rng.uniform(*freq_range, terms)
    phases = rng.uniform(0, 2 * np.pi, terms)
    weights = rng.uniform(0.3, 1.0, terms)
    weights *= amplitude / weights.sum()
    return (weights[:, None] * np.sin(2 * np.pi * freqs[:, None] * times[None] + phases[:, None])).sum(axis=0)


def _angle(rng: np.random.Generator, times: np.ndarray, base_sd: float, swing: float, limit: float) -> np.ndarray:
    base = float(np.clip(rng.normal(0.0, base_sd), -limit, limit))
    signal = base + smooth_signal(rng, times, rng.uniform(0.4, 1.0) * swing, (0.05, 0.45))
    # Soft clip keeps the motion smooth at the limits.
    return limit * np.tanh(signal / limit)


def sample_motion(rng: np.random.Generator, num_frames: int, fps: float, preset: Preset) -> Motion:
    """Draw the per-frame state of one video (see ``Motion``)."""
    times = np.arange(num_frames) / fps
    yaw = _angle(rng, times, preset.yaw_base_sd, preset.yaw_swing, preset.yaw_limit)
    pitch = _angle(rng, times, preset.pitch_base_sd, preset.pitch_swing, preset.pitch_limit)
    roll = _angle(rng, times, preset.roll_base_sd, preset.roll_swing, preset.roll_limit)
    shift_x = smooth_signal(rng, times, 0.04, (0.05, 0.3))
    shift_y = smooth_signal(rng, times, 0.03, (0.05, 0.3))
    # Talking: syllables at a drifting 3-5 Hz rate, gated by a slow speech/pause envelope.
    rate = rng.uniform(3.0, 5.0) + smooth_signal(rng, times, 0.8, (0.1, 0.4))
    phase = 2 * np.pi * np.cumsum(rate) / fps + rng.uniform(0, 2 * np.pi)
    envelope = np.clip(0.6 + smooth_signal(rng, times, 0.7, (0.1, 0.35)), 0.0, 1.0)
    mouth_open = np.clip(envelope * (0.15 + 0.85 * np.maximum(0.0, np.sin(phase))) * rng.uniform(0.6, 1.0), 0.0, 1.0)
    smile = np.clip(rng.uniform(0.0, 0.5) + smooth_signal(rng, times, 0.4, (0.03, 0.2)), 0.0, 1.0)
    brow_raise = np.clip(rng.uniform(0.0, 0.3) + smooth_signal(rng, times, 0.5, (0.1, 0.5)), 0.0, 1.0)
    eye_open = np.ones(num_frames)
    t = rng.exponential(3.0) * rng.uniform(0.2, 1.0)
    while t < times[-1] + 1.0:
        eye_open = np.minimum(eye_open, 1.0 - np.exp(-(((times - t) / 0.06) ** 2)))
        t += rng.uniform(1.5, 5.0)
    eye_open = np.clip(eye_open * rng.uniform(0.85, 1.0), 0.0, 1.0)
    gaze_x = np.clip(smooth_signal(rng, times, 0.5, (0.1, 0.6)), -1, 1)
    gaze_y = np.clip(smooth_signal(rng, times, 0.3, (0.1, 0.6)), -1, 1)
    light_x = rng.uniform(-0.7, 0.7) + smooth_signal(rng, times, 0.25, (0.02, 0.15))
    light_y = rng.uniform(-0.6, 0.2) + smooth_signal(rng, times, 0.15, (0.02, 0.15))
    light_dir = np.stack([light_x, light_y, np.ones(num_frames)], axis=1)
    light_dir /= np.linalg.norm(light_dir, axis=1, keepdims=True)
    light = np.clip(rng.uniform(0.65, 0.85) + smooth_signal(rng, times, 0.08, (0.05, 0.3)), 0.3, 1.0)
    ambient = np.full(num_frames, rng.uniform(0.35, 0.5))
    return Motion(yaw, pitch, roll, shift_x, shift_y, mouth_open, smile, brow_raise, eye_open, gaze_x, gaze_y, light_dir, light, ambient)
