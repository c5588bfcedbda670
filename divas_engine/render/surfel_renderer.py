"""2DGS surfel renderer: the tile rasterizer of ``divas_kernels.rasterize`` behind the
:class:`~divas_engine.render.protocol.Renderer` base class."""

from __future__ import annotations

import sys
import threading
from contextlib import nullcontext
from dataclasses import replace

import numpy as np

from divas_kernels import (
    ContribOutput,
    ScratchPool,
    accumulate_contributions,
    binning_key,
    pixel_window,
    rasterize_surfels,
    recycling,
    resolve_device,
    surfel_rows,
    to_device,
    upload_surfels,
)

from ..camera import Camera
from ..kinds import SceneKind
from ..scene import SurfelScene
from .buffers import RenderBuffers
from .config import RenderConfig
from .protocol import Renderer
from .surfel_blocks import SurfelBlocks

__all__ = ["SurfelRenderer"]


def _take_unshared_splats(binning, unshared: tuple[int, int] | None = None):
    """``binning.splats``, taken from it, when this call's argument is the binning's only
    reference and the binning the array's: no other thread is walking it, and no view of
    its memory is out. The test reads CPython's reference counts, as NumPy's ``resize``
    does. Returns None otherwise. ``unshared``: the counts of such a binning, which
    differ between Python versions; None calibrates them (returns the counts)."""
    counts = (sys.getrefcount(binning), sys.getrefcount(binning.splats))
    if unshared is None:
        return counts
    if counts[0] > unshared[0] or counts[1] > unshared[1]:
        return None
    splats, binning.splats = binning.splats, None
    return splats


class _Probe:
    def __init__(self) -> None:
        self.splats = object()


#: the counts of a binning nothing else holds, passed as :meth:`SurfelRenderer._make_room`
#: passes one (a temporary argument)
_UNSHARED: tuple[int, int] = _take_unshared_splats(_Probe())


