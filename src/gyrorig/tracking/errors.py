"""The tracking package's error."""

from __future__ import annotations

__all__ = ["TrackingError"]


class TrackingError(RuntimeError):
    """The video cannot be tracked (unreadable, camera mismatch, marker never found)."""
