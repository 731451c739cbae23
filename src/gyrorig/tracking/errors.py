"""The tracking package's error."""

from __future__ import annotations

__all__ = ["TrackingError", "BadInputError", "CameraFileError"]


class TrackingError(RuntimeError):
    """The video cannot be tracked (unreadable, camera mismatch, marker never found).

    ``first_look``: when the tip was never found, the first frame searched and every spot that stood out in
    it with the reason it was refused (:class:`gyrorig.tracking.first_look.FirstLook`; None otherwise)."""

    def __init__(self, *args, first_look=None):
        super().__init__(*args)
        self.first_look = first_look


class BadInputError(TrackingError, ValueError):
    """An input file is unreadable or malformed (bad input: exit 2), as opposed to footage that cannot be
    tracked (exit 3)."""


class CameraFileError(BadInputError):
    """``camera.json`` is unreadable or holds a value outside its allowed range (bad input: exit 2)."""
