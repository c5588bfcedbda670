"""The one 2D segmenter interface every mask source implements (paper Sec. 3.4).

Used like SAM's predictor: :meth:`Segmenter.set_image` once per view (the expensive part is
cached per view, keyed by the explicit ``view_id`` or a BLAKE2 hash of image and depth), then
:meth:`Segmenter.predict` per prompt set. Conventions shared by all implementations:

* ``rgb``: ``[H,W,3]`` ``uint8`` or float in ``[0,1]`` (alpha dropped); ``depth``: ``[H,W]``
  planar camera depth or None, ``≤ 0`` / non-finite = no surface (NOTES "Depth tuple").
* ``points``: ``[P,2]`` continuous pixel coordinates, pixel ``(i, j)`` centred at
  ``(i + 0.5, j + 0.5)``; ``labels``: ``[P]`` int, ``1`` positive, ``0`` negative.
* ``predict`` returns ``masks [3,H,W] float32`` probabilities ordered small → large like
  SAM's multimask output, and ``scores [3] float32``; DivAS uses channel 1
  (:func:`select_mask`, Sec. 3.4 "Mask-channel selection and view acceptance").

A session calls :meth:`Segmenter.segment_view` with a :class:`~.context.ViewContext` and the
optional hooks the base class declares with no-op defaults (``bind_scene``, ``warm_up``, the
prefetch hooks, ``wants_ground_truth``); a segmenter overrides the ones it uses.
"""

from __future__ import annotations

import hashlib
import threading
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..kinds import RejectReason
from .context import ObjectClicks, SceneBinding, ViewContext

if TYPE_CHECKING:
    from ..camera import Camera

__all__ = [
    "Segmenter",
    "SegResult",
    "Rejection",
    "MaskSelection",
    "select_mask",
    "as_rgb_float",
    "as_depth",
    "as_prompts",
    "pixel_index",
]


@dataclass(frozen=True, eq=False)
class SegResult:
    """One ``predict`` result: ``masks [3,H,W]`` float32 probabilities, ``scores [3]``,
    and optionally a ``message`` for the user (what to do when the scores are low)."""

    masks: np.ndarray
    scores: np.ndarray
    message: str | None = None


@dataclass(frozen=True)
class Rejection:
    """Why a view was rejected, with its numbers.

    Attributes:
        reason: the :class:`~divas_engine.kinds.RejectReason`.
        score, threshold, channel: ``LOW_SCORE``: the channel's score, the least score
            accepted and the channel kept.
        cause: ``SEGMENTATION_FAILED``: the segmenter's error.
    """

    reason: RejectReason
    score: float | None = None
    threshold: float | None = None
    channel: int | None = None
    cause: str | None = None

    @property
    def message(self) -> str:
        """The engine's sentence (reports, the CLI)."""
        r = self.reason
        if r is RejectReason.LOW_SCORE:
            score = float("nan") if self.score is None else self.score
            return f"channel-{self.channel} score {score:.3f} < {self.threshold}"
        if r is RejectReason.SEGMENTATION_FAILED:
            return f"segmentation failed: {self.cause}"
        return _REJECTION_TEXT[r]

    def to_dict(self) -> dict[str, Any]:
        score = None if self.score is None or not np.isfinite(self.score) else self.score
        d = {"reason": str(self.reason), "score": score, "threshold": self.threshold}
        return {**d, "channel": self.channel, "cause": self.cause}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Rejection:
        return cls(
            RejectReason(d["reason"]), d.get("score"), d.get("threshold"), d.get("channel"),
            d.get("cause"),
        )  # fmt: skip


_REJECTION_TEXT = {
    RejectReason.NO_POSITIVE_PROMPT: "no positive prompt",
    RejectReason.EMPTY_MASK: "empty mask after depth weighting",
    RejectReason.SEGMENTATION_MISSING: "segmentation result missing",
}


@dataclass(frozen=True, eq=False)
class MaskSelection:
    """Outcome of :func:`select_mask`.

    Attributes:
        mask: ``[H,W]`` float32 probabilities of the chosen channel, None when rejected.
        score: the chosen channel's score (nan when there is none).
        rejection: None when accepted, else why the view is rejected.
    """

    mask: np.ndarray | None
    score: float
    rejection: Rejection | None

    @property
    def accepted(self) -> bool:
        return self.rejection is None

    @property
    def reason(self) -> str | None:
        """The rejection's sentence, None when accepted."""
        return None if self.rejection is None else self.rejection.message


