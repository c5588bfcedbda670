"""2DGS / NeRF occupancy: Morton codes, the h_v/g rules, the active set against a
NumPy unique/bincount reference, the hash lookup and memory ∝ active voxels."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from divas_engine.fusion import morton
from divas_engine.fusion.config import NERF_PRESETS, GridConfig, nerf_preset
from divas_engine.fusion.nerf_occupancy import build_nerf_occupancy
from divas_engine.fusion.occupancy import (
    build_occupancy,
    grid_geometry,
    resolve_resolution,
    surfel_voxel_codes,
    voxel_codes_numpy,
)
from divas_engine.scene import DensityGrid, SurfelScene
from divas_kernels import occupancy as kocc


def _bitwise_encode(i: int, j: int, k: int) -> int:
    c = 0
    for b in range(21):
        c |= (
            ((i >> b) & 1) << (3 * b)
            | ((j >> b) & 1) << (3 * b + 1)
            | ((k >> b) & 1) << (3 * b + 2)
        )
    return c


@wp.kernel
def _morton_kernel(
    ijk: wp.array(dtype=wp.vec3i), codes: wp.array(dtype=wp.int64), back: wp.array(dtype=wp.vec3i)
):
    t = wp.tid()
    c = kocc.morton_encode3(ijk[t][0], ijk[t][1], ijk[t][2])
    codes[t] = c
    back[t] = kocc.morton_decode3(c)


def test_morton_roundtrip_matches_bitwise_reference(device):
    rng = np.random.default_rng(0)
    ijk = np.r_[
        rng.integers(0, 1 << 21, (300, 3)),
        rng.integers(0, 1024, (300, 3)),
        [[0, 0, 0], [1023, 1023, 1023], [(1 << 21) - 1] * 3, [1, 0, 0], [0, 1, 0], [0, 0, 1]],
    ]
    ref = np.array([_bitwise_encode(*map(int, r)) for r in ijk], dtype=np.int64)
    codes = morton.morton_encode(ijk)
    assert np.array_equal(codes, ref)
    assert np.array_equal(morton.morton_decode(codes), ijk)
    assert codes[ijk.max(1) < 1024].max() < 2**30  # 10 bits per axis → 30-bit codes
    a = wp.array(ijk.astype(np.int32), dtype=wp.vec3i, device=device)
    c = wp.empty(len(ijk), dtype=wp.int64, device=device)
    b = wp.empty(len(ijk), dtype=wp.vec3i, device=device)
    wp.launch(_morton_kernel, len(ijk), [a, c, b], device=device)
    assert np.array_equal(c.numpy(), ref)
    assert np.array_equal(b.numpy(), ijk)
    with pytest.raises(ValueError):
        morton.morton_encode(np.array([[1 << 21, 0, 0]]))


@pytest.mark.parametrize(
    "b,h,gmax,exp_g,exp_h,capped",
    [
        (1.0, 2.0 / 64, 1024, 64, 2.0 / 64, False),  # 2b/h exactly a power of two
        (1.0, 2.0 / 64.5, 1024, 128, 2.0 / 64.5, False),  # just above → next power
        (1.0, 2.0 / 537.6, 1024, 1024, 2.0 / 537.6, False),
        (1.0, 2.0 / 537.6, 512, 512, 2.0 / 512, True),  # capped: h_v = 2b/g
        (1.0, 5.0, 1024, 1, 5.0, False),  # voxel larger than the cube
    ],
)
def test_resolution_rule(b, h, gmax, exp_g, exp_h, capped):
    hh, g, cap = resolve_resolution(b, h, gmax)
    assert (g, cap) == (exp_g, capped)
    assert hh == pytest.approx(exp_h, rel=1e-12)


def _scene(means, scales, opac):
    n = len(means)
    return SurfelScene(
        np.asarray(means, np.float32),
        np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32),
        np.asarray(scales, np.float32),
        np.asarray(opac, np.float32),
        np.zeros((n, 1, 3), np.float32),
        0,
    )


def test_grid_geometry_hand_cases():
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, (20000, 3))
    frame_r = np.percentile(np.linalg.norm(p - np.median(p, 0), axis=1), 99)
    # α_v s̄ dominates: s̄ = 0.02 → h = 0.06 → 2b/h ≈ 35·r → g = 64
    geo = grid_geometry(p, np.full((len(p), 2), 0.02), GridConfig())
    assert geo.r_fg == pytest.approx(frame_r)
    assert geo.half_extent == pytest.approx(1.05 * frame_r)
    assert geo.s_bar == pytest.approx(0.02)
    assert geo.voxel_size == pytest.approx(0.06) and not geo.capped
    assert geo.resolution == 1 << int(np.ceil(np.log2(2 * geo.half_extent / 0.06)))
    # tiny surfels: h = r_fg/256 → 2b/h = 537.6 → g = 1024 uncapped, 512 capped (forward-facing)
    tiny = np.full((len(p), 2), 1e-5)
    geo = grid_geometry(p, tiny, GridConfig())
    assert (geo.resolution, geo.capped) == (1024, False)
    assert geo.voxel_size == pytest.approx(frame_r / 256)
    geo = grid_geometry(p, tiny, GridConfig.forward_facing())
    assert (geo.resolution, geo.capped) == (512, True)
    assert geo.voxel_size == pytest.approx(2 * geo.half_extent / 512)
    # s̄ is the median of max(s1, s2) over the AABB survivors
    sc = np.c_[np.full(len(p), 0.01), np.full(len(p), 0.03)]
    assert grid_geometry(p, sc).s_bar == pytest.approx(0.03)


def _random_scene(n=30000, seed=2):
    rng = np.random.default_rng(seed)
    means = np.r_[
        rng.normal(size=(n - 30, 3)), np.full((10, 3), np.nan), rng.normal(size=(20, 3)) * 50
    ]
    return _scene(means, rng.uniform(0.001, 0.01, (n, 2)), rng.uniform(0.05, 1.0, n))


def test_active_set_matches_numpy_reference(device):
    s = _random_scene()
    grid = build_occupancy(s, GridConfig(), device=device)
    geo = grid.geometry
    codes = voxel_codes_numpy(s.means, geo.center, geo.half_extent, geo.voxel_size, geo.resolution)
    assert np.array_equal(surfel_voxel_codes(s.means, geo, device=device).numpy(), codes)
    assert (codes[-30:-20] == -1).all() and (codes[-20:] == -1).sum() >= 15  # NaN and far floaters
    keep = codes >= 0
    u, inv = np.unique(codes[keep], return_inverse=True)
    dens = np.bincount(inv, weights=s.opacities[keep].astype(np.float64))
    cnt = np.bincount(inv)
    act = dens >= 0.5
    assert np.array_equal(grid.codes.numpy(), u[act])
    assert np.array_equal(grid.density.numpy(), dens[act].astype(np.float32))
    assert np.array_equal(grid.count.numpy(), cnt[act])
    r = grid.report
    assert (r.n_kept, r.n_occupied, r.n_active) == (keep.sum(), len(u), act.sum())
    assert r.surfels_per_active == pytest.approx(cnt[act].sum() / act.sum())
    assert r.active_fraction == pytest.approx(act.sum() / r.g**3)
    assert np.allclose(
        grid.centers(), geo.origin + (morton.morton_decode(u[act]) + 0.5) * geo.voxel_size
    )
    # O(1) lookup: every active code → its index; inactive/absent → −1
    assert np.array_equal(grid.lookup(u[act]), np.arange(act.sum()))
    assert (grid.lookup(np.r_[u[~act], 2**40, -1]) == -1).all()
    sai = grid.surfel_active_index(s.means)
    exp = np.full(len(codes), -1)
    exp[np.flatnonzero(keep)] = np.where(act[inv], np.cumsum(act)[inv] - 1, -1)
    assert np.array_equal(sai, exp)


def test_memory_scales_with_active_voxels(device):
    rng = np.random.default_rng(3)
    # a few thousand tiny surfels on a sphere: g = 1024 (a dense float grid would be 4 GiB)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    s = _scene(p, np.full((4000, 2), 1e-5), np.full(4000, 0.9))
    grid = build_occupancy(s, GridConfig(), device=device)
    r = grid.report
    assert r.g == 1024 and r.n_active > 3000
    assert r.resident_bytes <= 64 * r.n_active + 1024
    assert r.peak_bytes <= 40 * len(s) + 120 * r.n_occupied + 4096
    assert r.build_time_s > 0


def test_empty_and_degenerate_scenes(device):
    with pytest.raises(ValueError):
        build_occupancy(_scene(np.full((3, 3), np.nan), np.ones((3, 2)), np.ones(3)), device=device)
    g = build_occupancy(
        _scene(
            np.random.default_rng(0).normal(size=(50, 3)), np.full((50, 2), 1e-3), np.full(50, 0.1)
        ),
        device=device,
    )
    assert len(g) == 0 and g.report.n_active == 0


def test_nerf_presets_hold_the_paper_table():
    llff, mip = NERF_PRESETS["llff"], NERF_PRESETS["mip360"]
    assert (
        llff.gamma,
        llff.beta,
        llff.b_max,
        llff.lambda_range,
        llff.rho_thresh,
        llff.rho_thin,
        llff.rho_cover,
        llff.grid_resolution,
    ) == (4.0, 0.2, 10, 0.05, 10, 50, 0.20, 128)
    assert (
        mip.gamma,
        mip.beta,
        mip.b_max,
        mip.lambda_range,
        mip.rho_thresh,
        mip.rho_thin,
        mip.rho_cover,
        mip.grid_resolution,
    ) == (0.5, 0.2, 1, 5.0, 5, 30, 0.30, 256)
    for c in (llff, mip):
        assert (c.tau_cw, c.tau_thin, c.tau_cons) == (0.75, 0.6, 0.5)
    assert nerf_preset("llff", gamma=1.0).gamma == 1.0
    with pytest.raises(ValueError):
        nerf_preset("blender")


def test_nerf_occupancy_active_cells(device):
    rng = np.random.default_rng(4)
    dens = rng.exponential(4.0, (6, 5, 7)).astype(np.float32)
    g = DensityGrid(dens, np.array([[0, 0, 0], [7, 5, 3.0]]))
    cfg = nerf_preset("mip360")
    occ = build_nerf_occupancy(g, cfg, device=device)
    lin = np.flatnonzero(dens.ravel() >= cfg.rho_thresh)
    assert np.array_equal(occ.index.numpy(), lin)
    assert np.array_equal(occ.density.numpy(), dens.ravel()[lin])
    iz, iy, ix = np.unravel_index(lin, dens.shape)
    assert np.allclose(occ.centers(), np.c_[ix + 0.5, iy + 0.5, (iz + 0.5) * 0.5])
    assert occ.dx == 1.0 and not occ.report.resolution_matches
    inactive = np.setdiff1d(np.arange(dens.size), lin)[:3]
    assert np.array_equal(occ.lookup(np.r_[lin[3], inactive]), [3, -1, -1, -1])
    dense = occ.to_dense(np.arange(len(lin), dtype=np.float32) + 1)
    assert np.array_equal(np.flatnonzero(dense.ravel()), lin)
