"""Front-to-back compositing state and the per-pixel depth tuple (NOTES "Depth tuple").

Shared by the 2DGS rasterizer and the NeRF ray-marcher so both report the same
quantities with the same rules. Per pixel, primitives/samples ``k`` arrive in
front-to-back order with opacity ``α_k`` and planar depth ``z_k``; the weight is
``w_k = α_k T_k`` with ``T_k = Π_{j<k} (1 − α_j)``:

* ``D_min``: ``z`` of the first ``k`` with ``w_k ≥ τ_sig``; none → 0.
* ``D_med``: ``z`` of the ``k`` at which ``1 − T`` (after blending ``k``) first reaches 0.5;
  none → 0.
* ``D_max``: ``z`` of the ``k`` at which ``1 − T`` first reaches ``τ_cw``; never → the last
  *contributing* ``k`` (``α_k ≥ α_min``); none → 0.
* ``D_exp = Σ w z / Σ w`` (0 when ``Σ w = 0``); ``D_mw``: ``z`` of the largest ``w_k``
  (first on ties; 0 when nothing contributed).
* ``N_samp``: elements with ``α_k ≥ α_min`` traversed up to and including the anchor
  (``D_med`` for 2DGS, ``D_max`` for NeRF); no anchor → all traversed.
* Termination: after blending ``k``, stop once ``T < T_min``.
* Features (RGB or any per-primitive values) accumulate ``Σ w_k f_k`` plus
  ``T_final · background``.
"""

from __future__ import annotations

import warp as wp

__all__ = [
    "PixState",
    "BlendParams",
    "PixelOut",
    "state_init",
    "blend_step",
    "finish_pixel",
    "ANCHOR_MED",
    "ANCHOR_MAX",
    "FLAG_DONE",
]

FLAG_MIN = wp.constant(1)
FLAG_MED = wp.constant(2)
FLAG_MAX = wp.constant(4)
FLAG_DONE = wp.constant(8)
FLAG_ANY = wp.constant(16)

#: ``N_samp`` counts up to the ``D_med`` element (2DGS) …
ANCHOR_MED = 2
#: … or up to the ``D_max`` element (NeRF).
ANCHOR_MAX = 4


@wp.struct
class PixState:
    """Running compositing state of one pixel."""

    T: float  # transmittance
    ws: float  # Σ w
    wz: float  # Σ w z
    d_min: float
    d_med: float
    d_max: float
    d_mw: float
    w_max: float
    d_last: float  # depth of the last contributing element
    n_samp: int
    flags: int  # FLAG_* bits


@wp.struct
class BlendParams:
    """Compositing constants (see :class:`divas_engine.render.RenderConfig`)."""

    tau_sig: float  # τ_sig, D_min weight threshold
    tau_cw: float  # τ_cw, D_max cumulative-opacity threshold
    t_min: float  # termination transmittance
    alpha_min: float  # 1/255: smallest contributing opacity
    anchor: int  # ANCHOR_MED or ANCHOR_MAX


@wp.struct
class PixelOut:
    """Per-pixel output buffers, flattened ``p = y * width + x``."""

    feat: wp.array2d(dtype=float)  # [P, C] Σ w f (+ T·bg after finish)
    bg: wp.array(dtype=float)  # [C] background added with the final T
    alpha: wp.array(dtype=float)  # [P] 1 − T
    d_min: wp.array(dtype=float)
    d_med: wp.array(dtype=float)
    d_max: wp.array(dtype=float)
    d_mw: wp.array(dtype=float)
    d_exp: wp.array(dtype=float)
    n_samp: wp.array(dtype=wp.int32)


@wp.func
def state_init() -> PixState:
    s = PixState()
    s.T = 1.0
    s.ws = 0.0
    s.wz = 0.0
    s.d_min = 0.0
    s.d_med = 0.0
    s.d_max = 0.0
    s.d_mw = 0.0
    s.w_max = 0.0
    s.d_last = 0.0
    s.n_samp = 0
    s.flags = 0
    return s


@wp.func
def blend_step(s: PixState, alpha: float, z: float, bp: BlendParams):
    """Blend one element (``alpha`` > 0, planar depth ``z``); returns the new state and ``w``."""
    r = s
    w = alpha * r.T
    contributing = alpha >= bp.alpha_min
    if contributing:
        if (r.flags & bp.anchor) == 0:
            r.n_samp = r.n_samp + 1
        r.d_last = z
        r.flags = r.flags | FLAG_ANY
    if (r.flags & FLAG_MIN) == 0 and w >= bp.tau_sig:
        r.d_min = z
        r.flags = r.flags | FLAG_MIN
    r.ws = r.ws + w
    r.wz = r.wz + w * z
    if w > r.w_max:
        r.w_max = w
        r.d_mw = z
    r.T = r.T * (1.0 - alpha)
    acc = 1.0 - r.T
    if (r.flags & FLAG_MED) == 0 and acc >= 0.5:
        r.d_med = z
        r.flags = r.flags | FLAG_MED
    if (r.flags & FLAG_MAX) == 0 and acc >= bp.tau_cw:
        r.d_max = z
        r.flags = r.flags | FLAG_MAX
    if r.T < bp.t_min:
        r.flags = r.flags | FLAG_DONE
    return r, w


@wp.func
def finish_pixel(s: PixState, p: int, out: PixelOut):
    """Write the depth tuple of pixel ``p`` and add ``T · background`` to its features."""
    out.alpha[p] = 1.0 - s.T
    out.d_min[p] = s.d_min
    out.d_med[p] = s.d_med
    dmax = s.d_max
    if (s.flags & FLAG_MAX) == 0:
        dmax = s.d_last
    out.d_max[p] = dmax
    out.d_mw[p] = s.d_mw
    dexp = float(0.0)
    if s.ws > 0.0:
        dexp = s.wz / s.ws
    out.d_exp[p] = dexp
    out.n_samp[p] = wp.int32(s.n_samp)
    for c in range(out.bg.shape[0]):
        out.feat[p, c] = out.feat[p, c] + s.T * out.bg[c]
