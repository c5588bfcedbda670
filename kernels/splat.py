"""Per-view splat geometry of the 2DGS rasterizer: camera struct, projected splat
struct, conic screen bounds and the exact ray–splat evaluation (see
``divas_kernels.rasterize`` for the formulas)."""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = [
    "RasterCamera",
    "Splat",
    "make_raster_camera",
    "pixel_window",
    "conic_range",
    "splat_alpha",
    "row_span",
    "BIG",
]

BIG = wp.constant(1.0e30)


@wp.struct
class RasterCamera:
    R: wp.mat33  # world → camera rotation
    t: wp.vec3  # world → camera translation
    center: wp.vec3  # camera centre, world
    R64: wp.mat33d  # the same transform in float64 (projected centres)
    t64: wp.vec3d
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float
    # the pixel window rendered, inclusive (the whole image unless a window is asked
    # for): splat bounds are clipped to it, so surfels outside it are culled
    win_x0: int
    win_y0: int
    win_x1: int
    win_y1: int


@wp.struct
class Splat:
    """One surfel projected into one view.

    With camera-space plane rows ``m_x, m_y, m_z`` (coefficients of ``(u, v, 1)``),
    the pixel ray ``r = (r_x, r_y, 1)`` meets the plane at ``(u, v, 1) ∝ p = Q r``
    where ``Q``'s rows are ``q_0, q_1, q_n`` (the columns of ``[m_y×m_z, m_z×m_x,
    m_x×m_y]``); ``p_z = q_n · r`` and the planar hit depth is ``det[m] / p_z``.
    The centre's ray ``r_c`` has ``q_0·r_c = q_1·r_c = 0``, so everything is evaluated
    from the offset ``δ = r − r_c`` (no float32 cancellation for distant splats):
    ``u = q_0·δ / p_z``, ``v = q_1·δ / p_z``, ``p_z = pz0 + q_n·δ``. The projected centre
    is computed in float64 and kept as a float32 pair (``center + center_lo``), so
    the pixel offset stays far below 1e-6 px off even for splats much thinner than a pixel.
    """

    q0: wp.vec3
    q1: wp.vec3
    qn: wp.vec3  # = t_u × t_v in camera space (the scaled normal)
    det: float
    pz0: float  # q_n · r_c = det / depth at the projected centre's ray r_c
    center: wp.vec2  # projected centre, pixels (float32 part) …
    center_lo: wp.vec2  # … plus this remainder: the float64 projection, split
    r2: float  # low-pass cutoff radius, pixels
    depth: float  # planar centre depth (sort key)
    opacity: float
    rho_cut: float  # ρ beyond which α < α_min
    x0: int  # inclusive pixel rectangle; x0 > x1 → nothing
    y0: int
    x1: int
    y1: int


def make_raster_camera(
    w2c: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    near: float,
    window: tuple[int, int, int, int] | None = None,
) -> RasterCamera:
    """The rasterizer's camera; ``window`` = ``(x0, y0, x1, y1)`` half-open pixel box
    (:func:`pixel_window`) to render only that part of the image (None: all of it)."""
    c = RasterCamera()
    c.R = wp.mat33(*np.asarray(w2c[:3, :3], dtype=np.float32).ravel())
    c.t = wp.vec3(*np.asarray(w2c[:3, 3], dtype=np.float32))
    c.center = wp.vec3(*(-(w2c[:3, :3].T @ w2c[:3, 3])).astype(np.float32))
    c.R64 = wp.mat33d(*np.asarray(w2c[:3, :3], dtype=np.float64).ravel())
    c.t64 = wp.vec3d(*np.asarray(w2c[:3, 3], dtype=np.float64))
    c.fx, c.fy, c.cx, c.cy = float(fx), float(fy), float(cx), float(cy)
    c.width, c.height, c.near = int(width), int(height), float(near)
    c.win_x0, c.win_y0, x1, y1 = pixel_window(window, width, height)
    c.win_x1, c.win_y1 = x1 - 1, y1 - 1
    return c


def pixel_window(window, width: int, height: int) -> tuple[int, int, int, int]:
    """``window`` ``(x0, y0, x1, y1)`` (half-open pixels) clipped to a ``width × height``
    image; None → the whole image.

    Raises:
        ValueError: the window holds no pixel of the image.
    """
    if window is None:
        return 0, 0, int(width), int(height)
    x0, y0, x1, y1 = (int(v) for v in window)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, int(width)), min(y1, int(height))
    if x0 >= x1 or y0 >= y1:
        raise ValueError(f"pixel window {tuple(window)} holds no pixel of a {width}x{height} image")
    return x0, y0, x1, y1


# --------------------------------------------------------------------------- funcs
@wp.func
def conic_range(n: wp.vec3, d: wp.vec3, k2: float):
    """Range of ``(n·w)/(d·w)`` over ``w = (u, v, 1)``, ``u² + v² ≤ k2`` (requires
    ``d`` positive on the disc). Returns (centre, half-width) in ratio units.

    Closed form of the two roots of ``(c_n − X c_d)² = k2 |(n − X d)_{uv}|²`` written
    with the 2×2 determinants ``e_a, e_b, f`` so float32 keeps full precision.
    """
    cn = n[2]
    cd = d[2]
    ea = cd * n[0] - cn * d[0]
    eb = cd * n[1] - cn * d[1]
    f = n[0] * d[1] - d[0] * n[1]
    A = cd * cd - k2 * (d[0] * d[0] + d[1] * d[1])
    disc = k2 * (ea * ea + eb * eb) - k2 * k2 * f * f
    mid = cn / cd - k2 * (d[0] * ea + d[1] * eb) / (A * cd)
    hw = wp.sqrt(wp.max(disc, 0.0)) / A
    return mid, hw


