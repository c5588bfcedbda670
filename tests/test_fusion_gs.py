"""2DGS fusion kernel (alg:gs-fusion, alg:gs-thin): agreement with the NumPy reference,
the exact early-out, integral images, and one constructed case per gate on each side
of its threshold."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from divas_engine.camera import Camera
from divas_engine.fusion.config import GridConfig, GsFusionConfig
from divas_engine.fusion.gs_fusion import GsFusion, fuse_views_gs
from divas_engine.fusion.occupancy import build_occupancy
from divas_engine.fusion.state import FusionCapacityError
from divas_kernels.fusion_common import depth_gradient_factor
from divas_kernels.integral_image import integral_images, integral_images_numpy
from tests import fusion_reference as ref
from tests.fusion_cases import (
    axis_camera,
    checker,
    const_view,
    gs_contrib,
    one_voxel_grid,
    random_views,
    sphere_floor_scene,
)

CFG = GsFusionConfig()
THICK = GsFusionConfig(rho_thin=10.0)  # thin path off (active density 1 < 10)
H = 0.2  # voxel edge of the constructed cases; voxel at (0,0,4) covers a 7×7 footprint
X0 = np.array([0.0, 0.0, 4.0])


def f32_below(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(-np.inf)))


def f32_above(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(np.inf)))


@pytest.fixture(scope="module")
def sphere_case(device):
    grid = build_occupancy(sphere_floor_scene(), GridConfig(), device=device)
    return grid, random_views(6)


# --- agreement with the reference --------------------------------------------------------
def test_matches_numpy_reference(sphere_case):
    grid, views = sphere_case
    res = fuse_views_gs(grid, views, CFG)
    c, d, h = grid.centers(), grid.density.numpy().astype(np.float64), grid.geometry.voxel_size
    r = ref.fuse(lambda v: ref.gs_view(c, d, h, v, CFG), views, eps=CFG.eps, tau_cons=CFG.tau_cons)
    ok = r["margin"] > 1e-5  # knife-edge ties between float32 and float64 excluded
    assert (~ok).sum() <= 0.01 * len(ok)
    assert r["n_thick"].sum() > 300 and r["n_thin"].sum() > 50  # both paths exercised
    assert np.array_equal(res.n_thick[ok], r["n_thick"][ok])
    assert np.array_equal(res.n_thin[ok], r["n_thin"][ok])
    assert np.array_equal(res.vmask_raw[ok], r["vmask"][ok])
    assert np.abs(res.P - r["P"])[ok].max() < 1e-5
    assert np.array_equal(res.segmented[ok], r["segmented"][ok])
    seg = CFG.tau_cons <= res.P
    assert np.array_equal(res.vmask[seg], res.vmask_raw[seg]) and not res.vmask[~seg].any()


def test_early_out_is_exact(sphere_case):
    grid, views = sphere_case
    a = GsFusion(grid, CFG)
    b = GsFusion(grid, replace(CFG, early_out=False))
    for i, v in enumerate(views):
        a.add_view(v, i), b.add_view(v, i)
    for k, arr in a.accumulators().items():
        assert np.array_equal(arr, b.accumulators()[k]), k


def test_integral_images_and_depth_gradient(device):
    rng = np.random.default_rng(5)
    n = rng.integers(0, 300, (37, 53)).astype(np.int32)
    m = rng.random((37, 53)).astype(np.float32)
    sats = integral_images(
        wp.array(n, dtype=wp.int32, device=device), wp.array(m, dtype=float, device=device), 0.5
    )
    for got, exp in zip(sats, integral_images_numpy(n, m, 0.5)):
        assert np.array_equal(got.numpy(), exp)
    v = random_views(1, seed=9)[0]
    pdg = depth_gradient_factor(
        *(wp.array(a, dtype=float, device=device) for a in (v.d_min, v.d_ref, v.d_max)), 400.0, 1e-6
    ).numpy()
    assert np.allclose(pdg, ref.depth_gradient(v, 400.0, 1e-6), atol=2e-6)


# --- gates (one voxel, one view) -------------------------------------------------------
def test_thick_entry_mask_threshold():
    cam = axis_camera()
    assert gs_contrib(X0, H, const_view(cam, 4.0, mask=0.5), THICK)[2] == 1
    assert gs_contrib(X0, H, const_view(cam, 4.0, mask=f32_below(0.5)), THICK)[2] == 0


def test_planar_to_ray():
    """Off-axis pixel (cos θ = 0.8): δ = t₀ − d_med/cos θ must be ≤ h_v."""
    cam = Camera(201, 41, 100.0, 100.0, 100.5, 20.5, np.eye(4))
    xc = np.array([3.0, 0.0, 4.0])  # on the ray through pixel (175, 20), t₀ = 5
    for k, kind in ((0.99, 1), (1.01, 0)):
        dmed = 0.8 * (5.0 - k * H)
        assert gs_contrib(xc, H, const_view(cam, dmed), THICK)[2] == kind, k
    # with a planar depth read as a ray depth the voxel would be 0.8 behind: rejected
    assert gs_contrib(xc, H, const_view(cam, 5.0 - 0.99 * H), THICK)[2] == 0


def _layer_view(cam, centre_n, pattern=(3, 7), d_cam=4.0):
    n = checker((cam.height, cam.width), *pattern)
    n[20, 20] = centre_n
    # front hit just in front of the voxel, median far behind it (not see-through)
    return const_view(cam, 4.8, dmin=4.0 - 0.03, dmax=4.9, n=n, d_cam=d_cam), n


def test_layered_switches_to_front_hit():
    cam = axis_camera()
    _, n = _layer_view(cam, 0)
    box = n[17:24, 17:24].astype(np.int64)
    s1, s2 = box.sum() - box[3, 3], (box**2).sum() - box[3, 3] ** 2
    c_star = next(
        c
        for c in range(200)
        if ref.layered_exact(
            np.array([c]), np.array([49]), np.array([s1 + c]), np.array([s2 + c * c])
        )[0]
    )
    assert c_star > 7
    assert gs_contrib(X0, H, _layer_view(cam, c_star - 1)[0], THICK)[2] == 0
    assert gs_contrib(X0, H, _layer_view(cam, c_star)[0], THICK)[2] == 1


def test_see_through_switches_to_front_hit():
    cam = axis_camera()
    mk = lambda d_cam: const_view(cam, 6.0, dmin=4.0 - 0.03, dmax=6.1, d_cam=d_cam)  # noqa: E731
    assert gs_contrib(X0, H, mk(6.0 / 1.5 * 0.99), THICK)[2] == 1  # d_med > γ_ST d_cam
    assert gs_contrib(X0, H, mk(6.0 / 1.5 * 1.01), THICK)[2] == 0


def test_untrusted_front_hit_skips_thick_vote():
    cam = axis_camera()
    assert gs_contrib(X0, H, const_view(cam, 4.0, dmin=4.0, dmax=4.02), THICK)[2] == 1
    assert gs_contrib(X0, H, const_view(cam, 4.0, dmin=f32_above(4.0), dmax=4.02), THICK)[2] == 0


def test_asymmetric_depth_gate():
    cam = axis_camera()
    narrow = replace(THICK, gamma=0.5)  # t_depth = 0.1 < spatial tolerance h_v = 0.2
    tol = 0.5 * H

    def front(s):  # see-through → one-sided gate on d_min; voxel at d_min + s
        return gs_contrib(X0, H, const_view(cam, 6.5, dmin=4.0 - s, dmax=6.6, d_cam=4.0), narrow)[2]

    assert front(0.99 * tol) == 1 and front(1.01 * tol) == 0
    assert front(-1.5 * tol) == 1  # far in front of d_min: one-sided passes (|·| would not)

    def median(s):  # not front → two-sided gate on d_med; surface at voxel + s
        return gs_contrib(X0, H, const_view(cam, 4.0 + s), narrow)[2]

    for sign in (1, -1):
        assert median(sign * 0.99 * tol) == 1 and median(sign * 1.01 * tol) == 0


def test_tolerance_tightening():
    cam = axis_camera()
    n = checker((41, 41), 10, 0)
    box = n[17:24, 17:24]
    assert (
        n[20, 20] == 10
        and not ref.layered_exact(
            np.array([10]), np.array([49]), np.array([box.sum()]), np.array([(box**2).sum()])
        )[0]
    )
    e = 10 - box.mean()
    tol = H / (1 + CFG.beta * e)
    assert tol < 0.9 * H
    mk = lambda s: const_view(cam, 4.0 + s, n=n)  # noqa: E731
    assert gs_contrib(X0, H, mk(0.99 * tol), THICK)[2] == 1
    assert gs_contrib(X0, H, mk(1.01 * tol), THICK)[2] == 0
    assert gs_contrib(X0, H, const_view(cam, 4.0 + 0.9 * H), THICK)[2] == 1  # untightened


def test_spatial_gate_with_depth_gradient():
    cam = axis_camera()
    g = 0.02
    ramp = (np.arange(41) - 20) * g * 4.0
    pi = math.exp(-400.0 * g * g)  # App. D: relative central difference = g
    mk = lambda: const_view(cam, 4.0, dmin=3.99 + ramp[None, :], dmax=4.01 + ramp[None, :])  # noqa: E731
    v = mk()
    for k, kind in ((0.99, 1), (1.01, 0)):
        xc = np.array([0.0, 0.0, 4.0 + k * H * pi])  # δ = x_d − d_med on the axis
        assert gs_contrib(xc, H, v, THICK)[2] == kind, k


def test_depth_weight_and_compact_fusion():
    cam = axis_camera()
    v = const_view(cam, 4.0, dmin=3.9, dmax=4.3, mask=0.8)
    num, den, kind = gs_contrib(X0, H, v, THICK)
    w = math.exp(-1.0 * ((4.0 - 4.1) / 0.2) ** 2)  # t̂ = 4, d_ctr = 4.1, d_hw = 0.2
    assert (
        kind == 1 and den == pytest.approx(w, rel=1e-6) and num == pytest.approx(0.8 * w, rel=1e-6)
    )
    thin = const_view(cam, 4.28, dmin=4.279, dmax=4.29, mask=0.9)  # δ = 0.28 > h_v: thick fails
    tv = gs_contrib(X0, H, thin, replace(CFG, gamma=2.0))
    assert tv[2] == 2 and tv[0] == pytest.approx(0.9) and tv[1] == 1.0
    f = GsFusion(one_voxel_grid(X0, H), replace(CFG, gamma=2.0))
    f.add_view(v), f.add_view(thin)
    r = f.result()
    assert r.P[0] == pytest.approx((0.8 * w + 0.9) / (w + 1.0), rel=1e-6)
    assert (r.n_thick[0], r.n_thin[0], int(r.vmask[0, 0])) == (1, 1, 0b11)


@pytest.mark.parametrize("dmax", [4.0 - 1e-4, 3.9995, 4.0])
def test_depth_weight_on_non_monotone_tuple(dmax):
    """2DGS tuples are per-primitive hits and not monotone: D_max a hair before D_min (or
    D_med) must not zero an accepted thick vote. Segment = [d_min, max(d_max, d_ref)]:
    here [4, 4] (width 0 → ε floor, t̂ = 4 at its centre) → w = 1."""
    cam = axis_camera()
    v = const_view(cam, 4.0, dmin=4.0, dmax=dmax, mask=0.8)
    num, den, kind = gs_contrib(X0, H, v, THICK)
    assert kind == 1 and den == pytest.approx(1.0) and num == pytest.approx(0.8)
    # D_max before D_med but after D_min: segment [3.9, 4.0], t̂ = 4 at its edge → e⁻¹
    v = const_view(cam, 4.0, dmin=3.9, dmax=3.95, mask=0.8)
    num, den, kind = gs_contrib(X0, H, v, THICK)
    assert kind == 1 and den == pytest.approx(math.exp(-1.0), rel=1e-6)
    f = GsFusion(one_voxel_grid(X0, H), THICK)
    f.add_view(const_view(cam, 4.0, dmin=4.0, dmax=dmax, mask=0.8))
    assert f.result().P[0] == pytest.approx(0.8, rel=1e-6) and f.result().segmented[0]


def _thin_view(cam, centre, valid=None, mask=0.9, dmed=4.0, d_cam=4.0):
    """Centre pixel: (d_med, mask) tuple; other pixels d_med / mask, invalid where ~valid."""
    dm = np.full((cam.height, cam.width), dmed, np.float32)
    mk = np.broadcast_to(np.asarray(mask, np.float32), dm.shape).copy()
    if valid is not None:
        dm[~valid] = 0.0
    dm[20, 20], mk[20, 20] = centre
    return const_view(
        cam,
        dm,
        dmin=np.where(dm > 0, dm - 0.001, 0),
        dmax=np.where(dm > 0, dm + 0.002, 0),
        mask=mk,
        d_cam=d_cam,
    )


def test_behind_surface_gate():
    cam = axis_camera()
    for k, kind in ((1.98, 2), (2.02, 0)):
        assert gs_contrib(X0, H, _thin_view(cam, (4.0 - k * H, 0.3)), CFG)[2] == kind, k
    # see-through centre: the gate uses the trusted front hit d_min
    for k, kind in ((1.98, 2), (2.02, 0)):
        v = _thin_view(cam, (7.0, 0.3))
        v.d_min[20, 20] = 4.0 - k * H
        assert gs_contrib(X0, H, v, CFG)[2] == kind, k


@pytest.mark.parametrize("early_out", [True, False])
@pytest.mark.parametrize("h,n_min", [(H, 25), (0.6, 29)])  # n_abs, then ⌈ρ_occ A_B⌉ (A_B = 289)
def test_thin_n_min_floor(early_out, h, n_min):
    cam = axis_camera()
    cfg = replace(CFG, early_out=early_out)
    rng = np.random.default_rng(0)
    lo, hi = (17, 24) if h == H else (12, 29)
    pix = [(y, x) for y in range(lo, hi) for x in range(lo, hi) if (y, x) != (20, 20)]
    order = [(20, 21), (21, 20)] + [
        p for p in (pix[i] for i in rng.permutation(len(pix))) if p not in ((20, 21), (21, 20))
    ]
    for k, kind in ((n_min, 2), (n_min - 1, 0)):
        valid = np.zeros((41, 41), bool)
        for p in order[:k]:
            valid[p] = True
        assert gs_contrib(X0, h, _thin_view(cam, (0.0, 0.3), valid), cfg)[2] == kind, k


@pytest.mark.parametrize("early_out", [True, False])
def test_thin_coverage_over_depth_support(early_out):
    cam = axis_camera()
    cfg = replace(CFG, early_out=early_out)
    idx = [(20, 21)] + [
        (y, x) for y in range(17, 24) for x in range(17, 24) if (y, x) not in ((20, 20), (20, 21))
    ]
    valid = np.zeros((41, 41), bool)
    for p in idx[:30]:  # 30 depth-consistent pixels, the rest have no surface
        valid[p] = True
    for m_pos, kind in ((15, 2), (14, 0)):  # p_covered = 15/30 = ρ_cover vs 14/30
        mask = np.full((41, 41), 0.2, np.float32)
        for p in idx[:m_pos]:
            mask[p] = 0.9
        assert gs_contrib(X0, H, _thin_view(cam, (0.0, 0.3), valid, mask=mask), cfg)[2] == kind


@pytest.mark.parametrize("early_out", [True, False])
def test_thin_gate_ignores_see_through_background(early_out):
    """alg:gs-thin's per-pixel gate is one-sided only on *layered* pixels (the algorithm
    has no γ_ST / d_cam input): a far see-through background behind a thin stem is not
    depth support, so it cannot dilute p_covered (eq:gs-coverage)."""
    cam = axis_camera()
    cfg = replace(CFG, early_out=early_out)
    h = 0.6  # footprint 17×17 = 289 px, n_min = ⌈0.1·289⌉ = 29
    dmed = np.full((41, 41), 20.0, np.float32)  # background: 20 > γ_ST·d_cam = 6
    mask = np.full((41, 41), 0.1, np.float32)
    dmed[12:29, 18:21] = 4.0  # a 3-px stem at the voxel's depth, 51 px
    mask[12:29, 18:21] = 0.9
    dmed[20, 20], mask[20, 20] = 20.0, 0.1  # the centre pixel misses it: thin path
    v = const_view(cam, dmed, mask=mask)
    num, den, kind = gs_contrib(X0, h, v, cfg)
    assert kind == 2 and num == pytest.approx(0.9)  # n_depth = 50, p_covered = 1
    # the reference agrees
    r = ref.gs_view(X0[None], np.array([1.0]), h, v, cfg)
    assert int(r[2][0]) == 2


def test_thin_distance_gate():
    cam = axis_camera()
    cfg = replace(CFG, gamma=2.0)  # depth-consistent up to 2 h_v; the gate is 1.5 h_v
    for k, kind in ((0.99, 2), (1.01, 0)):
        dz = k * 1.5 * H  # the centre pixel unprojects dz behind the voxel (thick: δ > h_v)
        assert (
            gs_contrib(X0, H, const_view(cam, 4.0 + dz, dmin=4.0 + dz - 0.001), cfg)[2] == kind
        ), k


def test_thin_acceptance_and_mask_positive():
    cam = axis_camera()
    assert gs_contrib(X0, H, _thin_view(cam, (4.0, 0.3), mask=0.6), CFG)[2] == 2  # t = τ_thin
    assert gs_contrib(X0, H, _thin_view(cam, (4.0, 0.3), mask=f32_below(0.6)), CFG)[2] == 0
    loose = replace(CFG, tau_thin=0.5)
    assert gs_contrib(X0, H, _thin_view(cam, (4.0, 0.3), mask=f32_above(0.5)), loose)[2] == 2
    assert gs_contrib(X0, H, _thin_view(cam, (4.0, 0.3), mask=0.5), loose)[2] == 0  # m > 0.5


def test_gs_view_needs_d_cam():
    with pytest.raises(ValueError, match="d_cam"):
        gs_contrib(X0, H, const_view(axis_camera(), 4.0, d_cam=0.0), CFG)


def test_view_bitmask_capacity():
    cam = axis_camera(9, 9, 10.0)
    f = GsFusion(one_voxel_grid(X0, H), CFG)
    v = const_view(cam, 4.0)
    for i in range(64):
        assert f.add_view(v) == i
    with pytest.raises(FusionCapacityError):
        f.add_view(v)
    assert int(f.result().vmask_raw[0, 1]) == 0xFFFFFFFF
    f.remove_view(40)
    assert f.add_view(v) == 40
    with pytest.raises(ValueError):
        f.add_view(v, 40)
    with pytest.raises(KeyError):
        GsFusion(one_voxel_grid(X0, H), CFG).remove_view(3)
