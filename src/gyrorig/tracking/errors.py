"""The tracking package's error."""

from __future__ import annotations

__all__ = ["TrackingError", "BadInputError", "CameraFileError"]


class TrackingError(RuntimeError):
    """The video cannot be tracked (unreadable, camera mismatch, marker never found)."""


class BadInputError(TrackingError, ValueError):
    """An input file is unreadable or malformed (bad input: exit 2), as opposed to footage that cannot be
    tracked (exit 3)."""


class CameraFileError(BadInputError):
    """``camera.json`` is unreadable or holds a value outside its allowed range (bad input: exit 2)."""