class SurfelRenderer(Renderer):
    """Renders a :class:`SurfelScene`; the scene is uploaded to ``device`` once.

    Depth tuple per NOTES "Depth tuple", ``D_ref = D_med``. Points NOTES leaves open,
    settled here (details in ``kernels/rasterize.py``):

    * blend order: ascending planar *centre* depth (the 2DGS rasterizer's global
      sort), ties by surfel index;
    * the low-pass Gaussian is always combined by max (as 2DGS does), which is the
      edge-on fallback; its depth is the centre depth;
    * a surfel is drawn only if its whole cutoff disc (α ≥ 1/255, ≤ 3.33σ) lies beyond
      the near plane (``config.near``, or the camera's own larger ``Camera.near``);
      screen bounds are exact for that disc (not a fixed 3σ box);
    * "stop when T < 1e-4": the element that brings T below is blended, then stop;
    * ``N_samp`` with no ``D_med`` counts every traversed contributing surfel.

    The projection, culling, depth sort and tile binning of the last
    ``binning_cache`` views are kept (:class:`divas_kernels.ViewBinning`), so a value
    render (overlay, oracle target) of a camera just rendered in RGB only blends —
    bit-identical to a fresh render. 0 turns the cache off.

    Values known before a view is rendered (:meth:`attach_values`: the oracle's ground
    truth) are composited in every RGB render's own blend, as extra channels; a later
    :meth:`render_values` of that camera with the same values returns that image
    without blending again — bit-identical to a separate value render.
    """

    kind = SceneKind.GS2D

    #: views whose binning is kept (the anchor on screen, the current and the next view:
    #: their overlays); probe renders (``render_depth``) keep none
    binning_cache: int = 3
    #: device memory the kept binnings may hold together (each ≈ 60–80 bytes per surfel
    #: of the scene: its visible splats, the colours and the pairs — 3 views of a
    #: 1M-surfel scene, 1 of a 3M one, none from ≈ 4M on)
    binning_cache_bytes: int = 256 << 20
    #: keep an RGB render's per-surfel SH colours (``[N,3]`` float32, 12 bytes per surfel
    #: of the scene) with its binning, for a second RGB render of the same camera. A
    #: session never makes one (anchors and views keep their buffers; the value renders
    #: that reuse a binning read no colours), so they are dropped (34 MB at 3M surfels).
    #: A dropped colour set only means that RGB render projects afresh.
    binning_keeps_colours: bool = False
    #: how many RGB renders' composites of the attached values are kept (an image each:
    #: ``H·W·C`` floats, 1.2 MB for one channel at 640×480)
    value_images_kept: int = 4
    #: :meth:`render_values_sparse` takes its working arrays from buffers kept across
    #: calls (``divas_kernels.scratch``) — memory held between calls, ≈ 140 MB at 3M. Pays
    #: where the C heap maps every large array afresh (the add-on's fixed mmap threshold:
    #: far fewer page faults a mask render; the add-on switches it on there); with
    #: glibc's adaptive threshold the freed arrays
    #: are reused anyway and the first call costs more (every array its own buffer)
    scratch_sparse: bool = False
    #: the other renders (views, anchors, probes) too, for what no binning keeps (fewer
    #: fresh pages) — another ≈ 110 MB held at 3M, so off by default: it raises the peak
    #: RSS of a large scene in Blender
    scratch_renders: bool = False
    #: a render that replaces a kept binning writes its splats into the dropped one's
    #: array when nothing else holds it and its splats fit (``divas_kernels.recycling``):
    #: the same bits, and no fresh pages to fault in (41k, ≈ 5 % of the render's CPU, for
    #: a 3M view after a similar one). CPU only
    recycle_binnings: bool = True

    def __init__(self, scene: SurfelScene, device=None, config: RenderConfig | None = None):
        self.config = config or RenderConfig()
        self._binnings: list = []
        self._blocks: SurfelBlocks | None = None
        self._attached: tuple[np.ndarray, object] | None = None  # (host [N,C], device)
        self._images: list[tuple[tuple, np.ndarray]] = []  # (key, [P, C]) newest first
        #: the transient arrays of every CPU render (all of :meth:`render_values_sparse`'s;
        #: those no binning keeps of the others), reused render to render
        self._scratch = ScratchPool()
        self._sparse_lock = threading.Lock()  # sparse renders (they may run beside others)
        self._index_lock = threading.Lock()  # the block index, built once
        self.device = resolve_device(device)
        self.num_primitives = len(scene)
        self._buf = upload_surfels(
            scene.means,
            scene.rotations(),
            scene.scales,
            scene.opacities,
            scene.sh,
            scene.sh_degree,
            self.device,
            self.config.alpha_min,
        )

    def _run(
        self,
        cam: Camera,
        values: np.ndarray | None,
        features: bool = True,
        keep: bool = True,
        window: tuple[int, int, int, int] | None = None,
        extra=None,
    ):
        hit = self.kept_binning(cam) if window is None else None
        rgb = values is None and features
        if hit is not None and rgb and (hit.colors is None or extra is not None):
            hit = None  # an RGB render of a binning kept without its colours: afresh
        keep = keep and window is None and self.binning_cache > 0
        donors: list = []
        if keep and hit is None:
            donors = self._make_room()
        rows = None
        if hit is None and self.device.is_cpu and (window is not None or self._blocks is not None):
            rows = self._candidates(cam, window)
        # the working arrays no binning keeps in buffers kept from the last render
        # (divas_kernels.scratch: no fresh pages to fault in), when switched on
        pool = self._scratch.active(everything=False) if self.scratch_renders else nullcontext()
        with pool, recycling(donors):
            r = rasterize_surfels(
                self._buf,
                *_projection(cam),
                self.config.raster_settings(cam),
                values=values,
                background=self.config.background,
                features=features,
                binning=hit,
                keep_binning=keep,
                window=window,
                rows=rows,
                extra=extra,
                # the colours' array is a scratch one only when it is not kept
                keep_colours=self.binning_keeps_colours or not self.scratch_renders,
            )
        b = r.binning
        if b is not None:
            if not self.binning_keeps_colours:
                b.colors = None
            kept = [b] + [x for x in self._binnings if x is not b and x.key != b.key]
            self._binnings, total = [], 0
            for x in kept[: self.binning_cache]:
                total += x.nbytes
                if total > self.binning_cache_bytes:
                    break
                self._binnings.append(x)
            r.binning = None
        return r

    #: block culling is skipped when it keeps more than this fraction of the surfels
    block_cull_max_fraction: float = 0.85

    def _candidates(self, cam: Camera, window) -> np.ndarray | None:
        """The surfels of the scene blocks that can reach ``window`` of ``cam`` (the
        image when None; :meth:`SurfelBlocks.in_window`), or None when that is most of
        the scene. Projecting only them renders the same image bit for bit (a centroid
        view and its probes see a small part of the scene). CPU only."""
        if self.num_primitives == 0:
            return None
        blocks, _ = self.sparse_index()
        win = pixel_window(window, cam.width, cam.height)
        rows = blocks.in_window(cam, win, self._margin_px)
        return None if len(rows) > self.block_cull_max_fraction * self.num_primitives else rows

    def _make_room(self) -> list:
        """Before a render whose binning will be kept: drop the oldest kept binnings that
        would be dropped after it anyway (the count, or the bytes with one more of the
        size of the largest kept), so their memory is free while it renders (at 3M
        surfels one binning is ≈ 0.2 GB). A cache only: no result changes.

        Returns the dropped binnings' splat arrays that nothing else holds, for the
        render to write its own splats into (``divas_kernels.recycling``; CPU, when
        ``recycle_binnings``)."""
        est = max((x.nbytes for x in self._binnings), default=0)
        recycle = self.recycle_binnings and self.device.is_cpu
        donors = []
        while self._binnings and (
            len(self._binnings) >= self.binning_cache
            or sum(x.nbytes for x in self._binnings) + est > self.binning_cache_bytes
        ):
            if not recycle:
                self._binnings.pop()
                continue
            # popped straight into the call: a name bound to it would count as a holder
            splats = _take_unshared_splats(self._binnings.pop(), _UNSHARED)
            if splats is not None:
                donors.append(splats)
        return donors

    def render(self, camera: Camera, scale: float = 1.0, *, attached: bool = True) -> RenderBuffers:
        """RGB and depth tuple; ``attached`` False: without the :meth:`attach_values`
        channels (a view that will not be segmented, e.g. an anchor)."""
        cam = camera if scale == 1.0 else camera.scaled(scale)
        att = self._attached if attached else None
        r = self._run(cam, None, extra=None if att is None else att[1])
        f = r.out.feat.numpy()
        if att is None:
            rgb = f.reshape(cam.height, cam.width, 3)
        else:  # the attached values' channels follow the RGB: kept for render_values
            rgb = np.ascontiguousarray(f[:, :3]).reshape(cam.height, cam.width, 3)
            key = self._image_key(cam)
            rest = [x for x in self._images if x[0] != key]
            self._images = [(key, f[:, 3:].copy())] + rest[: max(self.value_images_kept - 1, 0)]
        return self._buffers(r.out, cam, rgb, r.stats)

    def attach_values(self, values: np.ndarray | None) -> None:
        """Per-surfel values ``[N]`` or ``[N, C]`` that every later :meth:`render`
        composites in its own blend (extra channels of the same per-pixel loop, no
        background), so that :meth:`render_values` of a camera rendered since, given
        values equal to these bit for bit (as float32), returns that composite without
        blending again: the same image bit for bit (the oracle's ground truth at each
        view the session shows; a separate value render costs a blend as long as the
        RGB one). A private float32 copy is held; None detaches."""
        self._images = []
        if values is None:
            self._attached = None
            return
        v = np.array(values, dtype=np.float32)  # a copy: the caller may change theirs
        if v.ndim not in (1, 2) or v.shape[0] != self.num_primitives:
            raise ValueError(
                f"attach_values: expected [{self.num_primitives}] or "
                f"[{self.num_primitives}, C] values, got {v.shape}"
            )
        v = np.ascontiguousarray(v[:, None] if v.ndim == 1 else v)
        v.flags.writeable = False
        # on the CPU the rasterizer wraps the host array; on CUDA it is uploaded once
        self._attached = (v, v if self.device.is_cpu else to_device(v, self.device))

    @property
    def attached_values(self) -> np.ndarray | None:
        """The attached values (read-only ``[N, C]`` float32 copy), or None."""
        return None if self._attached is None else self._attached[0]

    def _image_key(self, cam: Camera) -> tuple:
        """What a composite of the attached values at ``cam`` depends on: the view's
        binning and the blend constants."""
        s = self.config.raster_settings(cam)
        blend = (float(s.tau_sig), float(s.tau_cw), float(s.t_min), float(s.alpha_min))
        return binning_key(self._buf, *_projection(cam), s) + (blend, float(s.alpha_max))

    def _composited(self, cam: Camera, values: np.ndarray) -> np.ndarray | None:
        """The kept composite of ``values`` at ``cam`` (``[H,W]`` for ``[N]`` values,
        else ``[H,W,C]``) when the attached values equal them bit for bit, else None."""
        if self._attached is None or not self._images:
            return None
        key = self._image_key(cam)
        img = next((im for k, im in self._images if k == key), None)
        if img is None:
            return None
        att = self._attached[0]
        v = np.asarray(values, dtype=np.float32)  # what a value render composites
        v2 = v[:, None] if v.ndim == 1 else v
        if v.ndim not in (1, 2) or v2.shape != att.shape:
            return None
        if not np.array_equal(v2.view(np.uint32), att.view(np.uint32)):
            return None
        H, W = cam.height, cam.width
        return (img.reshape(H, W) if v.ndim == 1 else img.reshape(H, W, -1)).copy()

    def render_depth(
        self,
        camera: Camera,
        scale: float = 1.0,
        window: tuple[int, int, int, int] | None = None,
    ) -> RenderBuffers:
        """The depth tuple only (probes): ``rgb`` is zeros, no SH colours are evaluated
        and nothing is composited but the depths, which equal :meth:`render`'s.

        ``window``: ``(x0, y0, x1, y1)`` half-open pixels of the (scaled) image — only
        they are rendered (equal to the whole render's, at the window's cost: surfels
        that miss it are culled); every pixel outside it holds the empty tuple (α 0,
        depths 0, ``N_samp`` 0)."""
        cam = camera if scale == 1.0 else camera.scaled(scale)
        o = self._run(cam, None, features=False, keep=False, window=window).out
        b = self._buffers(o, cam, np.zeros((cam.height, cam.width, 3), np.float32), {})
        if window is not None:
            x0, y0, x1, y1 = pixel_window(window, cam.width, cam.height)
            outside = np.ones((cam.height, cam.width), bool)
            outside[y0:y1, x0:x1] = False
            for a in (b.alpha, b.D_min, b.D_ref, b.D_max, b.D_mw, b.D_exp, b.D_med, b.N_samp):
                a[outside] = 0
        return b

    def _buffers(self, o, cam: Camera, rgb: np.ndarray, stats: dict) -> RenderBuffers:
        """The :class:`RenderBuffers` of one rasterizer output ``o`` of ``cam``."""
        H, W = cam.height, cam.width
        img = lambda a: a.numpy().reshape(H, W)  # noqa: E731
        d_med = img(o.d_med)
        return RenderBuffers(
            rgb=rgb,
            alpha=img(o.alpha),
            D_min=img(o.d_min),
            D_ref=d_med.copy(),
            D_max=img(o.d_max),
            D_mw=img(o.d_mw),
            D_exp=img(o.d_exp),
            D_med=d_med,
            N_samp=img(o.n_samp),
            camera=cam,
            kind=self.kind,
            stats=stats,
        )

    def contributions(
        self,
        camera: Camera,
        positive: np.ndarray,
        window: tuple[int, int, int, int] | None = None,
    ) -> ContribOutput:
        """FlashSplat-style split of each primitive's blending weight in ``camera`` by the
        ``[H,W]`` bool mask ``positive``: A₁ inside, A₀ outside — this renderer's own
        weights, walking the camera's kept binning when it was just rendered (same sums).
        ``window``: ``(x0, y0, x1, y1)``, only these pixels are walked (the weights at
        them are the whole pass's; :func:`~divas_kernels.accumulate_contributions`)."""
        return accumulate_contributions(
            self._buf,
            *_projection(camera),
            positive,
            self.config.raster_settings(camera),
            binning=None if window is not None else self.kept_binning(camera),
            window=window,
        )

    @property
    def surfel_buffers(self):
        """The scene's device buffers (:func:`divas_kernels.upload_surfels`), for passes
        that share this renderer's kept binnings (the 3DGS completion's gather)."""
        return self._buf

    def kept_binning(self, camera: Camera):
        """The kept :class:`divas_kernels.ViewBinning` of ``camera`` (as rendered: same
        size), or None."""
        key = binning_key(self._buf, *_projection(camera), self.config.raster_settings(camera))
        return next((b for b in self._binnings if b.key == key), None)

    def release(self, camera: Camera) -> bool:
        """Drop ``camera``'s kept binning now when the byte budget holds no second one
        beside it — the next render would drop it anyway (a 3M-surfel view: ≈ 0.2 GB);
        a view that is done with (accepted) frees its memory at once. Returns
        whether one was dropped; smaller binnings stay (their overlays reuse them)."""
        hit = self.kept_binning(camera)
        if hit is None or 2 * hit.nbytes <= self.binning_cache_bytes:
            return False
        self._binnings = [b for b in self._binnings if b is not hit]
        return True

    def clear_cache(self) -> None:
        """Drop the kept view binnings (frees their device memory), the kept
        composites of the attached values and the sparse renders' scratch buffers."""
        self._binnings = []
        self._images = []
        with self._sparse_lock:  # not while a sparse render holds the buffers
            self._scratch.release()

    def render_values(self, camera: Camera, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        values = np.asarray(values)
        if values.ndim not in (1, 2) or values.shape[0] != self.num_primitives:
            raise ValueError(
                f"render_values: expected [{self.num_primitives}] or "
                f"[{self.num_primitives}, C] values, got {values.shape}"
            )
        cam = camera if scale == 1.0 else camera.scaled(scale)
        kept = self._composited(cam, values)
        if kept is not None:  # composited in the RGB render's blend (attach_values)
            return kept
        r = self._run(cam, values)
        f = r.out.feat.numpy()
        H, W = cam.height, cam.width
        return f.reshape(H, W) if values.ndim == 1 else f.reshape(H, W, -1)

    @property
    def renders_sparse(self) -> bool:
        return True

    @property
    def sparse_renders_concurrent(self) -> bool:
        """Whether :meth:`render_values_sparse` may run in one thread while another
        renders (CPU: it reads the scene's buffers and block index and keeps nothing but
        its scratch buffers, under a lock of its own; on a GPU it is the dense render,
        which shares the kept binnings)."""
        return self.device.is_cpu

    def render_values_sparse(
        self, camera: Camera, rows: np.ndarray, values: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """:meth:`render_values` of per-surfel values that are 0 off the surfels ``rows``
        (sorted, unique; ``values [K]`` or ``[K,C]`` theirs), rendered with only the
        surfels that can blend before the deepest of them and reach the image
        (:mod:`.surfel_blocks`): the same composite bit for bit, at the cost of those
        surfels instead of the scene's. The dense render on a GPU (where the pass over
        the scene is cheap). ``threads``: the CPU launch threads of this render (1: the
        calling thread only — a render beside another one; every split is per
        item, so the image is the same bit for bit)."""
        rows = np.asarray(rows, np.int64)
        v = np.asarray(values, np.float32)
        flat = v.ndim == 1
        v = v.reshape(len(rows), 1 if flat else v.shape[1])
        if not self.device.is_cpu:
            dense = np.zeros((self.num_primitives, v.shape[1]), np.float32)
            dense[rows] = v
            out = self.render_values(camera, dense)
            return out.reshape(camera.height, camera.width, -1)[..., 0] if flat else out
        with self._sparse_lock:
            return self._render_sparse_cpu(camera, rows, v, flat, threads)

    def _render_sparse_cpu(
        self, camera: Camera, rows: np.ndarray, v: np.ndarray, flat: bool, threads: int | None
    ) -> np.ndarray:
        out = np.zeros((camera.height, camera.width, v.shape[1]), np.float32)
        blocks, reach = self.sparse_index()
        sub = blocks.near(camera, self._buf.means.numpy()[rows], reach[rows], self._margin_px)
        settings = self.config.raster_settings(camera)
        if threads is not None:
            settings = replace(settings, threads=int(threads))
        if len(sub):
            pos = np.minimum(np.searchsorted(sub, rows), len(sub) - 1)
            hit = sub[pos] == rows
            vs = np.zeros((len(sub), v.shape[1]), np.float32)
            vs[pos[hit]] = v[hit]
            # the gather and the rasterizer's working arrays in buffers kept from the last
            # call (divas_kernels.scratch: no fresh pages to fault in; the output is not one)
            with self._scratch.active() if self.scratch_sparse else nullcontext():
                r = rasterize_surfels(
                    surfel_rows(self._buf, sub, colours=False),
                    *_projection(camera),
                    settings,
                    values=vs,
                    background=self.config.background,
                )
            out = r.out.feat.numpy().reshape(camera.height, camera.width, -1)
        return out[..., 0] if flat else out

    def sparse_index(self) -> tuple[SurfelBlocks, np.ndarray]:
        """The scene's :class:`SurfelBlocks` and every surfel's footprint radius
        ``sqrt(ρ_cut) · max(s_1, s_2)`` (built once, on first use: a per-scene cost), and
        the screen margin of their bounds: the low-pass disc ``sqrt(ρ_cut) σ_lp`` plus
        rounding."""
        with self._index_lock:
            if self._blocks is None:
                self._build_sparse_index()
        return self._blocks, self._reach

    def _build_sparse_index(self) -> None:
        """Every surfel's footprint radius, the blocks over them and the screen margin."""
        b = self._buf
        k2 = np.maximum(b.rho_cut.numpy().astype(np.float64), 0.0)
        tu, tv = b.tu.numpy(), b.tv.numpy()
        reach = np.empty(len(k2))
        for c in range(0, len(k2), 1 << 18):  # in chunks: little transient memory
            sl = slice(c, c + (1 << 18))
            s = np.maximum(
                np.linalg.norm(tu[sl].astype(np.float64), axis=1),
                np.linalg.norm(tv[sl].astype(np.float64), axis=1),
            )
            reach[sl] = np.sqrt(k2[sl]) * s
        self._reach = reach
        k2max = float(k2.max()) if len(k2) else 0.0
        self._margin_px = np.sqrt(k2max) * float(self.config.lowpass_sigma) + 1.5
        self._blocks = SurfelBlocks.build(b.means.numpy(), self._reach)  # last: "built"


def _projection(cam: Camera) -> tuple:
    """The camera arguments every rasterizer wrapper takes: ``w2c, fx, fy, cx, cy, W, H``."""
    return cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height
