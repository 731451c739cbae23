"""Output helpers: files appear complete under their final name or not at all."""

from __future__ import annotations

import json
import math
import os
import platform
import tempfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["atomic_path", "output_folder", "OutputExistsError", "OUTPUT_MARKER", "write_csv", "write_json", "json_safe", "versions"]

#: text files whose contents may name their folder (rewritten from the temporary folder's name to the final one)
_TEXT_SUFFIXES = {".json", ".csv", ".html", ".md", ".toml", ".txt"}


class OutputExistsError(ValueError):
    """The output folder (or file) exists and holds something: refused without ``--overwrite`` (bad input)."""


#: every output folder gyrorig writes holds this file: ``--overwrite`` replaces only such a folder
OUTPUT_MARKER = ".gyrorig-output"
#: the largest settings file gyrorig reads (a protocol, camera.json, fit.json: real ones are a few kB) [bytes]
MAX_SETTINGS_BYTES = 16 * 2**20


class InputTooLarge(ValueError):
    """A settings file far larger than any real one (bad input: its parser would take minutes or all memory)."""


def read_settings_text(path: str | Path) -> str:
    """A settings file's text (protocol TOML, camera.json, plan.json): UTF-8, a leading byte-order mark dropped
    (Windows editors write one; TOML and JSON readers refuse it).  OSError and UnicodeDecodeError as reading
    raises them."""
    return Path(path).read_bytes().decode("utf-8-sig")


def table_encoding(path: str | Path) -> str:
    """The text encoding of a table file: UTF-8 (a leading byte-order mark, which Excel's "CSV UTF-8" writes,
    dropped), or Windows-1252 where the bytes are not UTF-8 (Excel on a Western-European Windows saves "CSV (comma
    delimited)" in that code page: a degree sign or a "±" in a header is then one byte no UTF-8 reader takes).
    OSError as reading raises it; UnicodeDecodeError for bytes that are neither."""
    data = Path(path).read_bytes()
    try:
        data.decode("utf-8")
        return "utf-8-sig"
    except UnicodeDecodeError:
        data.decode("cp1252")
        return "cp1252"


def read_table_csv(path: str | Path, *, numbers: bool = True, **kwargs) -> pd.DataFrame:
    """A CSV table as spreadsheets write it: comma-separated with decimal points, or (a European locale's Excel
    or OSP Tracker export) semicolon-separated with decimal commas, or tab-separated; in UTF-8 or Windows-1252
    (:func:`table_encoding`).  The separator is the
    header's: a ``;`` or a tab in it and no comma; with ``;`` and ``numbers`` a decimal comma in any cell becomes a
    point (``numbers=False``: cells of text, e.g. file names, kept as written).  ``kwargs`` go to
    :func:`pandas.read_csv` (``comment``, ``dtype``, ``skiprows`` as a list of 0-based line numbers, ...); its errors as
    it raises them."""
    comment = kwargs.get("comment")
    skipped = set(kwargs.get("skiprows") or ())
    encoding = kwargs.pop("encoding", None) or table_encoding(path)
    header = ""
    with open(path, encoding=encoding, errors="replace") as fh:
        for number, line in enumerate(fh):
            if number not in skipped and line.strip() and not (comment and line.lstrip().startswith(comment)):
                header = line
                break
    sep = ";" if ";" in header and "," not in header else "\t" if "\t" in header and "," not in header else ","
    if sep != ";" or not numbers:
        return pd.read_csv(path, sep=sep, encoding=encoding, **kwargs)
    table = pd.read_csv(path, sep=";", dtype=str, keep_default_na=False, encoding=encoding, **kwargs)
    return table.apply(lambda column: column.str.replace(",", ".", regex=False))


def check_settings_size(path: str | Path, what: str) -> None:
    """Refuse a settings file above :data:`MAX_SETTINGS_BYTES` (:class:`InputTooLarge`, naming it)."""
    try:
        size = Path(path).stat().st_size
    except OSError:
        return  # the reader says what is wrong with it
    if size > MAX_SETTINGS_BYTES:
        raise InputTooLarge(f"{path}: {size / 2**20:.0f} MiB is far larger than any {what} (at most "
                            f"{MAX_SETTINGS_BYTES // 2**20} MiB read)")


def _claim(final: Path, overwrite: bool) -> None:
    if final.is_symlink() or (final.exists() and not final.is_dir()):
        if final.is_dir() or not overwrite:
            raise OutputExistsError(f"{final}: exists and is not a folder; give another --out (or --overwrite to "
                                    "replace it)")
    elif final.is_dir() and any(final.iterdir()):
        if not overwrite:
            raise OutputExistsError(f"{final}: the output folder exists and is not empty; give a new --out, or "
                                    "--overwrite to replace it whole")
        if not (final / OUTPUT_MARKER).is_file():
            raise OutputExistsError(f"{final}: holds files gyrorig did not write (no {OUTPUT_MARKER} in it): "
                                    "--overwrite replaces only a folder gyrorig wrote; give another --out")


