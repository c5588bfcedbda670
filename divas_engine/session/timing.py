"""Per-update timings of a session (paper Sec. 3.7: the per-update cost) and memory."""

from __future__ import annotations

import resource
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["Timings", "memory_report"]


class Timings:
    """Seconds per call, by stage.

    Stages used by :class:`~divas_engine.session.Session`: ``render`` (anchor and
    centroid-view renders), ``centroid`` (the centroid-view planner, probes included),
    ``segmenter`` (one SAM call), ``segmenter_wait`` (NeRF: blocking at a group sync),
    ``kernel`` (one fusion kernel call = one ``add_view``), ``undo``, ``mapping``
    (voxel-to-surfel), ``overlay`` (selection render on a view).
    """

    def __init__(self) -> None:
        self._calls: dict[str, list[float]] = defaultdict(list)
        self._lock = threading.Lock()
        self.t0 = time.perf_counter()

    def add(self, stage: str, seconds: float) -> None:
        with self._lock:
            self._calls[stage].append(float(seconds))

    @contextmanager
    def measure(self, stage: str) -> Iterator[None]:
        t = time.perf_counter()
        try:
            yield
        finally:
            self.add(stage, time.perf_counter() - t)

    def calls(self, stage: str) -> list[float]:
        with self._lock:
            return list(self._calls.get(stage, ()))

    def total(self, stage: str) -> float:
        return float(sum(self.calls(stage)))

    def summary(self) -> dict[str, Any]:
        """``{stage: {calls, total_s, mean_s, max_s, per_call_s}}``."""
        with self._lock:
            items = {k: list(v) for k, v in self._calls.items()}
        out = {}
        for k, v in sorted(items.items()):
            out[k] = {
                "calls": len(v),
                "total_s": float(sum(v)),
                "mean_s": float(sum(v) / len(v)) if v else 0.0,
                "max_s": float(max(v)) if v else 0.0,
                "per_call_s": v,
            }
        return out


def memory_report() -> dict[str, Any]:
    """Peak and current resident memory of this process (bytes)."""
    ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak = int(ru if sys.platform == "darwin" else ru * 1024)
    out: dict[str, Any] = {"peak_rss_bytes": peak}
    try:
        import psutil

        out["rss_bytes"] = int(psutil.Process().memory_info().rss)
    except Exception:  # psutil is optional here
        pass
    return out
