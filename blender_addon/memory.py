"""Keep freed memory out of Blender's resident set during a session.

A render or an accept allocates and frees many arrays of 1–32 MB. glibc's ``malloc`` serves
those from its heap once its adaptive mmap threshold has grown past their size, and a freed
chunk in the middle of the heap stays resident, so the RSS of a large session grows by free
heap under the renders' peaks. Two glibc settings fix it without changing any result:

* :func:`limit_heap` (when a session of :data:`LIMIT_FROM` primitives or more starts:
  :func:`limit_heap_for`): a fixed mmap threshold of :data:`MMAP_THRESHOLD` — arrays from
  4 MB on get pages of their own and give them back when freed, so the RSS follows what is in
  use, at a few % more CPU for page faults; smaller scenes keep the adaptive threshold;
* :func:`release_freed` (after the steps that render: import, Start, a click, an accept, a
  first look through an anchor, an overlay drawn the first time): ``malloc_trim(0)`` hands the
  heap's free pages back.

Both are no-ops where glibc is not the allocator (macOS, Windows, musl).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import time

__all__ = [
    "MMAP_THRESHOLD",
    "LIMIT_FROM",
    "limit_heap",
    "limit_heap_for",
    "release_freed",
    "last_seconds",
]

#: allocations from this size on are mapped on their own (glibc ``M_MMAP_THRESHOLD``)
MMAP_THRESHOLD = 4 << 20
#: sessions of this many primitives or more fix the threshold (:func:`limit_heap_for`)
LIMIT_FROM = 2_000_000
_M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter number

_libc = None
_looked = False
_limited = False
#: seconds the last :func:`release_freed` took (0.0 when it did nothing)
last_seconds = 0.0


def _glibc():
    """glibc's ``malloc_trim`` and ``mallopt``, or None (another C library)."""
    global _libc, _looked
    if not _looked:
        _looked = True
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                trim, opt = libc.malloc_trim, libc.mallopt  # glibc only
            except (OSError, AttributeError):
                trim = opt = None
            if trim is not None:
                trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
                opt.argtypes, opt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
                _libc = (trim, opt)
    return _libc


def limit_heap() -> bool:
    """Fix glibc's mmap threshold at :data:`MMAP_THRESHOLD` (once per process); returns
    whether it is set."""
    global _limited
    libc = _glibc()
    if libc is None:
        return False
    if not _limited:
        _limited = bool(libc[1](_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
    return _limited


def limit_heap_for(primitives: int) -> bool:
    """:func:`limit_heap` when a session of ``primitives`` is large enough to need it
    (:data:`LIMIT_FROM`); returns whether the threshold is fixed now."""
    if int(primitives) >= LIMIT_FROM:
        return limit_heap()
    return _limited


def release_freed() -> bool:
    """Give the allocator's free pages back to the system (module docstring); returns
    whether anything could be asked (glibc present)."""
    global last_seconds
    libc = _glibc()
    if libc is None:
        last_seconds = 0.0
        return False
    t = time.perf_counter()
    libc[0](0)
    last_seconds = time.perf_counter() - t
    return True
