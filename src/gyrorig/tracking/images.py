"""Frames stored as images: a folder of image files, one per frame, or a TIFF stack (many pages in one file, as
scientific cameras and ImageJ write them).

An image folder (:class:`ImageFolder`) holds one image per frame, PNG, TIFF or BMP (8 or 16 bit; a 16-bit file may
carry 12-bit values) or JPEG (8 bit; lossy: the sensor's noise model is then not used), in name order (numbers
in names compare as numbers: ``f9.png`` before ``f10.png``).  A folder holding images of several kinds is read as
its most numerous kind, and a warning counts the others left out.  A TIFF stack (:class:`TiffStack`) holds one
page per frame; a single-page TIFF is one frame.

Frame times come from a table with columns ``frame, t_s`` and one row per image in the same order (a camera that
dropped frames leaves gaps in ``t_s``): ``timestamps.csv`` in the folder, ``NAME.timestamps.csv`` beside a stack
``NAME.tif``, or a file given; without one, from the camera's rate.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import logging
import math
import re
import warnings
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from .errors import BadInputError
from .frames import Frames, _as_wanted, file_fingerprint, grid_fit

__all__ = ["ImageFolder", "TiffStack", "IMAGE_SUFFIXES", "read_timestamps"]

logger = logging.getLogger(__name__)

#: image files an :class:`ImageFolder` reads, by kind
IMAGE_KINDS = {"PNG": (".png",), "TIFF": (".tif", ".tiff"), "BMP": (".bmp",), "JPEG": (".jpg", ".jpeg")}
#: every suffix an :class:`ImageFolder` reads
IMAGE_SUFFIXES = tuple(s for suffixes in IMAGE_KINDS.values() for s in suffixes)
#: image kinds whose pixel values are not the sensor's (lossy compression)
LOSSY_KINDS = ("JPEG",)


def _name_key(path: Path) -> list:
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.name.lower())]


def _kind(path: Path) -> str | None:
    return next((k for k, suffixes in IMAGE_KINDS.items() if path.suffix.lower() in suffixes), None)


def read_timestamps(path: Path, count: int, what: str) -> np.ndarray:
    """Frame start times [s] from ``path`` (columns ``frame, t_s``, one row per frame of ``what``, which holds
    ``count`` frames), checked: numbers, increasing, one per frame."""
    import pandas as pd

    try:
        table = pd.read_csv(path)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise BadInputError(f"cannot read timestamps {path}: {exc}") from exc
    if "t_s" not in table.columns:
        raise BadInputError(f"{path}: needs a column t_s (and frame), one row per image")
    t = pd.to_numeric(table["t_s"], errors="coerce").to_numpy(float)
    if len(t) != count:
        raise BadInputError(f"{path}: {len(t)} rows for {count} images in {what}")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise BadInputError(f"{path}: row {int(bad[0]) + 1}, column t_s: not a number")
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        raise BadInputError(f"{path}: row {int(back[0]) + 2}, column t_s: times must increase "
                            f"({t[back[0]]:g} then {t[back[0] + 1]:g})")
    return t


def _checked(image: np.ndarray | None, where: str) -> np.ndarray:
    if image is None:
        raise BadInputError(f"{where}: unreadable image")
    if image.dtype not in (np.uint8, np.uint16):
        raise BadInputError(f"{where}: {image.dtype} pixels; allowed 8- or 16-bit")
    return image


class _Images:
    """What an image source shares: frame times, their grid, and frames checked for one size as they are read."""

    path: Path
    t_s: np.ndarray | None
    count: int
    lossy: bool = False
    #: a colour image's channel order as read
    order = "BGR"

    def __str__(self) -> str:
        return str(self.path)

    def frame_interval_s(self) -> float:
        """The interval between the frames [s] from their times (:func:`~gyrorig.tracking.frames.grid_fit`; NaN
        without timestamps)."""
        return self.frame_grid()[0]

    def frame_grid(self) -> tuple[float, float, int]:
        """:meth:`frame_interval_s` with its standard error and the number of frames (:func:`grid_fit`)."""
        return grid_fit(self.t_s) if self.t_s is not None else (math.nan, math.nan, 0)

    def _times(self, given, default: Path) -> np.ndarray | None:
        stamps = Path(given) if given is not None else default
        return read_timestamps(stamps, self.count, str(self.path)) if given is not None or stamps.exists() else None

    def _images(self):
        """``(image, where)`` for each frame in order."""
        raise NotImplementedError

    def open(self, *, colour: bool = False) -> Frames:
        images = self._images()
        first, where = next(images)
        h, w = first.shape[:2]
        times = self.t_s if self.t_s is not None else [math.nan] * self.count

        def items():
            try:
                for t, (image, at) in zip(times, itertools.chain([(first, where)], images)):
                    if image.shape[:2] != (h, w):
                        raise BadInputError(f"{at}: {image.shape[1]} x {image.shape[0]} pixels; the first image "
                                            f"({where}) is {w} x {h}")
                    yield np.ascontiguousarray(_as_wanted(image, colour, self.order)), float(t)
            finally:
                images.close()  # a stack's file, when the frames are closed before their end

        return Frames(int(w), int(h), math.nan, self.count, items(), lossy=self.lossy)


class ImageFolder(_Images):
    """A folder of images, one per frame (see the module docstring)."""

    def __init__(self, path: str | Path, timestamps: str | Path | None = None):
        self.path = Path(path)
        if not self.path.is_dir():
            raise BadInputError(f"{self.path}: not a folder of images")
        kinds: dict[str, list[Path]] = {}
        for f in self.path.iterdir():
            if (kind := _kind(f)) is not None and f.is_file():
                kinds.setdefault(kind, []).append(f)
        if not kinds:
            raise BadInputError(f"{self.path}: no images ({', '.join(IMAGE_SUFFIXES)})")
        kind = max(kinds, key=lambda k: len(kinds[k]))
        others = {k: len(v) for k, v in kinds.items() if k != kind}
        if others:
            logger.warning("%s: the frames are taken to be its %d %s images; %s left out", self.path,
                           len(kinds[kind]), kind, ", ".join(f"{n} {k}" for k, n in others.items()))
        self.files = sorted(kinds[kind], key=_name_key)
        pages = _page_count(self.files[0]) if kind == "TIFF" else 1
        if pages > 1:
            raise BadInputError(f"{self.files[0]}: a stack of {pages} pages, not one frame: give each stack itself "
                                "to track it")
        self.count, self.lossy = len(self.files), kind in LOSSY_KINDS
        self.t_s = self._times(timestamps, self.path / "timestamps.csv")

    def fingerprint(self) -> str:
        """The images' names and sizes and the frame times, hashed."""
        h = hashlib.sha256()
        for f in self.files:
            h.update(f"{f.name}\0{f.stat().st_size}\0".encode())
        if self.t_s is not None:
            h.update(np.asarray(self.t_s, float).tobytes())
        return h.hexdigest()

    def _images(self):
        for f in self.files:
            yield _checked(cv2.imread(str(f), cv2.IMREAD_UNCHANGED), str(f)), f.name


