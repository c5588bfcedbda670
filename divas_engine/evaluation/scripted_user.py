"""A simulated user that follows the paper's interactive protocol (evaluation only).

Paper Sec. 3.3 and 3.7: after each fused view the running 3D selection is overlaid on
the next view, and the user prompts only the regions it does not cover yet, until
coverage is complete. The anchors are the session's own anchor plan (Sec. 3.2) — never
the test cameras. The user sees only what a user sees (anchor renders with the overlay,
the centroid view and its mask preview) plus its intent, the ground-truth target
rendered at that view. Per anchor it clicks the deepest uncovered target region until
none is left or it stalls, optionally adds a negative point on a preview's spill, and
declines a preview that has leaked; then manual anchors from the training cameras, up
to the paper's view budget (tab:view-budget). Each step in full: docs/design-notes.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy import ndimage

from ..errors import DivasInputError

#: Default view budget per capture type (tab:view-budget's upper ends): forward-facing
#: (LLFF-like) 10 centroid views, 360° (Mip-NeRF 360) 20.
VIEW_BUDGET: dict[bool, int] = {True: 10, False: 20}

__all__ = [
    "VIEW_BUDGET",
    "UserBudget",
    "UserClick",
    "UserLog",
    "ScriptedUser",
    "uncovered_regions",
    "region_centre",
    "leak_free_fraction",
]


@dataclass(frozen=True)
class UserBudget:
    """Budgets and thresholds of the simulated user.

    Attributes:
        clicks_per_anchor: optional hard cap on positive clicks (centroid views) per
            anchor; None (default): none — the user works an anchor until it is complete
            or stalled.
        max_failed_clicks: the user gives up on an anchor after this many clicks in a row
            that did not shrink its uncovered target pixels by at least one minimum
            region (a view that failed, was rejected or declined, or covered too little),
            2.
        max_views: centroid views per session in total; None (default): the upper end of
            the paper's bounded view processing (tab:view-budget) for the capture type,
            :data:`VIEW_BUDGET` (10 forward-facing, 20 for 360°).
        min_region_frac: smallest uncovered (or false-positive) region worth a click, as
            a fraction of the view's pixels, 0.002 (0.2 %: 614 px at 640×480).
        target_threshold: the user's target at a view = GT render ``≥`` this, 0.5 (the
            evaluation's ground-truth threshold).
        negative_clicks: add one negative point on a centroid view whose mask preview
            has a false-positive region (kept only when it improves the mask), True.
        more_anchors: after the plan's offered anchors, go on with its other supported
            Fibonacci candidates in ranking order (Sec. 3.2's "all Fibonacci views"),
            while the view budget lasts, True.
        manual_anchors: training cameras the user may add as manual anchors afterwards
            (docs/design-notes.md), 4. The paper's remedy for targets its Fibonacci anchors
            do not expose (on the synthetic plant, c_scene — the median of all centres —
            lies on the floor below the plant and most anchors do not show it); a
            user only adds one when a training camera shows uncovered target, so scenes
            whose anchors suffice (ribs, occluded) are unaffected. 0 = automatic anchors
            only.
        browse_scale: the training cameras are browsed at this fraction of their size,
            0.25.
        min_accept_precision: the user declines a view whose mask preview (``≥ 0.5``)
            has a precision below this against the boundary-tolerant target at that
            view (docs/design-notes.md), 0.5: more leaked than target pixels. 0 accepts
            every view.
    """

    clicks_per_anchor: int | None = None
    max_failed_clicks: int = 2
    max_views: int | None = None
    min_region_frac: float = 0.002
    target_threshold: float = 0.5
    negative_clicks: bool = True
    more_anchors: bool = True
    manual_anchors: int = 4
    browse_scale: float = 0.25
    min_accept_precision: float = 0.5

    def __post_init__(self) -> None:
        for k in ("clicks_per_anchor", "max_views"):
            v = getattr(self, k)
            if v is not None and v < 1:
                raise ValueError(f"UserBudget.{k} must be ≥ 1 (or None), got {v}")
        if self.max_failed_clicks < 1:
            raise ValueError(
                f"UserBudget.max_failed_clicks must be ≥ 1, got {self.max_failed_clicks}"
            )
        if self.manual_anchors < 0:
            raise ValueError(f"UserBudget.manual_anchors must be ≥ 0, got {self.manual_anchors}")
        if not 0.0 <= self.min_accept_precision <= 1.0:
            raise ValueError(
                f"UserBudget.min_accept_precision must be in [0, 1], "
                f"got {self.min_accept_precision}"
            )
        if not 0.0 < self.browse_scale <= 1.0:
            raise ValueError(f"UserBudget.browse_scale must be in (0, 1], got {self.browse_scale}")
        if not 0.0 <= self.min_region_frac < 1.0:
            raise ValueError(
                f"UserBudget.min_region_frac must be in [0, 1), got {self.min_region_frac}"
            )


@dataclass
class UserClick:
    """One positive click of the simulated user.

    Attributes:
        anchor: anchor index; xy: the click (pixels of the anchor render).
        region_px: area of the uncovered region clicked; uncovered_px: all uncovered
            target pixels at the anchor then; target_px: visible target pixels.
        view_id: the centroid view spawned (None when the click hit no surface).
        status: the view's status after accepting it (``fused`` / ``rejected``),
            ``declined`` (the user did not accept its preview) or ``no surface``.
        negatives: negative points added on the centroid view (its pixels).
        negative_kept: whether the re-prompted mask was kept.
    """

    anchor: int
    xy: tuple[float, float]
    region_px: int
    uncovered_px: int
    target_px: int
    view_id: str | None = None
    status: str = ""
    negatives: list[tuple[float, float]] = field(default_factory=list)
    negative_kept: bool = False


@dataclass
class UserLog:
    """What the simulated user did in one session.

    Attributes:
        clicks: the positive clicks in order.
        anchor_status: per anchor, ``"complete"`` (no uncovered region of the minimum
            area left), ``"stalled"`` (given up after ``max_failed_clicks`` clicks without
            progress), ``"clicks"`` (the optional per-anchor cap reached), ``"budget"``
            (the session's view budget ran out there) or ``"not visited"`` (after that).
        uncovered_after: per anchor, uncovered target pixels at the last look (−1: not
            visited).
        looked_at: names of every camera the user looked at (anchors, centroid views).
        manual: training-camera indices added as manual anchors, in order.
        stop: ``"complete"`` (every anchor complete), ``"budget"`` (view budget spent)
            or ``"incomplete"`` (some anchor stalled or capped, the rest complete).
        max_views: the view budget the session ran under.
    """

    clicks: list[UserClick] = field(default_factory=list)
    anchor_status: list[str] = field(default_factory=list)
    uncovered_after: list[int] = field(default_factory=list)
    looked_at: list[str] = field(default_factory=list)
    manual: list[int] = field(default_factory=list)
    stop: str = ""
    max_views: int = 0

    @property
    def declined(self) -> int:
        """Centroid views the user did not accept (leaked previews)."""
        return sum(c.status == "declined" for c in self.clicks)

    @property
    def complete(self) -> list[bool]:
        """Per anchor: no uncovered region of the minimum area was left there."""
        return [s == "complete" for s in self.anchor_status]

    def as_dict(self) -> dict[str, Any]:
        return {
            "clicks": [asdict(c) for c in self.clicks],
            "anchor_status": self.anchor_status,
            "complete": self.complete,
            "uncovered_after": self.uncovered_after,
            "stop": self.stop,
            "manual_anchors": list(self.manual),
            "max_views": self.max_views,
            "views": len(self.clicks),
            "negatives": sum(len(c.negatives) for c in self.clicks),
            "negatives_kept": sum(c.negative_kept for c in self.clicks),
            "declined": self.declined,
        }


def uncovered_regions(target: np.ndarray, covered: np.ndarray, min_area: int) -> list[np.ndarray]:
    """Connected regions (8-connectivity) of ``target ∧ ¬covered`` with at least
    ``min_area`` pixels, as bool masks, largest first (ties: lower label first)."""
    miss = np.asarray(target, bool) & ~np.asarray(covered, bool)
    if not miss.any():
        return []
    n, lab, stats, _ = cv2.connectedComponentsWithStats(miss.astype(np.uint8), connectivity=8)
    keep = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= max(1, int(min_area))]
    keep.sort(key=lambda i: (-int(stats[i, cv2.CC_STAT_AREA]), i))
    return [lab == i for i in keep]


def region_centre(region: np.ndarray, avoid=()) -> tuple[float, float]:
    """The pixel of ``region`` farthest from its border (Euclidean distance transform;
    ties: first in row-major order), as the pixel-centre ``(x + 0.5, y + 0.5)``.

    ``avoid``: integer pixels ``(x, y)`` (earlier clicks) treated as border too, so the
    pixel is also far from them (ignored when they would leave nothing)."""
    r = np.asarray(region, bool)
    if not r.any():
        raise ValueError("region_centre: empty region")
    if len(avoid):
        r2 = r.copy()
        for x, y in avoid:
            if 0 <= y < r.shape[0] and 0 <= x < r.shape[1]:
                r2[y, x] = False
        if r2.any():
            r = r2
    d = ndimage.distance_transform_edt(np.pad(r, 1))[1:-1, 1:-1]
    y, x = divmod(int(np.argmax(d)), r.shape[1])
    return float(x) + 0.5, float(y) + 0.5


def leak_free_fraction(selected: np.ndarray, target: np.ndarray) -> float:
    """Precision of ``selected`` against ``target`` dilated by ``2⌈max(H, W)/256⌉`` px
    (two cells of SAM's 256 low-res logit grid: boundary imprecision, not a leak); 1 for
    an empty selection."""
    sel = np.asarray(selected, bool)
    n = int(np.count_nonzero(sel))
    if not n:
        return 1.0
    k = 2 * int(math.ceil(max(sel.shape) / 256))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
    tol = cv2.dilate(np.asarray(target, np.uint8), disc).astype(bool)
    return int(np.count_nonzero(sel & tol)) / n


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    u = int(np.count_nonzero(a | b))
    return int(np.count_nonzero(a & b)) / u if u else 1.0


class ScriptedUser:
    """The simulated user (module docstring; docs/design-notes.md).

    Args:
        gt_values: the user's intent — ground truth per surfel ``[N]`` or per voxel
            ``[D,H,W]``; only ever rendered at the views the user looks at.
        budget: :class:`UserBudget`.
    """

    def __init__(self, gt_values: np.ndarray, budget: UserBudget | None = None) -> None:
        self.gt_values = np.asarray(gt_values, np.float32)
        self.budget = budget or UserBudget()
        self._thumbs: dict[tuple, np.ndarray] = {}  # training-camera thumbnail targets

    # -------------------------------------------------------------- what the user sees
    def target(self, session, camera, log: UserLog | None = None) -> np.ndarray:
        """The user's target at ``camera`` (a working-resolution camera)."""
        if log is not None:
            log.looked_at.append(camera.name)
        vals = session.renderer.render_values(camera, self.gt_values)
        return vals >= np.float32(self.budget.target_threshold)

    @staticmethod
    def overlay_mask(session, camera) -> np.ndarray:
        """The binary overlay of the current selection at ``camera`` (working resolution)."""
        if not session.selection.any():
            return np.zeros((camera.height, camera.width), bool)
        return session.overlay(camera, full_camera=False).mask

    # -------------------------------------------------------------- the protocol
    def anchors(self, plan) -> list:
        """The anchors the user visits, in order: the plan's offered anchors, then (with
        ``more_anchors``) the plan's other *supported* Fibonacci candidates in ranking
        order — the "show all Fibonacci views" list of Sec. 3.2, unsupported directions
        left out. Never a test camera: only the plan's own anchors and candidates."""
        out = list(plan.anchors)
        if self.budget.more_anchors:
            seen = {(a.source, int(a.index)) for a in out}
            for i in plan.ranking.order:
                c = plan.candidates[int(i)]
                if not c.unsupported and (c.source, int(c.index)) not in seen:
                    out.append(c)
                    seen.add((c.source, int(c.index)))
        return out

    def max_views(self, session) -> int:
        """The session's view budget: ``max_views``, else :data:`VIEW_BUDGET` of its
        capture type."""
        b = self.budget
        return (
            int(b.max_views)
            if b.max_views is not None
            else VIEW_BUDGET[bool(session.forward_facing)]
        )

    def run(self, session) -> UserLog:
        """Drive ``session`` (freshly opened, current object empty) over its anchors, then
        (``manual_anchors``) over training cameras it adds as manual anchors."""
        b = self.budget
        log = UserLog(max_views=self.max_views(session))
        n_views = 0
        for ai in range(len(session.anchors)):
            n_views = self._visit(session, ai, log, n_views)
        seen: set[int] = set()
        while len(log.manual) < b.manual_anchors and n_views < log.max_views:
            pick = self._browse(session, seen, log)
            if pick is None:
                break
            a = session.add_anchor(session.cameras[pick], "training", pick)
            log.manual.append(pick)
            n_views = self._visit(session, a.index, log, n_views)
        st = log.anchor_status
        log.stop = (
            "budget"
            if "budget" in st or "not visited" in st
            else "complete"
            if all(x == "complete" for x in st)
            else "incomplete"
        )
        return log

    def _visit(self, session, ai: int, log: UserLog, n_views: int) -> int:
        """Steps 1–5 (docs/design-notes.md) on anchor ``ai``; returns the session's
        centroid-view count."""
        b = self.budget
        if n_views >= log.max_views:
            log.anchor_status.append("not visited")
            log.uncovered_after.append(-1)
            return n_views
        cam = session.anchors[ai].camera
        min_area = self._min_area(cam)
        tried: list[tuple[int, int]] = []
        failed, last = 0, None
        status, uncovered = "clicks", 0
        while True:
            tgt = self.target(session, cam, log)
            cov = self.overlay_mask(session, cam)
            uncovered = int(np.count_nonzero(tgt & ~cov))
            if last is not None:  # did the last click shrink the uncovered target?
                failed = 0 if last - uncovered >= min_area else failed + 1
            last = uncovered
            regions = uncovered_regions(tgt, cov, min_area)
            if not regions:
                status = "complete"
                break
            if n_views >= log.max_views:
                status = "budget"
                break
            if failed >= b.max_failed_clicks:
                status = "stalled"
                break
            if b.clicks_per_anchor is not None and len(tried) >= b.clicks_per_anchor:
                break
            # a region an earlier click of this anchor did not cover is clicked again
            # away from that click (its centroid view would be the same one)
            xy = region_centre(regions[0], avoid=tried)
            tried.append((int(xy[0]), int(xy[1])))
            click = UserClick(ai, xy, int(regions[0].sum()), uncovered, int(np.count_nonzero(tgt)))
            log.clicks.append(click)
            try:
                view = session.click(ai, xy)
            except DivasInputError:
                click.status = "no surface"
                continue
            n_views += 1
            click.view_id = view.id
            self._accept(session, view, click, log)
        log.anchor_status.append(status)
        log.uncovered_after.append(uncovered)
        return n_views

    def _min_area(self, cam) -> int:
        return max(1, int(round(self.budget.min_region_frac * cam.width * cam.height)))

    def _browse(self, session, seen: set[int], log: UserLog) -> int | None:
        """The training camera to add as the next manual anchor, or None: thumbnails
        ranked by their largest uncovered target region; the best one that still shows
        a region of the minimum area at working resolution wins (every camera opened
        is marked ``seen`` and not offered again)."""
        ranked = []
        ind = session.indicator()
        thr = np.float32(session.config.overlay_threshold)
        for i, full in enumerate(session.cameras):
            if i in seen:
                continue
            thumb = full.scaled(self.budget.browse_scale)
            tgt = self._thumb_target(session, i, thumb)
            if not tgt.any():
                continue
            cov = session.renderer.render_values(thumb, ind) >= thr
            regions = uncovered_regions(tgt, cov, self._min_area(thumb))
            if regions:
                ranked.append((-int(regions[0].sum()), i))
        for _, i in sorted(ranked):
            seen.add(i)
            cam = session.working_camera(session.cameras[i])
            if uncovered_regions(
                self.target(session, cam, log), self.overlay_mask(session, cam), self._min_area(cam)
            ):
                return i
        return None

    def _thumb_target(self, session, i: int, thumb) -> np.ndarray:
        """The user's target on training-camera thumbnail ``i`` (cached: it never changes)."""
        key = (id(session.renderer), i, thumb.width, thumb.height)
        if key not in self._thumbs:
            self._thumbs[key] = session.renderer.render_values(thumb, self.gt_values) >= np.float32(
                self.budget.target_threshold
            )
        return self._thumbs[key]

    def _accept(self, session, view, click: UserClick, log: UserLog) -> None:
        b = self.budget
        prev = session.prompt(view)
        tgt = mask = None
        if (b.negative_clicks or b.min_accept_precision > 0) and prev.selection.accepted:
            tgt = self.target(session, view.camera, log)
            mask = np.asarray(prev.selection.mask) >= 0.5
        if b.negative_clicks and tgt is not None:
            fp = uncovered_regions(mask, tgt, self._min_area(view.camera))
            if fp:
                nxy = region_centre(fp[0])
                click.negatives.append(nxy)
                p2 = session.prompt(view, [nxy], [0])
                m2 = np.asarray(p2.selection.mask) >= 0.5 if p2.selection.accepted else None
                if m2 is not None and _iou(m2, tgt) > _iou(mask, tgt):
                    click.negative_kept = True
                    mask = m2
                else:
                    session.prompt(view)  # back to the default prompt
        if mask is not None and leak_free_fraction(mask, tgt) < b.min_accept_precision:
            click.status = "declined"
            return
        session.accept(view)
        session.sync()
        click.status = view.status
