"""Typed, user-facing errors of the ``lsr`` package.

Every error a user can cause (bad input, bad config, missing weights) is an
``LsrError`` whose message says what to do. The CLI prints it as one line and
exits non-zero.
"""


class LsrError(Exception):
    """Base class of every user-facing error raised by ``lsr``."""


class ConfigError(LsrError, ValueError):
    """A configuration value is invalid or inconsistent."""


class DatasetError(LsrError):
    """A dataset on disk is missing, malformed or inconsistent."""


class WeightsError(LsrError):
    """Model or backbone weights are missing or do not match the config."""
