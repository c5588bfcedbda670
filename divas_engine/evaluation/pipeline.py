"""Scripted DivAS sessions for the evaluation: the real interactive
:class:`~divas_engine.session.Session` driven by the synthetic scenes' metadata.

Two protocols per scene (one object): ``"user"`` (default) — the paper's interactive protocol
(Sec. 3.3 / 3.7): a simulated user (:class:`~.scripted_user.ScriptedUser`) looks at each
anchor with the running overlay, clicks the largest uncovered region and accepts each centroid
view, within a :class:`~.scripted_user.UserBudget`; ``"clicks"`` — the metadata clicks of
:func:`~.demo_prompts.demo_prompts` (the ``divas demo`` protocol), every view accepted exactly as
``divas segment`` does. The segmenter is fresh per session.

Ablations are the same session with one config change (:data:`VARIANTS`): ``no_thin``
(``gs_fusion.rho_thin = inf``) and ``no_depth_weight`` (``denom_floor = inf`` and
``invalid_weight = 1``, so ``M̃ = M``). Pass 1 only / Pass 1+2 are read from the full session's
last mapping (``MappingResult.pass1`` / ``.pass2``): the chain is monotone.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..camera import Camera
from ..fusion.config import GsFusionConfig
from ..kinds import SceneKind, ViewStatus
from ..scene import Scene
from ..segment.depth_weighting import GsBandpassConfig, NerfDepthWeightConfig
from ..segment.factory import SegmenterKind, SegmenterSettings, build_segmenter
from ..session import Session, SessionConfig
from .baselines import MaskView
from .demo_prompts import demo_prompts
from .scripted_user import ScriptedUser, UserLog

__all__ = [
    "VARIANTS",
    "variant_config",
    "scripted_anchors",
    "SessionOutcome",
    "run_session",
    "make_segmenter",
    "CachingRenderer",
]

#: Session variants: name → description.
VARIANTS: dict[str, str] = {
    "full": "DivAS, paper defaults",
    "no_thin": "without the thin path (rho_thin = inf)",
    "no_depth_weight": "without depth weighting of the masks (M~ = M)",
}


def variant_config(name: str, base: SessionConfig | None = None) -> SessionConfig:
    """The :class:`SessionConfig` of a variant of :data:`VARIANTS`."""
    cfg = base or SessionConfig()
    if name == "full":
        return cfg
    if name == "no_thin":
        return replace(cfg, gs_fusion=replace(cfg.gs_fusion or GsFusionConfig(), rho_thin=math.inf))
    if name == "no_depth_weight":
        return replace(
            cfg,
            bandpass=replace(
                cfg.bandpass or GsBandpassConfig(), denom_floor=math.inf, invalid_weight=1.0
            ),
            nerf_weight=replace(
                cfg.nerf_weight or NerfDepthWeightConfig(), denom_floor=math.inf, invalid_weight=1.0
            ),
        )
    raise ValueError(f"unknown variant {name!r}; choose one of {list(VARIANTS)}")


def scripted_anchors(
    metadata: dict, cameras: Sequence[Camera]
) -> list[tuple[Camera, str, int, list[tuple[float, float]]]]:
    """``(camera, "training", index, clicks)`` per anchor, from the scene metadata
    (the ``divas demo`` protocol, :func:`~.demo_prompts.demo_prompts`)."""
    from ..session.prompts import resolve_anchors

    prompts = demo_prompts(metadata, list(cameras))
    out = []
    for r in resolve_anchors(prompts, list(cameras)):
        out.append((r.camera, r.source, r.index, [tuple(c.xy) for c in r.prompt.clicks]))
    return out


class CachingRenderer:
    """A renderer wrapper that memoises :meth:`render` and :meth:`render_values`.

    The renderers are deterministic, so the variant sessions of one scene (which render
    the same anchors and centroid views, and the oracle's same label coverage) can share
    results: outputs are identical to the wrapped renderer's. Keys are the camera's exact
    parameters and scale (plus a BLAKE2 digest of the values). Cached arrays are made
    read-only; the least recently used entries are dropped beyond ``max_bytes``.
    """

    def __init__(self, inner, max_bytes: int = 2 << 30) -> None:
        self.inner = inner
        self.max_bytes = int(max_bytes)
        self._cache: OrderedDict[tuple, tuple[Any, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = self.misses = 0

    def __getattr__(self, name: str) -> Any:  # kind, device, num_primitives, …
        return getattr(self.inner, name)

    @staticmethod
    def _cam_key(camera: Camera, scale: float) -> tuple:
        return (
            camera.width,
            camera.height,
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            camera.c2w.tobytes(),
            camera.name,
            camera.near,
            float(scale),
        )

    def _get(self, key: tuple, make):
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                self.hits += 1
                return hit[0]
        val = make()
        arrays = (
            [val]
            if isinstance(val, np.ndarray)
            else [a for a in vars(val).values() if isinstance(a, np.ndarray)]
        )
        for a in arrays:
            a.flags.writeable = False
        nbytes = sum(a.nbytes for a in arrays)
        with self._lock:
            self.misses += 1
            if key not in self._cache:
                self._cache[key] = (val, nbytes)
                self._bytes += nbytes
            while self._bytes > self.max_bytes and len(self._cache) > 1:
                _, (_, nb) = self._cache.popitem(last=False)
                self._bytes -= nb
        return val

    def render(self, camera: Camera, scale: float = 1.0):
        return self._get(
            ("rgb",) + self._cam_key(camera, scale), lambda: self.inner.render(camera, scale)
        )

    def render_values(self, camera: Camera, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        v = np.ascontiguousarray(values)
        digest = hashlib.blake2b(v.view(np.uint8).reshape(-1), digest_size=16).hexdigest()
        return self._get(
            ("values", v.dtype.str, v.shape, digest) + self._cam_key(camera, scale),
            lambda: self.inner.render_values(camera, values, scale),
        )


def make_segmenter(name: str, seed: int = 0):
    """A fresh segmenter: ``"oracle"`` (SAM-like oracle, NOTES), ``"graph3d"`` (the
    default, 3D cut) or ``"classic"``."""
    if name not in ("oracle", "graph3d", "classic"):
        raise ValueError(f"unknown segmenter {name!r} (oracle, graph3d, classic)")
    settings = SegmenterSettings(SegmenterKind(name), seed=seed)
    return build_segmenter(settings, has_ground_truth=True)  # the session's labels


@dataclass(eq=False)
class SessionOutcome:
    """What one scripted session produced.

    Attributes:
        selection: the final selection (``[N]`` surfels / ``[D,H,W]`` voxels).
        pass1, pass2: 2DGS mapping chain f¹, f² of the final state (None for NeRF).
        mapped: the paper's selection f (Pass 3) before the 3DGS completion (the
            same as ``selection`` when no completion ran; None for NeRF).
        completion: counts of the 3DGS completion (None when it did not run).
        completion_masks: its ``[N] bool`` parts ``contrib_added``, ``fill_added`` and
            ``dropped`` (None when it did not run; :mod:`.breakdown`).
        views: the fused views as :class:`MaskView` with the *raw* accepted masks (the
            segmenter's chosen channel before depth weighting) and their ``D_med``.
        weighted_views: the same with the depth-weighted masks that were fused.
        counts, statuses: session counts and ``(view id, status, reason)``.
        seconds: wall time of the session (open → last accept).
        timings: the session's stage timings.
        user_log: what the simulated user did (protocol ``"user"``), else None.
        anchors: ``(camera name, source, index)`` of the session's anchors.
    """

    selection: np.ndarray
    pass1: np.ndarray | None
    pass2: np.ndarray | None
    mapped: np.ndarray | None
    completion: dict | None
    views: list[MaskView]
    weighted_views: list[MaskView]
    counts: dict
    statuses: list[tuple[str, str, str | None]]
    seconds: float
    timings: dict = field(default_factory=dict)
    user_log: UserLog | None = None
    anchors: list = field(default_factory=list)
    completion_masks: dict[str, np.ndarray] | None = None


def run_session(
    scene: Scene,
    cameras: Sequence[Camera],
    labels: np.ndarray,
    anchors: Sequence[tuple[Camera, str, int, Sequence[tuple[float, float]]]] | None = None,
    *,
    segmenter: Any,
    config: SessionConfig | None = None,
    device=None,
    renderer=None,
    user: ScriptedUser | None = None,
) -> SessionOutcome:
    """Open a session on ``scene`` and drive it with one of the two protocols.

    * ``user`` given (protocol ``"user"``): the session opens on its own anchor plan
      (Sec. 3.2; :meth:`~.scripted_user.ScriptedUser.anchors`) and the
      :class:`~.scripted_user.ScriptedUser` clicks uncovered target
      regions under the overlay, accepting each view as it goes (``anchors`` must be
      None);
    * else (protocol ``"clicks"``): click every click of ``anchors``, then accept every
      view.

    Args:
        labels: ground truth (the oracle's target; unused by other segmenters).
        anchors: from :func:`scripted_anchors` (full-resolution pixels).
        renderer: a renderer of ``scene`` to share between sessions.
    """
    if (user is None) == (anchors is None):
        raise ValueError("run_session: pass either anchors (clicks protocol) or user")
    t0 = time.perf_counter()
    cfg = config or SessionConfig()
    if user is not None:
        from ..session import anchor_plan

        items = user.anchors(anchor_plan(scene, list(cameras), cfg))
    else:
        items = [(c, src, i) for c, src, i, _ in anchors]
    s = Session.open(
        scene,
        list(cameras),
        cfg,
        segmenter,
        device,
        anchors=items,
        gt_values=np.asarray(labels, np.float32),
        render_anchors=False,
        renderer=renderer,
    )
    try:
        user_log = None
        if user is not None:
            user_log = user.run(s)
            spawned = list(s.views)
        else:
            spawned = []
            for i, (_, _, _, clicks) in enumerate(anchors):
                a = s.anchors[i]
                for xy in clicks:
                    x, y = a.full_camera.pixels_to(a.camera, xy)
                    spawned.append(s.click(i, (float(x), float(y))))
            for v in spawned:
                s.accept(v)
        s.sync()
        spawned = list(s.views)  # with the wider views the session added (.widening)
        views, weighted, statuses = [], [], []
        for v in spawned:
            statuses.append((v.id, v.status, v.reason))
            if v.status != ViewStatus.FUSED:
                continue
            b = v.buffers
            raw = v.preview.selection.mask
            views.append(MaskView(v.camera, raw, b.D_med))
            weighted.append(MaskView(v.camera, v.mask, b.D_med))
        sel = s.selection.copy()
        p1 = p2 = mapped = comp = comp_masks = None
        if s.kind == SceneKind.GS2D:
            m = s.last_mapping if views else None  # no fused view: empty chain
            p1 = np.zeros_like(sel) if m is None else m.pass1.copy()
            p2 = np.zeros_like(sel) if m is None else m.pass2.copy()
            mapped = np.zeros_like(sel) if m is None else m.selected.copy()
            c = getattr(s.backend, "last_completion", None) if views else None
            comp = None if c is None else {**c.counts(), "rounds": c.rounds, **c.seconds}
            if c is not None:
                comp_masks = {
                    k: np.asarray(getattr(c, k), bool).copy()
                    for k in ("contrib_added", "fill_added", "dropped")
                }
        return SessionOutcome(
            selection=sel,
            pass1=p1,
            pass2=p2,
            mapped=mapped,
            completion=comp,
            views=views,
            weighted_views=weighted,
            counts=s.counts(),
            statuses=statuses,
            seconds=time.perf_counter() - t0,
            timings=s.timings.summary(),
            user_log=user_log,
            anchors=[(a.full_camera.name, a.source, a.source_index) for a in s.anchors],
            completion_masks=comp_masks,
        )
    finally:
        s.close()
