"""Launch helpers shared by the kernel wrappers.

Warp runs a CPU launch on one thread. It does release the GIL while the kernel
runs, so the wrappers split a CPU launch into ``threads`` sub-launches issued
from a small thread pool. On CUDA a launch is one
grid, unchanged.

A *split* kernel takes ``base: int, stride: int`` as its **last two** inputs and
handles work item ``i = base + tid * stride``; :func:`launch_split` fills them.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Literal

import warp as wp

# Quiet Warp, set once before anything initialises it: no banner and no per-module
# "load" lines between the CLI's progress bars (errors and warnings still print).
# Warp ≥ 1.10 has a log level; older releases a quiet flag.
if hasattr(wp, "LOG_WARNING"):
    wp.config.log_level = wp.LOG_WARNING
else:  # pragma: no cover - older Warp
    wp.config.quiet = True

__all__ = [
    "resolve_device",
    "launch_split",
    "cpu_threads",
    "set_thread_source",
    "usable_cores",
    "ensure_loaded",
    "init_warp",
    "THREADS_ENV",
]

#: environment variable capping the CPU launch threads of a process (a batch job's CPU
#: share: ``divas batch`` sets it in each job's process).
THREADS_ENV = "DIVAS_CPU_THREADS"

_POOL: ThreadPoolExecutor | None = None
_LOADED: set[tuple[int, str]] = set()
_SOURCE: Callable[[], int] | None = None


def set_thread_source(source: Callable[[], int] | None) -> None:
    """Read the process's CPU share at every launch from ``source()`` (a positive
    integer; ``divas batch`` hands a job the cores that are free as other jobs end);
    None: back to ``$DIVAS_CPU_THREADS`` and the core count."""
    global _SOURCE
    _SOURCE = source


def cpu_threads(requested: int | None = None) -> int:
    """Number of CPU launch threads: ``requested``, else the thread source
    (:func:`set_thread_source`), else ``$DIVAS_CPU_THREADS`` (a positive integer), else
    the usable core count."""
    if requested is not None and requested > 0:
        return int(requested)
    if _SOURCE is not None:
        n = int(_SOURCE())
        if n > 0:
            return n
    env = os.environ.get(THREADS_ENV, "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    return usable_cores()


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity; the core count elsewhere)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


def _cuda_driver_loadable() -> bool:
    """Whether the NVIDIA driver library loads (what Warp's init tries)."""
    if sys.platform == "darwin":
        return True  # no CUDA on macOS: Warp does not look for a driver there
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so", "libcuda.so.1")
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def init_warp() -> None:
    """``wp.init()`` once. A machine without an NVIDIA driver is a supported CPU setup, so
    Warp's C-level "Could not find or load the NVIDIA CUDA driver" line (written straight
    to file descriptor 2, past the log level) is kept off the user's terminal: stderr is
    muted for the init only, and only when the driver cannot be loaded."""
    from warp._src import context as _ctx  # the runtime is None until the first init

    if getattr(_ctx, "runtime", None) is not None or _cuda_driver_loadable():
        wp.init()
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def resolve_device(device: Any = None) -> wp.context.Device:
    """A Warp device from ``None``/``"auto"`` (CUDA when present, else CPU), a name or a device."""
    init_warp()
    if device is None or device == "auto":
        return wp.get_device("cuda:0" if wp.get_cuda_device_count() > 0 else "cpu")
    if isinstance(device, str) and device == "cuda" and wp.get_cuda_device_count() == 0:
        raise RuntimeError("device 'cuda' requested but no CUDA device is available")
    return wp.get_device(device)


def ensure_loaded(kernel: wp.Kernel, device: wp.context.Device) -> None:
    """Compile/load ``kernel``'s module once per device before threads launch it concurrently."""
    key = (id(kernel.module), str(device))
    if key not in _LOADED:
        wp.load_module(kernel.module, device=device)
        _LOADED.add(key)


def _forget_pool_in_child() -> None:
    """A forked child (a test harness, a user's multiprocessing) inherits the pool object
    but none of its worker threads: work submitted to it would wait forever. The child
    starts its own pool on first use."""
    global _POOL
    _POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_in_child)


def _pool(n: int) -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None or _POOL._max_workers < n:  # noqa: SLF001 - size check only
        _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="divas-warp")
    return _POOL


def launch_split(
    kernel: wp.Kernel,
    n: int,
    inputs: Sequence[Any],
    device: wp.context.Device,
    threads: int = 1,
    mode: Literal["chunk", "interleave"] = "chunk",
    items: tuple[int, int] | None = None,
) -> None:
    """Launch a split kernel over work items ``[0, n)``.

    Args:
        kernel: a kernel whose last two inputs are ``base, stride``.
        n: number of work items.
        inputs: the kernel inputs *without* ``base, stride``.
        device: launch device.
        threads: CPU sub-launches (ignored on CUDA).
        mode: ``"chunk"`` gives each thread a contiguous range (cache friendly for
            per-element work); ``"interleave"`` gives thread ``j`` items ``j, j+t, …``
            (load balance for uneven per-tile work).
        items: ``(first, end)``: run only the items ``[first, end)`` of ``[0, n)``, each
            in the sub-launch (``base``) it has in the whole launch (``"interleave"``
            only): a kernel that picks a per-thread row by ``base`` sees each of them in
            the same row and order as in the whole launch (the contribution walk over
            the tiles that hold its targets, ``divas_kernels.contrib``).
    """
    if n <= 0:
        return
    inputs = list(inputs)
    t = 1 if device.is_cuda else max(1, min(int(threads), n))
    first, end = (0, n) if items is None else (max(0, items[0]), min(n, items[1]))
    if items is not None and mode != "interleave":
        raise ValueError("launch_split: an item range needs the interleaved split")
    if end <= first:
        return
    if t == 1:
        wp.launch(kernel, dim=end - first, inputs=inputs + [first, 1], device=device)
        return
    ensure_loaded(kernel, device)
    jobs = []
    if mode == "chunk":
        step = (n + t - 1) // t
        for j in range(t):
            lo, hi = j * step, min(n, (j + 1) * step)
            if hi > lo:
                jobs.append((hi - lo, lo, 1))
    else:
        for j in range(t):
            b = first + (j - first) % t  # its first item in the range (≡ j mod t)
            jobs.append(((end - b + t - 1) // t, b, t))
    pool = _pool(t)
    futures = [
        pool.submit(wp.launch, kernel, dim=d, inputs=inputs + [b, s], device=device)
        for d, b, s in jobs
        if d > 0
    ]
    for f in futures:
        f.result()
