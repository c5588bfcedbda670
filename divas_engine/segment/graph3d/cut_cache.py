"""The graph3d segmenter's cuts by seed set: kept (least recently used dropped) and, for a
cut started ahead of its prompt (:meth:`CutCache.start`), in flight.

A click's 3D point is known before its centroid view is rendered, and the cut of the
object's clicks depends on nothing else (the view's default prompt is that point
projected, which :meth:`~.segmenter.Graph3DSegmenter.seeds` maps back to it): the session
starts the cut in a background thread while the view renders (Warp CPU launches and
large NumPy operations release the GIL), and the prompt takes it — the same
:class:`~.segmenter.RegionCut` object the prompt would have computed, since a cut is a
function of its seed set and the bound scene alone.

Rules: a key is computed at most once at a time (a prompt whose key is in flight waits
for it); a cut that raised in the background is not kept — the prompt computes it
again and the error surfaces there, in the caller's thread; :meth:`CutCache.clear` (a
new scene bound) makes every cut still in flight land nowhere.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from typing import Generic, TypeVar

__all__ = ["CutCache"]

T = TypeVar("T")


class CutCache(Generic[T]):
    """Cuts by key (``size`` kept), with the ones computing in the background.

    Args:
        size: how many finished cuts are kept.
    """

    def __init__(self, size: int):
        self.size = int(size)
        self._done: OrderedDict[bytes, T] = OrderedDict()
        self._running: dict[bytes, Future] = {}
        self._lock = threading.Lock()
        self._generation = 0
        self._background: set[bytes] = set()  # kept cuts a background thread made
        #: how many background cuts a :meth:`get` took (finished or waited for), each once
        self.prefetch_hits = 0

    def __len__(self) -> int:
        return len(self._done)

    def clear(self) -> None:
        """Forget every cut; the ones still in flight are not kept when they end."""
        with self._lock:
            self._done.clear()
            self._running.clear()
            self._background.clear()
            self._generation += 1

    def peek(self, key: bytes) -> T | None:
        """The finished cut of ``key`` or None (no LRU update, no wait)."""
        with self._lock:
            return self._done.get(key)

    def in_flight(self, key: bytes) -> Future | None:
        """The future of ``key``'s background cut, or None."""
        with self._lock:
            return self._running.get(key)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for every background cut (tests, closing); whether all ended."""
        with self._lock:
            futures = list(self._running.values())
        for f in futures:
            try:
                f.exception(timeout)
            except TimeoutError:
                return False
        return True

    def _put(self, key: bytes, value: T, generation: int) -> None:
        if generation != self._generation:
            return  # a new scene was bound meanwhile
        self._done[key] = value
        self._done.move_to_end(key)
        while len(self._done) > self.size:
            self._background.discard(self._done.popitem(last=False)[0])

    def get(self, key: bytes, compute: Callable[[], T]) -> T:
        """The cut of ``key``: kept, or the background one (waited for), or ``compute()``
        now (kept)."""
        with self._lock:
            hit = self._done.get(key)
            if hit is not None:
                self._done.move_to_end(key)
                if key in self._background:
                    self._background.discard(key)
                    self.prefetch_hits += 1
                return hit
            fut = self._running.get(key)
            generation = self._generation
        if fut is not None:
            ok = fut.exception() is None  # waits; a failed one is computed again below
            if ok:
                with self._lock:
                    # counted once per background cut: another waiter (the masks
                    # rendered ahead) may have taken it first
                    if key in self._background:
                        self._background.discard(key)
                        self.prefetch_hits += 1
                return fut.result()
        value = compute()
        with self._lock:
            self._put(key, value, generation)
        return value

    def start(self, key: bytes, compute: Callable[[], T]) -> bool:
        """Compute ``key``'s cut in a background thread unless it is kept or in flight;
        whether a thread was started."""
        with self._lock:
            if key in self._done or key in self._running:
                return False
            fut: Future = Future()
            fut.set_running_or_notify_cancel()
            self._running[key] = fut
            generation = self._generation

        def run() -> None:
            try:
                value = compute()
            except BaseException as e:  # noqa: BLE001 - handed to the waiting prompt
                with self._lock:
                    if self._running.get(key) is fut:
                        del self._running[key]
                fut.set_exception(e)
                return
            with self._lock:
                self._put(key, value, generation)
                if generation == self._generation:
                    self._background.add(key)
                if self._running.get(key) is fut:
                    del self._running[key]
            fut.set_result(value)

        threading.Thread(target=run, name="divas-graph3d-prefetch", daemon=True).start()
        return True