def select_mask(
    masks: np.ndarray,
    scores: np.ndarray,
    labels: np.ndarray,
    min_score: float = 0.5,
    channel: int = 1,
) -> MaskSelection:
    """Keep SAM's mid-granularity channel or reject the view (Sec. 3.4).

    A view is rejected when its prompts carry no positive label, or when the
    score of ``channel`` (1, the mid granularity) is below ``min_score`` (0.5).
    """
    labels = np.asarray(labels).reshape(-1)
    scores = np.asarray(scores, dtype=np.float32).reshape(-1)
    masks = np.asarray(masks)
    if masks.ndim != 3 or masks.shape[0] <= channel or scores.shape[0] != masks.shape[0]:
        raise ValueError(
            f"select_mask: expected masks [C,H,W] and scores [C] with C > {channel}, "
            f"got {masks.shape} and {scores.shape}"
        )
    score = float(scores[channel])
    if not np.any(labels == 1):
        return MaskSelection(None, score, Rejection(RejectReason.NO_POSITIVE_PROMPT))
    if not score >= min_score:  # also rejects nan
        low = Rejection(RejectReason.LOW_SCORE, score, min_score, channel)
        return MaskSelection(None, score, low)
    return MaskSelection(np.asarray(masks[channel], dtype=np.float32), score, None)


def as_rgb_float(rgb: np.ndarray) -> np.ndarray:
    """``[H,W,3]`` float32 in ``[0,1]`` from uint8 or float input (alpha dropped)."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"rgb must be [H,W,3], got shape {a.shape}")
    a = a[..., :3]
    if a.dtype == np.uint8:
        return a.astype(np.float32) * np.float32(1.0 / 255.0)
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"rgb must be uint8 or float in [0,1], got dtype {a.dtype}")
    out = np.nan_to_num(a.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(out, 0.0, 1.0)


def as_depth(depth: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """``[H,W]`` float32 depth (non-finite → 0, i.e. invalid) or None."""
    if depth is None:
        return None
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim == 3 and d.shape[2] == 1:
        d = d[..., 0]
    if d.shape != tuple(shape):
        raise ValueError(f"depth must be [H,W]={tuple(shape)} like the image, got {d.shape}")
    return np.where(np.isfinite(d), d, np.float32(0.0)).astype(np.float32, copy=False)


def as_prompts(points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate prompts: ``points [P,2]`` float64, ``labels [P]`` int64 in {0, 1}."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2) if np.size(points) else np.zeros((0, 2))
    lab = np.asarray(labels, dtype=np.int64).reshape(-1)
    if p.shape[0] != lab.shape[0]:
        raise ValueError(f"{p.shape[0]} prompt points but {lab.shape[0]} labels")
    if not np.all(np.isfinite(p)):
        raise ValueError("prompt points contain NaN/Inf")
    if np.any((lab != 0) & (lab != 1)):
        raise ValueError(
            f"prompt labels must be 1 (positive) or 0 (negative), got {np.unique(lab)}"
        )
    return p, lab


def pixel_index(points: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Row/column index of the pixel containing each continuous point (clamped to the image)."""
    h, w = shape
    cols = np.clip(np.floor(points[:, 0]).astype(np.int64), 0, w - 1)
    rows = np.clip(np.floor(points[:, 1]).astype(np.int64), 0, h - 1)
    return rows, cols


def _fingerprint(rgb: np.ndarray, depth: np.ndarray | None) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in (rgb, depth):
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


