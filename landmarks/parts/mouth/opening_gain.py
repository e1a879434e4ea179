"""Warps that open a shot's mouth as far as the target's, as the detector reads it (issue 23: expressions beyond
the shots).

A warp that moves a shot's mesh vertices onto the target's opens the shot's lips by the *measured* difference of
openings, yet the detector reads the output's lips opened less than that: stretched lips and a stretched sliver of
mouth interior do not look like an open mouth, and a landmark detector regresses towards its mean face. Warping
one hold-out frame of each of the 4 validation people onto the others' meshes gives a mouth gain (output opening
on target opening) of 0.56; moving the mouth 1.5 times as far gives 0.92.

So where the target opens its mouth wider than the shot, the shot's expression around the mouth is moved further:
in the canonical head frame (``landmarks.motion.mesh_rotation``'s similarity on the rigid vertices, so a head turn is not
expression), the difference target - shot of the vertices around the mouth (``mouth_weights``) is applied up to
``EXPRESSION_GAIN`` times instead of once, by moving the shot's vertices back by (gain - 1) times it
(``amplify_mouth``). The warp then carries the shot's lips further, and the target's face layout, shared by every
reference, is untouched. The gain grows from 1 to ``EXPRESSION_GAIN`` as the target's opening exceeds the shot's
by 0 to ``CLOSED_MOUTH``: a shot that already shows the target's mouth, the usual case in self re-enactment, moves
as before.

Chosen on the 4 validation people with the warp-guided default (``lsr eval --data VAL --k 8 32``): cross-identity
mouth gain at K = 8 0.86 -> 1.00 (correlation 0.82 -> 0.83), at K = 32 0.87 -> 0.97 (0.88 -> 0.89); face PSNR in
self re-enactment -0.01 dB. Also tried there: a gain of 1.5 overshot (1.08, one person 1.76); the eyes and the
mouth both amplified 1.5 times, whatever the shots showed, cost 0.16 dB of face PSNR for +0.02 of eye
correlation; the eyes gated as the mouth is (fully from an eye-opening difference of 0.03) raised the eye
correlation 0.63 -> 0.68 for another -0.01 dB, so the eyes move as measured; only the vertical part of the
mouth's difference changed nothing (gain 1.02, the same face PSNR).

numpy only; the weights are made once from the canonical mesh.
"""

from __future__ import annotations

import functools

import numpy as np

from landmarks.shape.expression import CLOSED_MOUTH, mouth_opening
from landmarks.motion.mesh_rotation import canonical, mesh_rotation, to_head_frame

EXPRESSION_GAIN = 1.25
"""How many times the shot -> target expression around the mouth is applied, at most."""
GAIN_RANGE = (1.0, 2.0)
"""The gains a caller may choose (``lsr eval --expression-gains``, ``ReenactorBase.expression_gain``): 1 carries a
shot's mouth exactly onto the target's points; past 2 a warp folds the lips over."""
MOUTH_REACH = 0.45
"""The mouth region: full weight within half this fraction of the canonical face's eye distance of the inner
lips' centre, none beyond 1.5 times it (a linear ramp between)."""


@functools.lru_cache(maxsize=1)
def mouth_weights() -> np.ndarray:
    """(468,) float64 in [0, 1]: how much of each mesh vertex's expression is amplified (1 around the inner lips,
    0 from the eyes up), on the canonical mesh's x, y."""
    from landmarks.shape.mesh68 import mesh_to_68

    vertices = canonical()[0]
    points = mesh_to_68(vertices[:, :2]).astype(np.float64)  # (68, 2)
    distance = float(np.linalg.norm(points[36:42].mean(0) - points[42:48].mean(0)))
    ramp = np.linalg.norm(vertices[:, :2] - points[60:68].mean(0), axis=1) / (MOUTH_REACH * distance)
    weights = np.clip(1.5 - ramp, 0.0, 1.0)
    weights.setflags(write=False)
    return weights


def mouth_gain(shot_landmarks: np.ndarray, target_landmarks: np.ndarray, gain: float = EXPRESSION_GAIN) -> float:
    """The gain for one shot: 1 + (gain - 1) x (target opening - shot opening) / ``CLOSED_MOUTH``, clipped to
    [1, gain]. (68, 2), (68, 2) -> float (1 when an opening is not finite)."""
    excess = (float(mouth_opening(target_landmarks)) - float(mouth_opening(shot_landmarks))) / CLOSED_MOUTH
    return 1.0 + (gain - 1.0) * float(np.clip(excess, 0.0, 1.0)) if np.isfinite(excess) else 1.0


def amplify_mouth(shot_mesh: np.ndarray, target_mesh: np.ndarray, gain: float) -> np.ndarray:
    """The shot's mesh moved so that a warp onto ``target_mesh`` carries its mouth ``gain`` times the expression
    difference (module docstring). shot_mesh, target_mesh: (468, 3) frame pixels -> (468, 3) float64 (the shot's
    own vertices when ``gain`` is 1 or either mesh is not finite)."""
    shot = np.asarray(shot_mesh, np.float64)
    target = np.asarray(target_mesh, np.float64)
    if shot.shape != (468, 3) or target.shape != (468, 3):
        raise ValueError(f"meshes must be (468, 3), got {shot.shape} and {target.shape}")
    if gain == 1.0 or not (np.isfinite(shot).all() and np.isfinite(target).all()):
        return shot
    rotation, scale, _ = frame = mesh_rotation(shot)
    difference = to_head_frame(target, mesh_rotation(target)) - to_head_frame(shot, frame)  # canonical units
    return shot - (gain - 1.0) * mouth_weights()[:, None] * (scale * difference @ rotation.T)
