"""One BLAS thread while a session is open (issue 20).

The engine's NumPy products are tall and thin — ``[n,3] @ [3]`` heights, ``[n,3] @ [3,3]``
camera transforms of centres and blocks, at up to millions of rows. OpenBLAS runs each
of them on every core, and afterwards its worker threads spin-wait for the next call for
≈ 2^28 cycles before they sleep: measured here, one ``[1.27M,3] @ [3]`` product costs 4 ms
on one thread but 0.107 CPU s with two (the second core spinning for ≈ 0.1 s). On a
2-core laptop that spinning core is the one the renderer's threads and graph3d's cut need:
at 3M splats graph3d's cut took 0.65 CPU s with two BLAS threads and 0.38 with one, its
mask render 0.51 → 0.37 (BENCHMARKS.md, issue 20, click20g).

Those products split their *rows* across threads (each output is one row's dot product,
computed by the same kernel), so one thread gives the same bits; the reductions whose
result does depend on the thread count (``ddot``) the engine already avoids (graph3d's
solver sums with NumPy). Tested: ``tests/test_blas_threads.py`` and the session results
with one and two threads.

:class:`BlasThreads` sets the OpenBLAS libraries loaded in the process (NumPy's, SciPy's)
to :data:`SESSION_BLAS_THREADS` threads while at least one session is open and puts back
what they had when the last one closes (the host, e.g. Blender, keeps its own setting
otherwise). Linux only (the libraries are found in ``/proc/self/maps``); elsewhere a no-op.
"""

from __future__ import annotations

import ctypes
import threading
from pathlib import Path

__all__ = ["SESSION_BLAS_THREADS", "BlasThreads", "openblas_libraries"]

#: BLAS threads while a session is open (None: leave the libraries' own setting)
SESSION_BLAS_THREADS: int | None = 1

_SETTERS = ("openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = ("openblas_get_num_threads64_", "openblas_get_num_threads")


class _Lib:
    """One loaded OpenBLAS: its thread-count getter and setter."""

    def __init__(self, path: str, get, put) -> None:
        self.path, self._get, self._put = path, get, put

    def get(self) -> int:
        return int(self._get())

    def set(self, n: int) -> None:
        self._put(int(n))


def openblas_libraries() -> list[_Lib]:
    """The OpenBLAS libraries mapped into this process (NumPy's and SciPy's wheels each
    bundle one) that export a thread-count setter; empty when none is found."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    paths = []
    for line in maps.read_text().splitlines():
        parts = line.split(maxsplit=5)  # address, perms, offset, dev, inode, path
        path = parts[5].strip() if len(parts) == 6 else ""
        if "openblas" in Path(path).name.lower() and path not in paths:
            paths.append(path)
    out = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        put = next((getattr(lib, s) for s in _SETTERS if hasattr(lib, s)), None)
        get = next((getattr(lib, g) for g in _GETTERS if hasattr(lib, g)), None)
        if put is None or get is None:
            continue
        put.argtypes, put.restype, get.restype = [ctypes.c_int], None, ctypes.c_int
        out.append(_Lib(path, get, put))
    return out


class BlasThreads:
    """Process-wide, reference-counted: :meth:`acquire` when a session opens (the first
    one sets :data:`SESSION_BLAS_THREADS`), :meth:`release` when it closes (the last one
    restores each library's earlier count)."""

    _lock = threading.Lock()
    _users = 0
    _saved: list[tuple[_Lib, int]] = []

    @classmethod
    def acquire(cls) -> None:
        with cls._lock:
            cls._users += 1
            if cls._users > 1 or SESSION_BLAS_THREADS is None:
                return
            cls._saved = []
            for lib in openblas_libraries():
                cls._saved.append((lib, lib.get()))
                lib.set(SESSION_BLAS_THREADS)

    @classmethod
    def release(cls) -> None:
        with cls._lock:
            if cls._users == 0:
                return
            cls._users -= 1
            if cls._users == 0:
                for lib, n in cls._saved:
                    lib.set(n)
                cls._saved = []
