"""Limits and guards shared by every input reader.

* :class:`LoadLimits`: how much memory a file may make the readers allocate. Anything
  compressed (gzip SPZ, zstd SPZ v4, zip/npz members, WebP/PNG textures) may inflate to
  ``max(min_inflate_bytes, max_inflate_ratio × file size)`` at most, checked against
  the sizes the file *declares* before anything is allocated; row counts, image sides
  and JSON sizes have absolute caps. The defaults admit every real capture we know
  (the biggest inflate ~6× their file) while a 2 MB hostile file cannot ask for
  gigabytes. Change them for one block with :func:`load_limits`.
* :func:`require_input_file`: refuses FIFOs, devices and sockets *before* opening them
  (a FIFO given as a scene would otherwise block ``open`` forever).
* :func:`input_guard`: the last line of defence around a whole reader — a parse error
  that escaped the readers' own checks (``struct.error``, ``zlib.error``, a ``KeyError``
  from a foreign file, …) becomes one :class:`~divas_engine.errors.DivasInputError`
  naming the file. ``MemoryError`` is *not* converted: the limits exist to prevent it.
"""

from __future__ import annotations

import contextlib
import os
import stat
import struct
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, replace
from os import PathLike
from pathlib import Path

from ..errors import DivasInputError

__all__ = [
    "LoadLimits",
    "limits",
    "load_limits",
    "inflate_budget",
    "require_input_file",
    "input_guard",
    "PARSE_ERRORS",
]


@dataclass(frozen=True)
class LoadLimits:
    """Caps on what a file may make the readers allocate.

    Attributes:
        max_inflate_ratio: decompressed bytes per byte of input file (all streams of a
            file together).
        min_inflate_bytes: any file may inflate to at least this many bytes.
        max_rows: primitives (Gaussians, grid cells) in one scene.
        max_image_side: pixels per side of a texture or camera image.
        max_json_bytes: size of a JSON input (cameras, transforms, prompts, sessions).
        max_clicks: clicks (anchor clicks plus centroid-view points) in a prompts file.
    """

    max_inflate_ratio: float = 256.0
    min_inflate_bytes: int = 256 << 20
    max_rows: int = (1 << 31) - 1
    max_image_side: int = 16384 * 4
    max_json_bytes: int = 64 << 20
    max_clicks: int = 10_000


_LIMITS = LoadLimits()


def limits() -> LoadLimits:
    """The limits in force."""
    return _LIMITS


@contextlib.contextmanager
def load_limits(**changes) -> Iterator[LoadLimits]:
    """Override fields of the limits for the duration of a ``with`` block."""
    global _LIMITS
    old = _LIMITS
    _LIMITS = replace(old, **changes)
    try:
        yield _LIMITS
    finally:
        _LIMITS = old


def inflate_budget(file_size: int) -> int:
    """Bytes a file of ``file_size`` bytes may decompress to (:class:`LoadLimits`)."""
    lim = _LIMITS
    return int(max(lim.min_inflate_bytes, lim.max_inflate_ratio * max(0, file_size)))


def require_input_file(path: str | PathLike, what: str, *, allow_dir: bool = False) -> Path:
    """``path`` if it is an existing regular file (or folder with ``allow_dir``).

    Uses ``stat`` only, so a FIFO or device is refused without being opened.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise DivasInputError(p, f"{what} does not exist") from None
    except OSError as e:
        raise DivasInputError(p, f"cannot access {what} ({e.strerror or e})") from None
    if stat.S_ISREG(st.st_mode) or (allow_dir and stat.S_ISDIR(st.st_mode)):
        return p
    if stat.S_ISDIR(st.st_mode):
        raise DivasInputError(p, f"is a directory, expected a {what}")
    kind = (
        "FIFO (named pipe)"
        if stat.S_ISFIFO(st.st_mode)
        else "device"
        if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
        else "socket"
        if stat.S_ISSOCK(st.st_mode)
        else "special file"
    )
    raise DivasInputError(p, f"is a {kind}, not a regular file; expected a {what}")


#: What a malformed file can make the parsers raise besides DivasInputError.
PARSE_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,
    TypeError,
    KeyError,
    IndexError,
    AttributeError,
    OverflowError,
    ZeroDivisionError,
    EOFError,
    RecursionError,
    NotImplementedError,
    UnicodeError,
    struct.error,
    zlib.error,
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    OSError,
)


def _extra_errors() -> tuple[type[BaseException], ...]:
    extra: list[type[BaseException]] = []
    with contextlib.suppress(ImportError):
        import cv2

        extra.append(cv2.error)
    with contextlib.suppress(ImportError):
        import zstandard

        extra.append(zstandard.ZstdError)
    return tuple(extra)


@contextlib.contextmanager
def input_guard(path: str | PathLike, what: str) -> Iterator[None]:
    """Turn a parse error escaping a reader into a :class:`DivasInputError` on ``path``."""
    try:
        yield
    except DivasInputError:
        raise
    except PARSE_ERRORS + _extra_errors() as e:
        if isinstance(e, OSError) and e.strerror:
            msg = f"{e.strerror}" + (f": {e.filename}" if e.filename else "")
        else:
            msg = f"{type(e).__name__}: {e}"
        if len(msg) > 300:
            msg = msg[:300] + "…"
        raise DivasInputError(path, f"cannot read {what}: malformed or unreadable ({msg})") from e
