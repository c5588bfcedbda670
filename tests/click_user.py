"""A minimal simulated user for correction tests (RITM / SimpleClick style): over the
session's anchor views, the truth ``T`` (the target's labels rendered, ≥ 0.5) and the
prediction ``P`` (the selection rendered, ≥ 0.5); the next click is the pixel of
``T ∧ ¬P`` (positive) or ``P ∧ ¬T`` (negative) farthest from the error's border (the
Euclidean distance transform, the image border counting as border), deeper first, then
positive, then the lower anchor. Positive clicks are previewed and accepted; negative
ones are what the session makes of them. The evaluation's own protocol is
``divas eval --protocol noc``; this is the same rule, kept small for tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class UserClick:
    anchor: int
    xy: tuple[float, float]
    positive: bool
    depth: float


def masks(renderer, camera, labels: np.ndarray, selection: np.ndarray):
    """``(truth, prediction)`` at ``camera``: the labels and the selection rendered ≥ 0.5."""
    shape = (camera.height, camera.width)
    t = renderer.render_values(camera, labels.astype(np.float32)).reshape(shape) >= 0.5
    if not selection.any():
        return t, np.zeros_like(t)
    return t, renderer.render_values(camera, selection.astype(np.float32)).reshape(shape) >= 0.5


def next_click(session, labels: np.ndarray) -> UserClick | None:
    """The deepest error pixel over the anchors (module docstring); None: no error."""
    best = None
    for a in session.anchors:
        t, p = masks(session.renderer, a.camera, labels, session.selection)
        for positive, err in ((True, t & ~p), (False, p & ~t)):
            if not err.any():
                continue
            d = ndimage.distance_transform_edt(np.pad(err, 1))[1:-1, 1:-1]
            i = int(np.argmax(d))
            key = (-float(d.flat[i]), 0 if positive else 1, a.index)
            if best is None or key < best[0]:
                y, x = divmod(i, err.shape[1])
                best = (key, UserClick(a.index, (x + 0.5, y + 0.5), positive, float(d.flat[i])))
    return None if best is None else best[1]


def apply(session, click: UserClick) -> str:
    """Make ``click`` on the session; what it did."""
    res = session.click(click.anchor, click.xy, click.positive)
    if not click.positive:
        c = session.last_correction
        return "negative" if c is None else f"negative: {c.views_changed} views"
    session.prompt(res)
    session.accept(res)
    return str(res.status)


def image_iou(renderer, cameras, labels: np.ndarray, selection: np.ndarray) -> float:
    """Mean IoU of the selection's and the labels' renders (≥ 0.5) over ``cameras``."""
    out = []
    for cam in cameras:
        t, p = masks(renderer, cam, labels, selection)
        u = int((t | p).sum())
        out.append(int((t & p).sum()) / u if u else 1.0)
    return float(np.mean(out))
