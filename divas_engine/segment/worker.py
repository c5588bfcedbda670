"""SAM scheduling: asynchronous for NeRF, synchronous for 2DGS (Sec. 3.4, "Execution scheduling").

DivAS-NeRF runs SAM in a background worker on the preceding centroid views while the user
annotates the current one, and synchronises when the current view ends its anchor group or at
least three masks are pending; DivAS-GS calls SAM synchronously. :class:`SamWorker` offers
both behind one API (``submit``, ``should_sync``, ``sync``). Async jobs run one at a time on a
single thread (the segmenter is never used concurrently). Results are cached by view id with
the prompts they answered, so re-submitting the same prompts reuses them; re-submitting a
pending view replaces its job. A job's exception is re-raised at :meth:`SamWorker.sync` as
:class:`SegmentationJobError` naming the view, never lost in the thread.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Hashable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from .base import Segmenter, SegResult, as_prompts
from .context import ViewContext

__all__ = ["SamWorker", "SegmentationJobError", "SYNC_PENDING"]

#: Pending masks that force a synchronisation (Sec. 3.4, condition (ii)).
SYNC_PENDING = 3


class SegmentationJobError(RuntimeError):
    """A segmentation job failed; ``view_id``, the ``cause`` and the other views' ``results``."""

    def __init__(
        self,
        view_id: Hashable,
        cause: BaseException,
        results: dict[Hashable, SegResult],
        failures: dict[Hashable, BaseException],
    ):
        self.view_id, self.cause = view_id, cause
        self.results, self.failures = results, failures
        more = f" (and {len(failures) - 1} more failed view(s))" if len(failures) > 1 else ""
        super().__init__(
            f"segmentation of view {view_id!r} failed: {type(cause).__name__}: {cause}{more}"
        )


def _prompt_key(points: np.ndarray, labels: np.ndarray) -> str:
    p, lab = as_prompts(points, labels)
    return hashlib.blake2b(p.tobytes() + b"|" + lab.tobytes(), digest_size=16).hexdigest()


class SamWorker:
    """Runs ``segmenter.segment_view`` jobs asynchronously (NeRF) or synchronously (2DGS).

    Args:
        segmenter: any :class:`.base.Segmenter`.
        asynchronous: background thread (True) or run inside ``submit`` (False).
        sync_pending: pending count that makes :meth:`should_sync` true (3).
    """

    def __init__(
        self, segmenter: Segmenter, *, asynchronous: bool = True, sync_pending: int = SYNC_PENDING
    ):
        self.segmenter = segmenter
        self.asynchronous = bool(asynchronous)
        self.sync_pending = int(sync_pending)
        self._pool = (
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="divas-sam")
            if self.asynchronous
            else None
        )
        self._pending: dict[Hashable, tuple[str, Future]] = {}
        self._cache: dict[Hashable, tuple[str, SegResult]] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.runs = 0  # segmenter calls actually made (cache hits excluded)

    # -- API -----------------------------------------------------------------------
    def submit(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> None:
        """Queue (or, synchronous, run) SAM on one view (keyed by ``view.id``) with its
        prompts."""
        view_id = view.id
        if self._closed:
            raise RuntimeError("SamWorker is closed")
        key = _prompt_key(points, labels)
        fut: Future = Future()
        with self._lock:
            old = self._pending.pop(view_id, None)
            if old is not None and old[0] == key:  # same prompts still pending: keep that job
                self._pending[view_id] = old
                return
            if old is not None:
                old[1].cancel()
            cached = self._cache.get(view_id)
            if cached is not None and cached[0] == key:
                fut.set_result(cached[1])
                self._pending[view_id] = (key, fut)
                return
        if self._pool is not None:
            own = replace(
                view,
                rgb=np.array(view.rgb, copy=True),
                depth=None if view.depth is None else np.array(view.depth, copy=True),
            )
            args = (np.array(points, copy=True), np.array(labels, copy=True))
            fut = self._pool.submit(self._run, own, *args)
        else:
            try:
                fut.set_result(self._run(view, points, labels))
            except Exception as exc:  # re-raised at sync(), like the async path
                fut.set_exception(exc)
        with self._lock:
            self._pending[view_id] = (key, fut)

    def pending(self) -> int:
        """Masks submitted and not yet collected by :meth:`sync` (finished or not)."""
        with self._lock:
            return len(self._pending)

    def should_sync(self, end_of_group: bool = False) -> bool:
        """Synchronise now? Async: end of the anchor group or ≥ ``sync_pending`` pending.

        Synchronous mode: whenever something is pending (2DGS fuses every view at once).
        """
        n = self.pending()
        if not self.asynchronous:
            return n > 0
        return n > 0 and (bool(end_of_group) or n >= self.sync_pending)

    def sync(self) -> dict[Hashable, SegResult]:
        """Wait for every pending job; results in submission order.

        Raises:
            SegmentationJobError: for the first failed view (others' results attached).
        """
        with self._lock:
            jobs = list(self._pending.items())
            self._pending.clear()
        results: dict[Hashable, SegResult] = {}
        failures: dict[Hashable, BaseException] = {}
        for view_id, (key, fut) in jobs:
            try:
                res = fut.result()
            except BaseException as exc:  # noqa: BLE001 - handed back to the caller below
                failures[view_id] = exc
                continue
            results[view_id] = res
            with self._lock:
                self._cache[view_id] = (key, res)
        if failures:
            first = next(iter(failures))
            raise SegmentationJobError(first, failures[first], results, failures) from failures[
                first
            ]
        return results

    def result(self, view_id: Hashable) -> SegResult | None:
        """The cached result of a synchronised view, or None."""
        with self._lock:
            hit = self._cache.get(view_id)
        return None if hit is None else hit[1]

    def forget(self, view_id: Hashable) -> None:
        """Drop a view's cached result."""
        with self._lock:
            self._cache.pop(view_id, None)

    def close(self, cancel_pending: bool = True) -> None:
        """Stop the worker: queued jobs are cancelled (or awaited); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=cancel_pending)
        with self._lock:
            self._pending.clear()

    def __enter__(self) -> SamWorker:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------
    def _run(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> SegResult:
        self.runs += 1
        return self.segmenter.segment_view(view, points, labels)
