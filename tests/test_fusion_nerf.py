"""NeRF fusion kernel (alg:nerf-fusion, alg:nerf-thin): agreement with the NumPy
reference, the exact early-out, and constructed cases on each side of every gate."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.fusion.config import nerf_preset
from divas_engine.fusion.nerf_fusion import NerfFusion, fuse_views_nerf
from divas_engine.fusion.nerf_occupancy import build_nerf_occupancy
from divas_engine.scene import DensityGrid
from tests import fusion_reference as ref
from tests.fusion_cases import axis_camera, const_view, nerf_case

LLFF = nerf_preset("llff")
X0 = np.array([0.0, 0.0, 4.0])


def f32_below(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(-np.inf)))


def f32_above(x: float) -> float:
    return float(np.nextafter(np.float32(x), np.float32(np.inf)))


def nerf_contrib(xc, h, view, cfg, rho=20.0, device=None):
    """(num, den, kind) of one cell of edge ``h`` centred at ``xc`` with density ``rho``."""
    xc = np.asarray(xc, float)
    g = DensityGrid(np.full((1, 1, 1), rho, np.float32), np.stack([xc - h / 2, xc + h / 2]))
    occ = build_nerf_occupancy(g, cfg, device)
    assert len(occ) == 1
    num, den, kind = NerfFusion(occ, cfg).contributions(view)
    return float(num[0]), float(den[0]), int(kind[0])


def test_matches_numpy_reference():
    occ, cfg, views = nerf_case()
    res = fuse_views_nerf(occ, views, cfg)
    c, d = occ.centers(), occ.density.numpy().astype(np.float64)
    r = ref.fuse(
        lambda v: ref.nerf_view(c, d, occ.cell, v, cfg), views, eps=cfg.eps, tau_cons=cfg.tau_cons
    )
    ok = r["margin"] > 1e-5
    assert (~ok).sum() <= 0.01 * len(ok)
    assert r["n_thick"].sum() > 500 and r["n_thin"].sum() > 200
    assert np.array_equal(res.n_thick[ok], r["n_thick"][ok])
    assert np.array_equal(res.n_thin[ok], r["n_thin"][ok])
    assert np.abs(res.P - r["P"])[ok].max() < 1e-5
    assert res.vmask is None


def test_early_out_is_exact():
    occ, cfg, views = nerf_case()
    a, b = NerfFusion(occ, cfg), NerfFusion(occ, replace(cfg, early_out=False))
    for v in views:
        a.add_view(v), b.add_view(v)
    for k, arr in a.accumulators().items():
        assert np.array_equal(arr, b.accumulators()[k]), k


def test_depth_tolerance_with_per_sample_bonus(device):
    cam = axis_camera()
    h = 0.02
    for n, bonus in ((5, 1.0), (100, 10.0)):  # b = min(β n, b_max) = 1, then capped at 10
        tau = (LLFF.gamma + bonus) * h
        for s, kind in ((0.99, 1), (-0.99, 1), (1.01, 0), (-1.01, 0)):
            v = const_view(cam, 4.0 + s * tau, dmin=3.0, dmax=5.0, n=n)
            assert nerf_contrib(X0, h, v, LLFF, device=device)[2] == kind, (n, s)


@pytest.mark.parametrize("off_axis", [False, True])
def test_spatial_tolerance_with_depth_range(off_axis, device):
    """δ to the clamped band must be ≤ Δx π_dg + λ_range (d_max − d_min), in ray depths."""
    h, width = 0.02, 1.0
    tau = h + LLFF.lambda_range * width
    if off_axis:  # pixel (175, 20): cos θ = 0.8, voxel at ray distance 5
        cam, xc, t0, cos = (
            Camera(201, 41, 100.0, 100.0, 100.5, 20.5, np.eye(4)),
            np.array([3.0, 0, 4]),
            5.0,
            0.8,
        )
    else:
        cam, xc, t0, cos = axis_camera(), X0, 4.0, 1.0
    for k, kind in ((0.99, 1), (1.01, 0)):
        hi = t0 - k * tau
        v = const_view(cam, cos * t0, dmin=cos * (hi - width), dmax=cos * hi)
        assert nerf_contrib(xc, h, v, LLFF, device=device)[2] == kind, k


def test_depth_weight(device):
    cam = axis_camera()
    num, den, kind = nerf_contrib(
        X0, 0.02, const_view(cam, 4.0, dmin=3.9, dmax=4.3, mask=0.7), LLFF, device=device
    )
    w = math.exp(-(((4.0 - 4.1) / 0.2) ** 2))
    assert (
        kind == 1 and den == pytest.approx(w, rel=1e-6) and num == pytest.approx(0.7 * w, rel=1e-6)
    )


def _thin_view(cam, centre_mask=0.3, mask=0.9, dexp=4.0, n=0):
    m = np.broadcast_to(np.asarray(mask, np.float32), (cam.height, cam.width)).copy()
    m[20, 20] = centre_mask
    return const_view(cam, dexp, mask=m, n=n)


def test_thin_eligibility_mask_and_density(device):
    cam = axis_camera()
    h = 0.2  # 7×7 footprint
    assert (
        nerf_contrib(X0, h, _thin_view(cam, f32_above(0.1)), LLFF, rho=50.0, device=device)[2] == 2
    )
    assert (
        nerf_contrib(X0, h, _thin_view(cam, 0.1), LLFF, rho=50.0, device=device)[2] == 0
    )  # m > 0.1
    assert (
        nerf_contrib(X0, h, _thin_view(cam, 0.3), LLFF, rho=f32_below(50.0), device=device)[2] == 0
    )  # ρ ≥ ρ_thin


def test_thin_doubled_base_multiplier(device):
    cam = axis_camera()
    cfg = replace(LLFF, gamma=0.5)
    h = 0.2  # thick τ_depth = 0.5·0.2 = 0.1; thin (2γ + b)Δx = 0.2 with n = 0
    for s, kind in ((0.99, 2), (1.01, 0)):
        v = _thin_view(cam, centre_mask=0.9, dexp=4.0 + s * 0.2)
        assert nerf_contrib(X0, h, v, cfg, rho=60.0, device=device)[2] == kind, s
    v = _thin_view(cam, centre_mask=0.9, dexp=4.0 + 0.99 * 0.2, n=3)  # b = 0.6 relaxes further
    assert (
        nerf_contrib(
            X0, h, replace(v, d_ref=v.d_ref + np.float32(0.1)), cfg, rho=60.0, device=device
        )[2]
        == 2
    )


@pytest.mark.parametrize("early_out", [True, False])
def test_thin_coverage_over_footprint(early_out, device):
    cam = axis_camera()
    cfg = replace(LLFF, early_out=early_out)
    pix = [(y, x) for y in range(17, 24) for x in range(17, 24) if (y, x) != (20, 20)]
    for k, kind in ((10, 2), (9, 0)):  # ρ_cover N_pixels = 0.2·49 = 9.8
        m = np.full((41, 41), 0.3, np.float32)
        for p in pix[:k]:
            m[p] = 0.9
        assert (
            nerf_contrib(X0, 0.2, _thin_view(cam, 0.3, m), cfg, rho=60.0, device=device)[2] == kind
        ), k
