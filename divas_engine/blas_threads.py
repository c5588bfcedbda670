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

:class:`BlasThreads` limits the BLAS libraries loaded in the process (NumPy's, SciPy's) to
:data:`SESSION_BLAS_THREADS` threads while at least one session is open and puts back what
they had when the last one closes (the host, e.g. Blender, keeps its own setting
otherwise). The libraries are found and set by ``threadpoolctl`` (OpenBLAS, MKL, BLIS on
Linux, Windows and macOS; a BLAS it cannot set, e.g. Accelerate, is left as it is).
"""

from __future__ import annotations

import threading

from threadpoolctl import ThreadpoolController

__all__ = ["SESSION_BLAS_THREADS", "BlasThreads", "limit_blas"]

#: BLAS threads while a session is open (None: leave the libraries' own setting)
SESSION_BLAS_THREADS: int | None = 1


def limit_blas(threads: int):
    """Limit every BLAS loaded now to ``threads``; returns the limiter whose
    ``restore_original_limits()`` puts the previous counts back."""
    return ThreadpoolController().limit(limits=int(threads), user_api="blas")


class BlasThreads:
    """Process-wide, reference-counted: :meth:`acquire` when a session opens (the first
    one sets :data:`SESSION_BLAS_THREADS`), :meth:`release` when it closes (the last one
    restores each library's earlier count)."""

    _lock = threading.Lock()
    _users = 0
    _limiter = None

    @classmethod
    def acquire(cls) -> None:
        with cls._lock:
            cls._users += 1
            if cls._users > 1 or SESSION_BLAS_THREADS is None:
                return
            cls._limiter = limit_blas(SESSION_BLAS_THREADS)

    @classmethod
    def release(cls) -> None:
        with cls._lock:
            if cls._users == 0:
                return
            cls._users -= 1
            if cls._users == 0 and cls._limiter is not None:
                cls._limiter.restore_original_limits()
                cls._limiter = None
