"""What a subject's shots cover of a face's moving parts, and K shots chosen to cover it.

The method borrows what the shots show: a driver that opens the mouth wider than any shot, closes the eyes
further, turns the head further or looks further aside asks for what no shot has. Each face is described by
``FEATURES`` (``face_features``):

* ``mouth``: inner-lip gap over the inter-ocular distance (``landmarks.shape.expression.mouth_opening``);
* ``eyes``: eyelid gap over the inter-ocular distance (``landmarks.shape.expression.eye_opening``);
* ``yaw`` / ``pitch``: head pose in degrees (``landmarks.motion.head_pose.estimate_head_pose`` on the rigid points);
* ``gaze``: the iris's horizontal offset in eye widths (``landmarks.parts.appearance.gaze``, read from the image;
  NaN where there is no image or the eyes are closed).

``choose_covering`` picks K of many candidate shots spread over a video, the most neutral face among them, and
swaps in the person's extreme moments (the widest mouth, the most closed eyes, the furthest turns and glances;
each feature in units of ``STEPS``) where no chosen shot shows them.
``beyond_shots`` flags the target frames that lie outside the shots' range (by more than ``MARGINS``), and
``describe`` says it in one line, with the shots that would help.
"""

from __future__ import annotations

import dataclasses

import numpy as np

FEATURES = ("mouth", "eyes", "yaw", "pitch", "gaze")
STEPS = {"mouth": 0.08, "eyes": 0.03, "yaw": 8.0, "pitch": 8.0, "gaze": 0.08}
"""One step of each feature is a visibly different face: about half a talking mouth's range, a third of an open
eye's lid gap, a head turned by 8 degrees, the iris moved by 8% of the eye's width."""
MARGINS = {"mouth": 0.03, "eyes": 0.015, "yaw": 5.0, "pitch": 5.0, "gaze": 0.06}
"""A target lies beyond the shots in a feature when it is outside their range by more than this (the landmark and
iris readings' own noise is about a third of it)."""
CLOSED_EYES = 0.6  # a shot's eye opening under this share of the shots' median shows the eyes (half) closed


def face_features(landmarks: np.ndarray, image_size: tuple[int, int], gazes: np.ndarray | None = None) -> np.ndarray:
    """``FEATURES`` of each face. landmarks: (N, 68, 2) x, y pixels (NaN rows: no face); image_size: (H, W) of the
    frames they live in; gazes: (N,) horizontal iris offsets in eye widths, or None (unknown) -> (N, 5) float64,
    NaN where unknown."""
    from landmarks.shape.expression import eye_opening, mouth_opening
    from landmarks.motion.head_pose import estimate_head_pose
    from landmarks.motion.retarget_points import RIGID_INDEX

    points = np.asarray(landmarks, np.float64)
    if points.ndim != 3 or points.shape[1:] != (68, 2):
        raise ValueError(f"landmarks must be (N, 68, 2), got {points.shape}")
    features = np.full((len(points), len(FEATURES)), np.nan)
    found = np.isfinite(points).all(axis=(1, 2))
    features[:, 0], features[:, 1] = mouth_opening(points), eye_opening(points)
    for index in np.flatnonzero(found):
        features[index, 2:4] = estimate_head_pose(points[index], image_size, RIGID_INDEX)[:2]
    if gazes is not None:
        gazes = np.asarray(gazes, np.float64)
        if gazes.shape != (len(points),):
            raise ValueError(f"gazes must be ({len(points)},), got {gazes.shape}")
        features[:, 4] = gazes
    features[~found] = np.nan
    return features


def spread(count: int, wanted: int) -> list[int]:
    """``wanted`` indices spread evenly over range(count) (all of them when count <= wanted), sorted."""
    return np.unique(np.round(np.linspace(0, count - 1, wanted)).astype(int)).tolist()


def _scaled(features: np.ndarray) -> np.ndarray:
    """Features in units of ``STEPS``, unknown values at 0 (they add no distance)."""
    steps = np.array([STEPS[name] for name in FEATURES])
    return np.nan_to_num(np.asarray(features, np.float64) / steps, nan=0.0)