@contextlib.contextmanager
def _quiet():
    """Pillow's warnings about a file's tags left unsaid (a page it cannot read raises; one it can is read)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _page_count(path: Path) -> int:
    """The pages of a TIFF file (BadInputError when it is not one Pillow can read)."""
    try:
        with _quiet(), Image.open(path) as image:
            return int(getattr(image, "n_frames", 1))
    except (OSError, ValueError, EOFError) as exc:
        raise BadInputError(f"{path}: unreadable TIFF ({exc})") from exc


class TiffStack(_Images):
    """A TIFF file's pages, one per frame (see the module docstring), read in turn (Pillow: each page found from the
    last, where OpenCV's reader walks the file from its first page for every read)."""

    order = "RGB"

    def __init__(self, path: str | Path, timestamps: str | Path | None = None):
        self.path = Path(path)
        if not self.path.is_file():
            raise BadInputError(f"{self.path}: no such file")
        self.count = _page_count(self.path)
        self.t_s = self._times(timestamps, self.path.with_name(self.path.stem + ".timestamps.csv"))

    def fingerprint(self) -> str:
        """The file's size and its first and last MiB, and the frame times, hashed."""
        h = hashlib.sha256(file_fingerprint(self.path).encode())
        if self.t_s is not None:
            h.update(np.asarray(self.t_s, float).tobytes())
        return h.hexdigest()

    def _images(self):
        with _quiet():  # only around Pillow's calls: the filter is the process's, and frames are yielded between
            image = Image.open(self.path)
        try:
            for k in range(self.count):
                where = f"{self.path}, page {k + 1}"
                try:
                    with _quiet():
                        image.seek(k)
                        page = np.asarray(image.convert("L") if image.mode in ("P", "LA", "1") else image)
                except (OSError, ValueError, EOFError) as exc:
                    raise BadInputError(f"{where}: unreadable ({exc})") from exc
                if page.dtype.byteorder == ">":  # a big-endian 16-bit TIFF
                    page = page.astype(page.dtype.newbyteorder("="))
                yield _checked(page, where), f"page {k + 1}"
        finally:
            image.close()
