"""Typed, user-facing errors of the landmarks toolkit (no dependency on ``lsr``)."""


class LandmarksError(Exception):
    """Base class of every user-facing error raised by ``landmarks``."""


class InputFileError(LandmarksError):
    """A file is missing, unreadable, corrupt, empty or of an unsupported kind."""


class OutputPathError(LandmarksError):
    """An output cannot be written where asked (checked before the work starts)."""


class NoFaceError(LandmarksError):
    """No face was found where one is needed."""


class ModelFilesError(LandmarksError):
    """dlib model files (from the face_recognition_models package) cannot be found."""