EXTREMES = (("mouth", 1), ("eyes", -1), ("yaw", -1), ("yaw", 1), ("gaze", -1), ("gaze", 1), ("pitch", -1), ("pitch", 1))
"""The moments ``choose_covering`` looks for, in order: the widest mouth, the most closed eyes, the furthest turn
each way, the furthest glance each way, the furthest tilt each way."""


def choose_covering(features: np.ndarray, k: int, first: int, extremes: int | None = None) -> list[int]:
    """K of the candidates (in time order) that cover the person: spread evenly over them, ``first`` among them (the
    most neutral face: the anchor), then up to ``extremes`` (default K // 2, at least 1 from K = 2) of the person's
    extreme moments (``EXTREMES``, each taken where it is more than a ``STEPS`` unit away from every face chosen)
    in place of the chosen face most like another chosen one. The spread keeps what changes slowly over a video
    (light, framing) and the faces the person shows most: a warp-guided model blends the few shots nearest each
    target, and a set of extremes alone left the validation people's typical faces only unlike shots to blend (K = 8,
    self re-enactment, face PSNR 28.53 dB spread evenly, 28.10 by farthest-point sampling, 28.57 this way, with the
    hold-outs beyond every shot 23 -> 6 of 128).

    features: (N, 5) from ``face_features`` (rows with an unknown mouth, eyes or pose are never chosen as
    extremes); k: 1..N; first: an index of a usable row -> K sorted indices."""
    features = np.asarray(features, np.float64)
    if features.ndim != 2 or features.shape[1] != len(FEATURES):
        raise ValueError(f"features must be (N, {len(FEATURES)}), got {features.shape}")
    count = len(features)
    if not 1 <= k <= count:
        raise ValueError(f"k must be in 1..{count}, got {k}")
    if not 0 <= first < count:
        raise ValueError(f"first must index one of the {count} candidates, got {first}")
    chosen = spread(count, k)
    if first not in chosen:  # the anchor replaces the spread's pick nearest to it in time
        chosen[int(np.argmin(np.abs(np.array(chosen) - first)))] = int(first)
    limit = (max(1, k // 2) if k >= 2 else 0) if extremes is None else extremes
    scaled = _scaled(features)
    usable = np.flatnonzero(np.isfinite(features[:, :4]).all(axis=1))
    distances = np.linalg.norm(scaled[:, None] - scaled[None], axis=-1)  # (N, N) in STEPS units
    taken = 0
    for name, sign in EXTREMES:
        column = features[usable, FEATURES.index(name)]
        if taken >= limit or not np.isfinite(column).any():
            continue
        index = int(usable[np.nanargmax(sign * column)])
        if distances[index, chosen].min() <= 1.0:
            continue  # a chosen face shows it already
        others = [c for c in chosen if c != first]
        if not others:
            break
        # the chosen face most like another chosen one makes way
        redundancy = [min(distances[c, d] for d in chosen if d != c) for c in others]
        chosen[chosen.index(others[int(np.argmin(redundancy))])] = index
        taken += 1
    return sorted(chosen)


@dataclasses.dataclass(frozen=True)
class Beyond:
    """Which target frames lie beyond the shots. Each field: (T,) bool. ``mouth``: opened wider than every shot;
    ``eyes``: closed further than every shot; ``yaw_left`` / ``yaw_right``: turned further than every shot
    (negative / positive yaw); ``pitch``: tilted outside the shots' range; ``gaze``: the iris further aside
    than in every shot (False where a gaze is unknown)."""

    mouth: np.ndarray
    eyes: np.ndarray
    yaw_left: np.ndarray
    yaw_right: np.ndarray
    pitch: np.ndarray
    gaze: np.ndarray

    @property
    def yaw(self) -> np.ndarray:
        return self.yaw_left | self.yaw_right

    @property
    def any(self) -> np.ndarray:
        """(T,) bool: beyond the shots in any feature."""
        return self.mouth | self.eyes | self.yaw | self.pitch | self.gaze


def beyond_shots(shot_features: np.ndarray, target_features: np.ndarray) -> Beyond:
    """The target frames outside the shots' range by more than ``MARGINS`` (``Beyond``). shot_features: (K, 5),
    target_features: (T, 5), both from ``face_features`` in the same image size; NaN values are never beyond."""
    shots = np.asarray(shot_features, np.float64)
    targets = np.asarray(target_features, np.float64)
    if shots.ndim != 2 or targets.ndim != 2 or shots.shape[1] != len(FEATURES) or targets.shape[1] != len(FEATURES):
        raise ValueError(f"features must be (K, {len(FEATURES)}) and (T, {len(FEATURES)}), got {shots.shape}, "
                         f"{targets.shape}")

    def outside(column: int, below: bool) -> np.ndarray:
        name = FEATURES[column]
        values = shots[:, column][np.isfinite(shots[:, column])]
        wanted = targets[:, column]
        if not values.size:
            return np.zeros(len(targets), bool)
        with np.errstate(invalid="ignore"):
            if below:
                return np.nan_to_num(wanted < values.min() - MARGINS[name], nan=False).astype(bool)
            return np.nan_to_num(wanted > values.max() + MARGINS[name], nan=False).astype(bool)

    gaze = outside(4, True) | outside(4, False)
    return Beyond(mouth=outside(0, False), eyes=outside(1, True), yaw_left=outside(2, True),
                  yaw_right=outside(2, False), pitch=outside(3, True) | outside(3, False), gaze=gaze)


def _share(flags: np.ndarray) -> str:
    return f"{100.0 * flags.mean():.0f}%"


def describe(shot_features: np.ndarray, target_features: np.ndarray, who: str = "the driver") -> str:
    """One line on how much of the targets lies beyond the shots and which shots would help, e.g. "the driver
    opens the mouth wider than any shot in 38% of frames and closes the eyes further in 5% (no shot shows closed
    eyes): add shots with the mouth wide open and the eyes closed". (K, 5), (T, 5) -> str."""
    shots = np.asarray(shot_features, np.float64)
    flags = beyond_shots(shots, target_features)
    count = len(flags.mouth)
    if not count:
        return f"{who} has no frame with a face to compare with the shots"
    parts, wanted = [], []
    if flags.mouth.any():
        parts.append(f"opens the mouth wider than any shot in {_share(flags.mouth)} of frames")
        wanted.append("the mouth wide open")
    if flags.eyes.any():
        eyes = shots[:, 1][np.isfinite(shots[:, 1])]
        closed = eyes.size and eyes.min() < CLOSED_EYES * np.median(eyes)
        parts.append(f"closes the eyes further in {_share(flags.eyes)}"
                     + ("" if closed else " (no shot shows closed eyes)"))
        wanted.append("the eyes closed")
    for label, side in (("left", flags.yaw_left), ("right", flags.yaw_right)):
        if side.any():
            parts.append(f"turns further to the image's {label} in {_share(side)}")
            wanted.append(f"the head turned to the {label}")
    if flags.pitch.any():
        parts.append(f"tilts the head up or down further in {_share(flags.pitch)}")
        wanted.append("the head tilted")
    if flags.gaze.any():
        parts.append(f"looks further aside in {_share(flags.gaze)}")
        wanted.append("a glance aside")
    if not parts:
        return (f"the shots cover {who}: no frame opens the mouth wider, closes the eyes further, or turns or looks "
                "further than some shot")
    joined = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]
    helps = wanted[0] if len(wanted) == 1 else ", ".join(wanted[:-1]) + " and " + wanted[-1]
    return f"{who} {joined} ({_share(flags.any)} of frames in all): shots with {helps} would help"


LABELS = {"mouth": "mouth opening", "eyes": "eye opening", "yaw": "head yaw (deg)", "pitch": "head pitch (deg)",
          "gaze": "gaze (eye widths)"}
PICTURE_WIDTH, ROW_HEIGHT, LABEL_WIDTH, SHARE_WIDTH = 720, 40, 150, 110
COLOURS = {"covered": (210, 210, 210), "shot": (30, 90, 220), "inside": (90, 90, 90), "beyond": (220, 40, 40)}


def coverage_picture(shot_features: np.ndarray, target_features: np.ndarray) -> np.ndarray:
    """What the shots cover, as a picture: a row per feature (``LABELS``), the shots' range (grown by ``MARGINS``)
    as a grey band with a blue mark per shot, each target frame a tick, dark inside the band and red beyond it,
    and the share beyond at the right. (K, 5), (T, 5) from ``face_features`` -> (H, ``PICTURE_WIDTH``, 3) uint8
    RGB. A feature no shot has (NaN) is left out; one no target has says so."""
    import cv2

    shots = np.asarray(shot_features, np.float64)
    targets = np.asarray(target_features, np.float64).reshape(-1, len(FEATURES))
    flags = beyond_shots(shots, targets)
    beyond = {"mouth": flags.mouth, "eyes": flags.eyes, "yaw": flags.yaw, "pitch": flags.pitch, "gaze": flags.gaze}
    rows = [name for column, name in enumerate(FEATURES) if np.isfinite(shots[:, column]).any()]
    image = np.full((ROW_HEIGHT * (len(rows) + 1), PICTURE_WIDTH, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(image, "shots (blue), the driven frames (dark: a shot is near, red: beyond every shot)",
                (8, 24), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    left, right = LABEL_WIDTH, PICTURE_WIDTH - SHARE_WIDTH
    for row, name in enumerate(rows, start=1):
        column = FEATURES.index(name)
        shot_values = shots[:, column][np.isfinite(shots[:, column])]
        target_values = targets[:, column]
        known = np.isfinite(target_values)
        values = np.concatenate([shot_values, target_values[known]])
        low, high = values.min() - MARGINS[name], values.max() + MARGINS[name]
        low, high = min(low, shot_values.min() - STEPS[name] / 2), max(high, shot_values.max() + STEPS[name] / 2)

        def x(value: float) -> int:
            return int(round(left + (value - low) / (high - low) * (right - left)))

        middle = ROW_HEIGHT * row + ROW_HEIGHT // 2
        cv2.putText(image, LABELS[name], (8, middle + 5), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        band = (x(shot_values.min() - MARGINS[name]), x(shot_values.max() + MARGINS[name]))
        cv2.rectangle(image, (band[0], middle - 12), (band[1], middle + 12), COLOURS["covered"], -1)
        cv2.line(image, (left, middle), (right, middle), (170, 170, 170), 1)
        for value, outside in zip(target_values[known], beyond[name][known]):
            colour = COLOURS["beyond"] if outside else COLOURS["inside"]
            cv2.line(image, (x(value), middle - 6), (x(value), middle + 6), colour, 1)
        for value in shot_values:
            cv2.line(image, (x(value), middle - 14), (x(value), middle + 14), COLOURS["shot"], 2)
        share = f"{100.0 * beyond[name][known].mean():.0f}% beyond" if known.any() else "not measured"
        colour = COLOURS["beyond"] if known.any() and beyond[name][known].any() else (0, 0, 0)
        cv2.putText(image, share, (right + 10, middle + 5), font, 0.45, colour, 1, cv2.LINE_AA)
    return image


MOMENTS = (
    ("straight ahead", "look into the camera, mouth closed"),
    ("mouth wide open", "open your mouth as wide as you can"),
    ('"O"', 'round your lips into an "O"'),
    ("eyes closed", "close your eyes"),
    ("glance left", "look to your left without turning"),
    ("glance right", "look to your right without turning"),
    ("turn left", "turn your head to the left"),
    ("turn right", "turn your head to the right"),
    ("smile", "smile"),
)
"""The moments a recording asks for, each (name, what to do): the range the method borrows from its shots."""


BASELINE_FRAMES = 150
"""A recording's baseline is the median of its last this many faces (6 s at 25 fps)."""


@dataclasses.dataclass
class MomentKeeper:
    """The best frame of each of ``MOMENTS`` seen so far in a recording (a webcam's frames, one at a time).

    A frame's score for a moment (larger is better): straight ahead = frontal, eyes open, mouth closed; mouth wide
    open = the mouth's opening; "O" = an open mouth that is narrow for its height; eyes closed = the eyes' closing;
    glances = the iris's offset (``landmarks.parts.appearance.gaze``) with a frontal head; turns = the head's yaw; smile =
    the mouth's width with the lips closed. A moment keeps a frame only where it scores better than the first frames
    did (their baseline: the median of the last ``BASELINE_FRAMES`` faces), by at least a step of the feature (``STEPS``), so a
    recording of a still face keeps only "straight ahead" (always the best so far). Left and right are the
    image's.
    """

    frames: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    landmarks: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    scores: dict[str, float] = dataclasses.field(default_factory=dict)
    seen: list[np.ndarray] = dataclasses.field(default_factory=list)

    def measures(self, frame: np.ndarray, points: np.ndarray) -> dict[str, float]:
        """The frame's raw measures: mouth, eyes, yaw, pitch, gaze (``face_features``), width (mouth width over
        eye distance) and roundness (mouth opening over its width)."""
        from landmarks.parts.appearance import gaze
        from landmarks.shape.measures import inter_ocular_distance

        gazes = np.array([gaze(frame, points)[0]])
        mouth, eyes, yaw, pitch, glance = face_features(points[None], frame.shape[:2], gazes)[0]
        eye_distance = float(inter_ocular_distance(points))
        width = float(np.linalg.norm(points[54] - points[48])) / max(eye_distance, 1e-6)
        return {"mouth": mouth, "eyes": eyes, "yaw": yaw, "pitch": pitch, "gaze": glance, "width": width,
                "roundness": mouth / max(width, 1e-6)}

    def add(self, frame: np.ndarray, points: np.ndarray) -> list[str]:
        """Consider one frame (H, W, 3) uint8 with its face's landmarks (68, 2); returns the moments it now holds."""
        points = np.asarray(points, np.float64)
        if points.shape != (68, 2) or not np.isfinite(points).all():
            return []
        measure = self.measures(frame, points)
        self.seen = [*self.seen[-(BASELINE_FRAMES - 1):], np.array([measure[key] for key in
                                                                     ("mouth", "eyes", "yaw", "pitch", "gaze", "width")])]
        baseline = np.nanmedian(np.stack(self.seen), axis=0)
        mouth, eyes, yaw, pitch, glance, width = (measure[key] for key in ("mouth", "eyes", "yaw", "pitch", "gaze", "width"))
        frontal = (abs(yaw) + abs(pitch - baseline[3])) / STEPS["yaw"]  # a camera above or below tilts every frame
        scores = {
            "straight ahead": -frontal - mouth / STEPS["mouth"] - max(0.0, baseline[1] - eyes) / STEPS["eyes"],
            "mouth wide open": (mouth - baseline[0]) / STEPS["mouth"],
            '"O"': (mouth - baseline[0]) / STEPS["mouth"] * min(1.0, measure["roundness"] / 0.6)
            - max(0.0, width - baseline[5]) / 0.1,
            "eyes closed": (baseline[1] - eyes) / STEPS["eyes"],
            "glance left": (baseline[4] - glance) / STEPS["gaze"] - frontal,
            "glance right": (glance - baseline[4]) / STEPS["gaze"] - frontal,
            "turn left": (baseline[2] - yaw) / STEPS["yaw"],
            "turn right": (yaw - baseline[2]) / STEPS["yaw"],
            "smile": (width - baseline[5]) / 0.1 - max(0.0, mouth - baseline[0]) / STEPS["mouth"],
        }
        kept = []
        for name, _ in MOMENTS:
            score = scores[name]
            enough = name == MOMENTS[0][0] or score >= 1.0  # straight ahead: the best so far, whatever it is
            if np.isfinite(score) and enough and score > self.scores.get(name, -np.inf):
                self.frames[name], self.landmarks[name], self.scores[name] = frame.copy(), points, float(score)
                kept.append(name)
        return kept

    def shots(self) -> list[tuple[str, np.ndarray]]:
        """The kept moments in ``MOMENTS`` order: (name, frame)."""
        return [(name, self.frames[name]) for name, _ in MOMENTS if name in self.frames]

    def missing(self) -> list[str]:
        """The moments not caught yet, in ``MOMENTS`` order."""
        return [name for name, _ in MOMENTS if name not in self.frames]
