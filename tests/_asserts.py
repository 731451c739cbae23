"""Domain asserts shared by the tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def assert_plot(path: str | Path, *, min_size_px: int = 300) -> None:
    """``path`` is a PNG of a drawn figure: it decodes, is at least ``min_size_px`` on each side, and holds
    lines and text (some dark pixels, but mostly background), not a blank or a solid image."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"{path}: not a readable image"
    h, w = img.shape
    assert min(h, w) >= min_size_px, (path, img.shape)
    ink = float(np.mean(img < 128))
    assert 0.002 < ink < 0.5, (path, "fraction of dark pixels", ink)
