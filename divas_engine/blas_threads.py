"""One BLAS thread while a session is open.

The engine's NumPy products are tall and thin (``[n,3] @ [3]`` heights, ``[n,3] @ [3,3]``
camera transforms, up to millions of rows). OpenBLAS runs each on every core and its workers
then spin-wait before they sleep, so on a 2-core machine a spinning core is taken from the
renderer's threads and graph3d's cut. Those products split their *rows* across threads, so one
thread gives the same bits (the thread-dependent ``ddot`` reductions the engine avoids; tested
in ``tests/test_blas_threads.py``).

:class:`BlasThreads` limits the BLAS libraries loaded in the process (NumPy's, SciPy's) to
:data:`SESSION_BLAS_THREADS` threads while at least one session is open and puts back what they
had when the last one closes (the host, e.g. Blender, keeps its own setting otherwise). The
libraries are set by ``threadpoolctl`` (OpenBLAS, MKL, BLIS; one it cannot set is left as is).
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
