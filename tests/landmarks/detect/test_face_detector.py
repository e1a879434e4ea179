"""Face detection and 68 landmarks on the astronaut, on every image kind, and the error paths."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.detect import dlib_models as models
from landmarks.detect.face_detector import DlibDetector, Face
from landmarks.exceptions import InputFileError, ModelFilesError, NoFaceError
from landmarks.shape.ibug68 import LEFT_EYE, RIGHT_EYE


@pytest.fixture(scope="module")
def astronaut_face(detector, astronaut) -> Face:
    return detector.detect_one(astronaut)


def test_astronaut_has_exactly_one_face(detector, astronaut, astronaut_face):
    faces = detector.detect(astronaut)
    assert len(faces) == 1
    face = faces[0]
    assert face.box.shape == (4,) and face.box.dtype == np.float32
    assert face.landmarks.shape == (68, 2) and face.landmarks.dtype == np.float32
    assert face.score > 0.5
    # The face is at about x 175-265, y 76-166 in the 512x512 picture.
    assert 150 < face.box[0] < 200 and 240 < face.box[2] < 290 and 50 < face.box[1] < 110


def test_landmarks_inside_expanded_box(astronaut_face):
    x0, y0, x1, y1 = astronaut_face.box
    margin = 0.2 * (x1 - x0)
    points = astronaut_face.landmarks
    assert (points[:, 0] > x0 - margin).all() and (points[:, 0] < x1 + margin).all()
    assert (points[:, 1] > y0 - margin).all() and (points[:, 1] < y1 + margin).all()


def test_anatomical_order(astronaut_face):
    points = astronaut_face.landmarks
    brows_y = points[17:27, 1].mean()
    eyes_y = points[36:48, 1].mean()
    nose_tip_y = points[30, 1]
    mouth_y = points[48:68, 1].mean()
    assert brows_y < eyes_y < nose_tip_y < mouth_y < points[8, 1]  # chin lowest
    assert points[0, 0] < points[8, 0] < points[16, 0]  # jaw runs image-left to image-right
    # Eyes mirror about the centre line through the nose bridge.
    centre_x = points[27:31, 0].mean()
    left_eye, right_eye = points[LEFT_EYE].mean(axis=0), points[RIGHT_EYE].mean(axis=0)
    assert left_eye[0] < centre_x < right_eye[0]
    inter_ocular = right_eye[0] - left_eye[0]
    assert abs((centre_x - left_eye[0]) - (right_eye[0] - centre_x)) < 0.25 * inter_ocular
    assert abs(left_eye[1] - right_eye[1]) < 0.25 * inter_ocular


@pytest.mark.parametrize("kind", ["grey", "rgba", "uint16", "float"])
def test_other_array_kinds_give_the_same_landmarks(detector, astronaut, astronaut_face, kind):
    if kind == "grey":
        image = cv2.cvtColor(astronaut, cv2.COLOR_RGB2GRAY)
    elif kind == "rgba":
        image = np.dstack([astronaut, np.full(astronaut.shape[:2], 255, np.uint8)])
    elif kind == "uint16":
        image = astronaut.astype(np.uint16) * 257
    else:
        image = astronaut.astype(np.float32) / 255.0
    face = detector.detect_one(image)
    tolerance = 4.0 if kind == "grey" else 0.5  # grey changes the pixels the predictor sees
    assert np.abs(face.landmarks - astronaut_face.landmarks).mean() < tolerance


def test_exif_rotated_jpeg_matches_upright(tmp_path, detector, astronaut, astronaut_face):
    from PIL import Image

    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 clockwise to display"; the stored pixels are rotated the other way
    Image.fromarray(np.rot90(astronaut).copy()).save(tmp_path / "rotated.jpg", exif=exif.tobytes(), quality=95)
    face = detector.detect_one(tmp_path / "rotated.jpg")
    assert np.abs(face.landmarks - astronaut_face.landmarks).max() < 5.0


def test_very_large_image_reports_original_pixels(detector, astronaut, astronaut_face):
    large = cv2.resize(astronaut, None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)  # 2048 x 2048
    face = detector.detect_one(large)
    # dlib points are integers at pixel centres: x4 of an integer grid maps to (4x + 1.5).
    expected = astronaut_face.landmarks * 4 + 1.5
    assert np.abs(face.landmarks - expected).mean() < 4.0
    assert np.abs(face.box / 4 - astronaut_face.box).max() < 12.0


def test_faces_sorted_largest_first_and_index_selects(detector, astronaut):
    small = cv2.resize(astronaut, (384, 384), interpolation=cv2.INTER_AREA)
    canvas = np.full((512, 912, 3), 255, np.uint8)  # detection runs on it downscaled to 640 wide
    canvas[:, :512] = astronaut
    canvas[64:448, 520:904] = small
    faces = detector.detect(canvas)
    assert len(faces) == 2
    assert faces[0].area > faces[1].area
    assert faces[0].box[0] < 512 < faces[1].box[0]
    assert detector.detect_one(canvas, face_index=1).box[0] > 512
    with pytest.raises(NoFaceError, match="only 2 face"):
        detector.detect_one(canvas, face_index=2)


def test_cnn_detector_finds_the_face(astronaut, astronaut_face):
    crop = np.ascontiguousarray(astronaut[40:240, 120:320])  # 200x200 around the face keeps mmod fast on CPU
    faces = DlibDetector("cnn", upsample=0).detect(crop)
    assert len(faces) == 1
    shifted = faces[0].landmarks + np.array([120, 40], np.float32)
    assert np.abs(shifted - astronaut_face.landmarks).mean() < 5.0


def test_no_face_raises(detector, rng):
    noise = rng.integers(0, 256, (300, 400, 3), dtype=np.uint8)
    assert detector.detect(noise) == []
    with pytest.raises(NoFaceError, match="no face found in the image; use a photo where the face is visible"):
        detector.detect_one(noise)
    with pytest.raises(NoFaceError, match="no face found in blank"):
        detector.detect_one(np.zeros((64, 64, 3), np.uint8), name="blank")


def test_corrupt_file_raises_input_error(detector, tmp_path, rng):
    path = tmp_path / "photo.png"
    path.write_bytes(rng.integers(0, 256, 1000, dtype=np.uint8).tobytes())
    with pytest.raises(InputFileError, match="photo.png"):
        detector.detect(path)


def test_missing_model_files_say_how_to_install(monkeypatch):
    monkeypatch.setattr(models.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(ModelFilesError, match="pip install face_recognition_models"):
        models.model_path(models.SHAPE_PREDICTOR_68)


def test_models_load_once():
    assert models.shape_predictor_68() is models.shape_predictor_68()
    assert models.hog_face_detector() is models.hog_face_detector()