def _check_place(final: Path, keep: tuple[str | Path, ...]) -> None:
    """Refuse an output folder that is, or lies above, the working folder or one of the inputs (real paths:
    symbolic links followed), where replacing it would remove them."""
    real = final.resolve()
    here = Path.cwd().resolve()
    if real == here or real in here.parents:
        raise OutputExistsError(f"{final}: is the working folder or lies above it; give an --out inside it")
    for k in keep:
        kp = Path(k).resolve()
        if kp == real or real in kp.parents:
            raise OutputExistsError(f"{final}: the output folder holds an input ({k}); give another --out")


@contextmanager
def output_folder(final: str | Path, overwrite: bool = False, keep: tuple[str | Path, ...] = ()) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``final``; on success it replaces ``final`` whole.

    An existing non-empty ``final`` is refused (:class:`OutputExistsError`) unless ``overwrite``, and even then
    unless gyrorig wrote it (:data:`OUTPUT_MARKER` in it); a ``final`` that is or lies above the working folder or
    a path in ``keep`` (the command's inputs), real paths compared, is refused always.  The temporary
    name is unique to the process and the call, so concurrent runs never share it.  Text files
    naming the temporary folder are rewritten to name ``final``.  On any error (Ctrl-C included)
    the temporary folder is removed and ``final`` is left as it was.
    """
    import secrets
    import shutil

    final = Path(final).absolute()
    _check_place(final, keep)
    _claim(final, overwrite)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.parent / f".{final.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    tmp.mkdir()
    try:
        (tmp / OUTPUT_MARKER).write_text("written by gyrorig: --overwrite may replace this folder whole\n")
        yield tmp
        for f in tmp.rglob("*"):
            if f.suffix.lower() in _TEXT_SUFFIXES and f.is_file():
                text = f.read_text(errors="surrogateescape")
                if str(tmp) in text:
                    f.write_text(text.replace(str(tmp), str(final)), errors="surrogateescape")
        _claim(final, overwrite)  # another run may have filled it meanwhile: the same rule at the end
        trash = None
        if final.exists() or final.is_symlink():
            trash = final.parent / f".{final.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
            os.replace(final, trash)
        os.replace(tmp, final)
        if trash is not None:
            shutil.rmtree(trash) if trash.is_dir() and not trash.is_symlink() else trash.unlink()
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` only on success.

    If the body raises (or the process is interrupted), the temporary file is removed
    and nothing appears under the final name.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; outputs get the usual permissions
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _write(path: str | Path, writer: Callable[[Path], None]) -> Path:
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


#: a text cell starting with one of these is a formula to a spreadsheet (``=HYPERLINK(...)``): written with a ``'``
_FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def _inert(value: Any) -> Any:
    """A text cell a spreadsheet will not run as a formula: ``'`` before one that starts like one (a number
    written as text, ``-1.5``, is left as it is)."""
    if not isinstance(value, str) or not value.startswith(_FORMULA_STARTS):
        return value
    try:
        float(value)
        return value
    except ValueError:
        return "'" + value


def write_csv(df: pd.DataFrame, path: str | Path) -> Path:
    """Write a DataFrame as CSV (full float precision, no index), atomically; text cells that a spreadsheet would
    take for a formula start with ``'``."""
    text = [c for c in df.columns if df[c].dtype == object or pd.api.types.is_string_dtype(df[c].dtype)]
    if text:
        df = df.assign(**{c: df[c].map(_inert) for c in text})
    return _write(path, lambda p: df.to_csv(p, index=False, float_format="%.17g"))


def write_json(obj: Any, path: str | Path) -> Path:
    """Write JSON (indented, sorted keys), atomically."""

    def writer(p: Path) -> None:
        p.write_text(json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")

    return _write(path, writer)


def json_safe(obj: Any) -> Any:
    """Strict-JSON form: NaN and inf become null; numpy scalars and arrays become Python ones; records with a
    ``to_dict()`` (:class:`gyrorig.prediction.Prediction`, ...) their dict."""
    if is_dataclass(obj) and not isinstance(obj, type) and callable(getattr(obj, "to_dict", None)):
        return json_safe(obj.to_dict())
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def versions() -> dict[str, str]:
    """Versions of Python and the numerical libraries, for manifests."""
    import numba
    import numpy
    import scipy

    from . import __version__

    return {
        "gyrorig": __version__,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "pandas": pd.__version__,
        "numba": numba.__version__,
    }
