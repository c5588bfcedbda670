"""Host memory reused by the transient arrays of repeated CPU renders.

Every CPU render allocates working arrays (splats, sort keys, tile pairs …) whose pages fault
in on first touch; in Blender's heap every allocation over a fixed threshold is mapped anew.
Inside ``with pool.active():`` :func:`scratch_empty` hands out the ``k``-th buffer of the
previous scopes (grown when too small), so a repeated render of similar size touches pages it
already owns; the values are the same (every wrapper writes before it reads). Only arrays that
do not outlive the scope are pooled (``everything=False`` leaves out those a kept binning holds,
marked ``kept``); a pool in use by another thread is not shared. :func:`recycling` lets a
render that keeps its binning take over the splat array of the binning it replaces, when
nothing else holds it. Details: docs/design-notes.md.
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections.abc import Iterator
from contextvars import ContextVar

import numpy as np
import warp as wp

__all__ = ["ScratchPool", "recycling", "scratch_active", "scratch_empty"]

_ACTIVE: ContextVar[ScratchPool | None] = ContextVar("divas_scratch_pool", default=None)
_DONORS: ContextVar[list | None] = ContextVar("divas_scratch_donors", default=None)
#: a donor serves a kept array only when it is at most this much larger (the new binning
#: holds the donor's whole capacity as long as it is kept)
RECYCLE_SLACK = 1.25
#: a grown buffer gets this much headroom (the next render's arrays are a little larger)
_GROWTH = 1.125
_ALIGN = 64


class ScratchPool:
    """Reusable host buffers for the transient Warp arrays of one renderer's repeated CPU
    renders (module docstring). Not shared between threads at once (a renderer is used
    under its session's render lock)."""

    def __init__(self) -> None:
        self._buffers: list[np.ndarray] = []
        self._next = 0
        self._depth = 0
        self._busy = threading.Lock()
        self.everything = True

    @property
    def nbytes(self) -> int:
        """Bytes the pool holds."""
        return sum(b.nbytes for b in self._buffers)

    def release(self) -> None:
        """Give the buffers back (the next scope allocates afresh)."""
        if self._depth:
            raise RuntimeError("ScratchPool.release inside an active scope")
        self._buffers = []

    @contextlib.contextmanager
    def active(self, everything: bool = True) -> Iterator[ScratchPool | None]:
        """Within this scope :func:`scratch_empty` takes this pool's buffers, in order
        (``everything`` False: only arrays not marked ``kept``). Yields None, pooling
        nothing, when the pool is in use by another scope (another thread)."""
        if not self._busy.acquire(blocking=False):
            if _ACTIVE.get() is self:
                raise RuntimeError("ScratchPool scopes do not nest")
            yield None
            return
        self._next, self._depth, self.everything = 0, 1, bool(everything)
        token = _ACTIVE.set(self)
        try:
            yield self
        finally:
            _ACTIVE.reset(token)
            self._depth = 0
            self._busy.release()

    def _take(self, nbytes: int) -> np.ndarray:
        k = self._next
        self._next += 1
        if k == len(self._buffers):
            self._buffers.append(np.empty(0, np.uint8))
        buf = self._buffers[k]
        if buf.nbytes < nbytes:
            size = -(-int(math.ceil(nbytes * _GROWTH)) // _ALIGN) * _ALIGN
            del buf
            self._buffers[k] = np.empty(0, np.uint8)  # the old one goes before the new one
            buf = self._buffers[k] = np.empty(size, np.uint8)
        return buf


@contextlib.contextmanager
def recycling(donors: list[wp.array]) -> Iterator[None]:
    """Within this scope the first :func:`scratch_empty` ``kept`` request of a donor's
    dtype takes that donor (a CPU array nothing else references, handed over by the
    caller): its memory when the request fits in it with at most ``RECYCLE_SLACK``
    to spare; otherwise the donor is freed right there, before the fresh allocation
    (the memory held never exceeds a render without donors by more than the donors
    themselves until that request). Donors left at the end are freed."""
    token = _DONORS.set(donors)
    try:
        yield
    finally:
        _DONORS.reset(token)
        donors.clear()


def _from_donor(donors: list, shape: tuple, dtype, nbytes: int, dev) -> wp.array | None:
    k = next((k for k, d in enumerate(donors) if d.dtype == dtype), None)
    if k is None:
        return None
    donor = donors.pop(k)
    if not (donor.device == dev and nbytes <= donor.capacity <= RECYCLE_SLACK * nbytes):
        return None  # (the last reference goes here: freed before the fresh array)
    arr = wp.array(ptr=donor.ptr, dtype=dtype, shape=shape, device=dev, capacity=donor.capacity)
    # the memory lives as long as the array (its owner: a donor recycled before is a view)
    arr._divas_scratch = getattr(donor, "_divas_scratch", donor)
    return arr


def scratch_active(everything: bool = True) -> bool:
    """Whether a :class:`ScratchPool` scope is active in this context (``everything``:
    one that pools the arrays marked ``kept`` too)."""
    pool = _ACTIVE.get()
    return pool is not None and (pool.everything or not everything)


def scratch_empty(shape, dtype, device=None, kept: bool = False) -> wp.array:
    """``wp.empty(shape, dtype, device)``, from the active :class:`ScratchPool` when there
    is one, the device is the CPU and the array is not ``kept`` beyond the render (or
    the scope keeps nothing)."""
    pool = _ACTIVE.get()
    dev = wp.get_device(device)
    donors = _DONORS.get() if kept and (pool is None or not pool.everything) else None
    if donors is None and (pool is None or not dev.is_cpu or (kept and not pool.everything)):
        return wp.empty(shape, dtype=dtype, device=dev)
    shape = (int(shape),) if np.isscalar(shape) else tuple(int(s) for s in shape)
    count = int(np.prod(shape)) if shape else 1
    nbytes = max(count * wp.types.type_size_in_bytes(dtype), 1)
    if donors is not None:
        arr = _from_donor(donors, shape, dtype, nbytes, dev) if donors else None
        return arr if arr is not None else wp.empty(shape, dtype=dtype, device=dev)
    buf = pool._take(nbytes)
    arr = wp.array(ptr=buf.ctypes.data, dtype=dtype, shape=shape, device=dev, capacity=nbytes)
    arr._divas_scratch = buf  # the buffer lives as long as the array
    return arr
