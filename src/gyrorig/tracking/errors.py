"""The tracking package's error."""

from __future__ import annotations

__all__ = ["TrackingError", "CameraFileError"]


class TrackingError(RuntimeError):
    """The video cannot be tracked (unreadable, camera mismatch, marker never found)."""


class CameraFileError(TrackingError, ValueError):
    """``camera.json`` is unreadable or holds a value outside its allowed range (bad input: exit 2)."""