class Segmenter(ABC):
    """Base class: per-view state cache plus input checking.

    Subclasses implement :meth:`_encode` (image → per-view state, the cached
    part) and :meth:`_predict` (state + prompts → masks, scores).

    ``cache_size`` views are kept (least recently used dropped). One instance
    is not meant to be used from two threads at once; :meth:`segment` holds an
    internal lock around ``set_image`` + ``predict`` for the background worker.
    """

    name: str = "segmenter"
    #: start a click's work before its view is rendered (:meth:`prefetch`,
    #: :meth:`prefetch_view`): a host that previews right after every click switches it
    #: on; a segmenter with nothing to start early ignores it
    prefetch_cuts: bool = False
    #: the session rejects a view whose mid channel scores below its ``min_score``
    #: (Sec. 3.4: a per-view mask that may be wrong in that view). False for a segmenter
    #: whose masks of an object are one 3D selection rendered into each view: its score
    #: is the same in every view, so a gate would only drop the clicks of an unsure
    #: object; its mask is fused and its message says what to click next
    score_gates_views: bool = True

    def __init__(self, cache_size: int = 8):
        self.cache_size = int(cache_size)
        self._cache: OrderedDict[Hashable, Any] = OrderedDict()
        self._state: Any = None
        self._shape: tuple[int, int] | None = None
        self._lock = threading.RLock()

    # -- public API ---------------------------------------------------------
    def set_image(
        self, rgb: np.ndarray, depth: np.ndarray | None = None, *, view_id: Hashable | None = None
    ) -> None:
        """Prepare a view; cached per ``view_id`` (or image hash when None)."""
        img = np.asarray(rgb)
        key: Hashable = (
            ("id", view_id) if view_id is not None else ("hash", _fingerprint(img, depth))
        )
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                self._state, self._shape = self._cache[key]
                return
            rgbf = as_rgb_float(img)
            d = as_depth(depth, rgbf.shape[:2])
            state = self._encode(rgbf, d, view_id)
            self._state, self._shape = state, rgbf.shape[:2]
            if self.cache_size > 0:
                self._cache[key] = (state, self._shape)
                while len(self._cache) > self.cache_size:
                    self._cache.popitem(last=False)

    def predict(self, points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Masks ``[3,H,W]`` float32 probabilities and scores ``[3]`` for the current view."""
        p, lab = as_prompts(points, labels)
        with self._lock:
            if self._state is None:
                raise RuntimeError(f"{self.name}: call set_image() before predict()")
            state, (h, w) = self._state, self._shape
            masks, scores = self._predict(state, p, lab)
        masks = np.asarray(masks, dtype=np.float32)
        scores = np.asarray(scores, dtype=np.float32).reshape(-1)
        if masks.shape != (3, h, w) or scores.shape != (3,):
            raise RuntimeError(
                f"{self.name}: produced masks {masks.shape} / scores {scores.shape}, "
                f"expected (3, {h}, {w}) / (3,)"
            )
        return masks, scores

    def segment(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None,
        points: np.ndarray,
        labels: np.ndarray,
        *,
        view_id: Hashable | None = None,
    ) -> SegResult:
        """``set_image`` + ``predict`` as one atomic call (thread-safe)."""
        with self._lock:
            self.set_image(rgb, depth, view_id=view_id)
            masks, scores = self.predict(points, labels)
        return SegResult(masks, scores)

    def segment_view(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> SegResult:
        """The session's call: masks and scores for a prompt set on one of its views.
        The default segments the view's image and depth (:meth:`segment`, cached by the
        view's id); a segmenter that reads more of the view overrides it."""
        return self.segment(view.rgb, view.depth, points, labels, view_id=view.id)

    def clear_cache(self) -> None:
        with self._lock:
            self._cache.clear()

    # -- optional hooks a session calls (no-op defaults) -------------------------------
    def bind_scene(self, binding: SceneBinding) -> None:  # noqa: B027 - optional hook
        """The session's scene, once when it opens; image-only segmenters ignore it."""

    def warm_up(self) -> None:  # noqa: B027 - optional hook
        """Build the per-scene state the first prompt would build (the session calls it
        in its background warm-up, after the fusion state); the default has none. A
        failure is left for the first prompt to raise."""

    def rendered_selection(
        self, view_id: Hashable, channel: int = 1
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """For a segmenter whose masks render a 3D selection: ``([n,3] centres, [n]
        opacities)`` of the primitives of the selection of ``channel`` behind its last
        masks of view ``view_id`` (the session widens a view that leaves much of it
        unseen, :mod:`~divas_engine.session.widening`); None when it has none (an image
        segmenter: only the mask's border tells)."""
        return None

    @property
    def wants_ground_truth(self) -> bool:
        """Whether the session should hand it each view's ground truth
        (:attr:`ViewContext.truth`, evaluation only); the default does not read it."""
        return False

    @property
    def prefetches(self) -> bool:
        """Whether :meth:`prefetch` would start anything: the session back-projects a
        click for it only then."""
        return False

    def prefetch(self, clicks: ObjectClicks) -> bool:
        """Start, in the background, the work the prompt of a view of the object with
        these 3D ``clicks`` will need (before the view is rendered); whether anything
        was started. The default starts nothing."""
        return False

    def prefetch_view(self, camera: Camera, clicks: ObjectClicks) -> bool:
        """Like :meth:`prefetch`, once the view's ``camera`` is known (while the view
        renders); whether anything was started. The default starts nothing."""
        return False

    def wait_prefetch(self, timeout: float | None = None) -> bool:
        """Wait for the work :meth:`prefetch` / :meth:`prefetch_view` started (a closing
        session: no thread may outlive it); whether all of it ended in ``timeout``."""
        return True

    @property
    def cached_views(self) -> int:
        return len(self._cache)

    # -- implementation hooks ------------------------------------------------
    @abstractmethod
    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        """Per-view state from ``rgb [H,W,3]`` float32 in [0,1] and checked depth."""

    @abstractmethod
    def _predict(
        self, state: Any, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``masks [3,H,W]`` probabilities and ``scores [3]`` from state and checked prompts."""