@wp.func
def splat_plane_rows(mx: wp.vec3, my: wp.vec3, mz: wp.vec3) -> Splat:
    """A splat whose ray–plane rows are set from the camera-space columns
    ``m* = (t_u*, t_v*, μ*)`` (x, y, z rows of [R t_u | R t_v | R μ + t]): ``q0, q1, qn``
    are the adjugate rows and ``det`` the triple product; all other fields are defaults."""
    c1 = wp.cross(my, mz)
    c2 = wp.cross(mz, mx)
    c3 = wp.cross(mx, my)
    sp = Splat()
    sp.q0 = wp.vec3(c1[0], c2[0], c3[0])
    sp.q1 = wp.vec3(c1[1], c2[1], c3[1])
    sp.qn = wp.vec3(c1[2], c2[2], c3[2])
    sp.det = wp.dot(mz, c3)
    return sp


@wp.func
def plane_hit(sp: Splat, ex: float, ey: float) -> wp.vec2:
    """Exact ray–splat intersection (NOTES "Depth tuple") for the pixel ray with normalised
    offset ``(ex, ey)`` from the projected centre: ``(u² + v², p_z)`` with (u, v) the
    tangent-plane coordinates in units of the scales and ``p_z`` the homogeneous depth
    term (hit depth = ``det / p_z``). Edge-on (``p_z = 0``) gives ``u² + v² = BIG``."""
    pz = sp.pz0 + sp.qn[0] * ex + sp.qn[1] * ey
    rho3 = BIG
    if pz != 0.0:
        u = (sp.q0[0] * ex + sp.q0[1] * ey) / pz
        v = (sp.q1[0] * ex + sp.q1[1] * ey) / pz
        rho3 = u * u + v * v
    return wp.vec2(rho3, pz)


@wp.func
def splat_alpha(
    sp: Splat,
    px: float,
    py: float,
    fx: float,
    fy: float,
    inv_var: float,
    alpha_max: float,
    near: float,
):
    """Opacity and planar depth of splat ``sp`` at pixel centre ``(px, py)`` (focal
    lengths ``fx, fy``). Returns ``(α, z)``; ``α = 0`` when the pixel is beyond the
    cutoff or the hit lies before the near plane."""
    dx = (px - sp.center[0]) - sp.center_lo[0]
    dy = (py - sp.center[1]) - sp.center_lo[1]
    hit = plane_hit(sp, dx / fx, dy / fy)
    rho3 = hit[0]
    pz = hit[1]
    rho2 = (dx * dx + dy * dy) * inv_var
    rho = wp.min(rho3, rho2)
    alpha = float(0.0)
    z = sp.depth
    if rho <= sp.rho_cut:
        if rho3 <= rho2:
            z = sp.det / pz
        if z >= near:
            alpha = wp.min(alpha_max, sp.opacity * wp.exp(-0.5 * rho))
    return alpha, z


@wp.func
def row_span(sp: Splat, py: float, fx: float, fy: float, xa: int, xb: int):
    """Pixel columns of the row through pixel centre ``py`` that can hold ``α ≥ α_min``,
    clipped to ``[xa, xb]`` (conservative; an empty span has first > last).

    The cutoff ellipse: ``(q_0·r)² + (q_1·r)² ≤ ρ_cut (q_n·r)²`` is a quadratic in
    the ray offset ``δ_x`` per row, solved around the projected centre (inside the ellipse)
    with the cancellation-free root formula; the low-pass disc adds a chord of the
    circle of radius ``r2`` around the projected centre; the span is their hull,
    widened by a quarter pixel (plus 1e-4 relative) against float32 rounding.
    """
    lo = float(1.0e9)
    hi = float(-1.0e9)
    k2 = sp.rho_cut
    ey = ((py - sp.center[1]) - sp.center_lo[1]) / fy
    b0 = sp.q0[1] * ey
    b1 = sp.q1[1] * ey
    bn = sp.pz0 + sp.qn[1] * ey
    a0 = sp.q0[0]
    a1 = sp.q1[0]
    an = sp.qn[0]
    A = a0 * a0 + a1 * a1 - k2 * an * an
    B = a0 * b0 + a1 * b1 - k2 * an * bn
    C = b0 * b0 + b1 * b1 - k2 * bn * bn
    disc = B * B - A * C
    if A > 0.0:
        if disc >= -1.0e-5 * (B * B + wp.abs(A * C)):
            # roots of A δ² + 2B δ + C without cancellation: q/A and C/q
            sq = wp.sqrt(wp.max(disc, 0.0))
            q = -B - sq
            if B < 0.0:
                q = -B + sq
            r1 = float(0.0)
            r2 = float(0.0)
            if q != 0.0:
                r1 = q / A
                r2 = C / q
            mg = 1.0e-4 * fx * (wp.abs(r1) + wp.abs(r2))
            lo = sp.center[0] + fx * wp.min(r1, r2) - mg
            hi = sp.center[0] + fx * wp.max(r1, r2) + mg
    else:
        lo = -1.0e9
        hi = 1.0e9
    dy = (py - sp.center[1]) - sp.center_lo[1]
    h2 = sp.r2 * sp.r2 - dy * dy
    if h2 >= 0.0:
        h = wp.sqrt(h2)
        lo = wp.min(lo, sp.center[0] - h)
        hi = wp.max(hi, sp.center[0] + h)
    first = xa
    last = xb
    if hi < lo:
        first = 1
        last = 0
    else:
        lo = wp.clamp(lo - 0.25, -2.0, 1.0e7)
        hi = wp.clamp(hi + 0.25, -2.0, 1.0e7)
        first = wp.max(xa, int(wp.ceil(lo - 0.5)))
        last = wp.min(xb, int(wp.floor(hi - 0.5)))
    return first, last
