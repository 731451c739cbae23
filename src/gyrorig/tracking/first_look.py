"""The first frame the follower searched, kept to show why the tip was not found there: every spot that stood out
in it, each with what became of it (:class:`Verdict`), drawn by ``gyrorig track`` as ``DIR.first-look.png`` when
the tip is never found."""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from .detect import Detection

__all__ = ["Verdict", "Candidate", "FirstLook", "MAX_RECORDED"]


class Verdict(str, Enum):
    """What became of a spot that stood out in the first frame searched."""

    SIZE = "not the tip's size"
    LAB_MARKER = "a lab marker"
    OFF_SPHERE = "out of the tip's reach"
    NOT_FITTED = "fainter than the candidates fitted"
    NO_FIT = "no spot fit"
    SHAPE = "fitted, not the tip's shape or size"
    NOT_ALIKE = "fitted, unlike the tip before it was lost"
    UNCONFIRMED = "not found again in the next frame"
    WITH_SCENE = "moved with the scene"
    TAKEN = "taken for the tip"


@dataclass(frozen=True)
class Candidate:
    """A spot of the first frame searched: its centre and radius [px] and its :class:`Verdict`."""

    x_px: float
    y_px: float
    radius_px: float
    verdict: Verdict


#: the first look records at most this many spots
MAX_RECORDED = 60


@dataclass
class FirstLook:
    """The first frame the follower searched, the detection threshold, and every spot that stood out in it."""

    frame: np.ndarray
    threshold: Detection
    candidates: list
    #: the tip's image radius the protocol and camera predict (upright) [px]
    expected_radius_px: float
    settled: bool = False

    def settle(self, fits: list, near: list, kept: list) -> None:
        """The next frame's verdict on the first frame's fitted candidates (``fits``; ``near``: the pairs that
        found them again, ``kept``: the one taken): taken, moved with the scene, or not found again."""
        chosen = {id(p[4]) for p in kept}
        confirmed = {id(p[4]) for p in near}
        by_fit = {(f.x_px, f.y_px): f for f in fits}
        for k, c in enumerate(self.candidates):
            f = by_fit.get((c.x_px, c.y_px))
            if c.verdict is Verdict.UNCONFIRMED and f is not None:
                v = Verdict.TAKEN if id(f) in chosen else Verdict.WITH_SCENE if id(f) in confirmed else c.verdict
                self.candidates[k] = replace(c, verdict=v)
        self.settled = True

    def reasons(self) -> dict[str, int]:
        """How many spots had each verdict."""
        out: dict[str, int] = {}
        for c in self.candidates:
            out[c.verdict.value] = out.get(c.verdict.value, 0) + 1
        return out
