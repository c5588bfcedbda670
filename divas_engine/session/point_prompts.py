"""A prompts file's anchors, its 3D points included, as cameras with clicks.

:func:`resolve_prompts` is what a host calls (``divas segment``, the add-on): the file's
own anchors (:func:`~.prompts.resolve_anchors`), then one anchor per camera the engine
picks for the file's ``points`` (:func:`~divas_engine.views.point_anchors.choose_point_anchors`
over the training cameras, or the Fibonacci candidates of a camera-free scene), each
with the points it sees as clicks. The depth a point is checked against is the depth a
click on that anchor is back-projected with, rendered as the session renders anchors.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from ..render.buffers import RenderBuffers
from ..scene import Scene
from ..views.point_anchors import PointAnchorConfig, choose_point_anchors
from .backends import backend_class_for
from .config import SessionConfig
from .prompts import (
    AnchorPrompt,
    Click,
    PointPrompt,
    Prompts,
    ResolvedAnchor,
    find_training_camera,
    resolve_anchors,
)

__all__ = ["resolve_prompts", "resolve_points", "session_points"]


def _click_depth(scene: Scene, buffers: RenderBuffers) -> np.ndarray:
    """The depth a click is back-projected with (the backends' ``click_depth``)."""
    return buffers.D_mw if backend_class_for(scene).kind == SceneKind.NERF else buffers.D_med


def resolve_points(
    prompts: Prompts,
    scene: Scene,
    cameras: Sequence[Camera],
    config: SessionConfig,
    render: Callable[[Camera], RenderBuffers],
    fibonacci: Callable[[], list[Camera]],
) -> list[ResolvedAnchor]:
    """The anchors the engine picks for ``prompts.points`` (none without points).

    ``render`` renders a camera at the session's resolution (a session's renderer);
    ``fibonacci`` returns the Fibonacci candidates (called only without training cameras).
    """
    if not prompts.points:
        return []
    training = bool(cameras)
    cands = list(cameras) if training else fibonacci()
    s = float(config.render_scale)

    def depth_of(i: int) -> tuple[Camera, np.ndarray]:
        cam = cands[i] if s == 1.0 else cands[i].scaled(s)
        return cam, _click_depth(scene, render(cam))

    xyz = np.array([p.xyz for p in prompts.points], np.float64)
    pos = np.array([p.positive for p in prompts.points], bool)
    picked = choose_point_anchors(
        xyz,
        pos,
        cands,
        depth_of,
        PointAnchorConfig(tol=config.negative_occlusion_tol),
        radius=np.array([p.radius for p in prompts.points], np.float64),
        source=prompts.source,
    )
    out = []
    for a in picked:
        cam = cands[a.candidate]
        clicks = tuple(Click(c.xy, c.positive) for c in a.clicks)
        if not training:
            kind, value, source = "fibonacci", a.candidate, "fibonacci"
        elif find_training_camera(list(cameras), cam.name) == a.candidate:
            kind, value, source = "training_camera", cam.name, "training"
        else:  # a name that does not single it out: the camera itself
            kind, value, source = "camera", cam, "training"
        out.append(
            ResolvedAnchor(
                cam,
                source,
                a.candidate,
                AnchorPrompt(kind, value, clicks),
                tuple(c.point for c in a.clicks),
            )
        )
    return out


def resolve_prompts(
    prompts: Prompts,
    scene: Scene,
    cameras: Sequence[Camera],
    config: SessionConfig,
    render: Callable[[Camera], RenderBuffers],
    fibonacci: Callable[[], list[Camera]],
) -> list[ResolvedAnchor]:
    """Every anchor of ``prompts``: the file's own, then those picked for its points."""
    fib: list[Camera] | None = None

    def candidates() -> list[Camera]:
        nonlocal fib
        if fib is None:
            fib = fibonacci()
        return fib

    own = resolve_anchors(prompts, list(cameras), candidates)
    return own + resolve_points(prompts, scene, cameras, config, render, candidates)


def session_points(doc: dict, object_index: int | None = None, source=None) -> Prompts:
    """The clicks of one object of a saved session (its checked JSON document) as 3D
    point prompts: each click's back-projected point and label, anchors in order, clicks
    in order. ``object_index``: the object (default: the last one holding clicks).

    Raises:
        DivasInputError: no such object, or it holds no click with a 3D point.
    """
    from ..errors import DivasInputError

    objs = doc["objects"]
    with_clicks = [o for o in objs if any(o["clicks"].values())]
    if object_index is None:
        if not with_clicks:
            raise DivasInputError(source, "the session holds no clicks")
        obj = with_clicks[-1]
    else:
        found = [o for o in objs if o["index"] == object_index]
        if not found:
            have = ", ".join(str(o["index"]) for o in objs)
            raise DivasInputError(source, f"no object {object_index} (objects: {have})")
        obj = found[0]
    points = []
    for a in sorted(obj["clicks"], key=int):
        for c in obj["clicks"][a]:
            if c.get("point") is not None:
                points.append(PointPrompt(tuple(float(x) for x in c["point"]), c["positive"]))
    if not points:
        raise DivasInputError(source, f"object {obj['index']} holds no click with a 3D point")
    return Prompts((), {}, None if source is None else str(source), tuple(points))
