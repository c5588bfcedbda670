"""2DGS voxel-to-surfel mapping (Sec. 3.6, alg:vox2surfel): Warp against the NumPy
reference on random cases, the monotone chain, and hand-built cases per pass."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.fusion import FusionResult, FusionView, GridConfig, GsFusion, build_occupancy
from divas_engine.fusion.morton import morton_encode
from divas_engine.fusion.occupancy import GridGeometry, OccupancyGrid, voxel_codes_numpy
from divas_engine.mapping import MappingConfig, SurfelMapper, map_to_surfels
from divas_engine.scene import SurfelScene
from tests.fusion_cases import random_views, sphere_floor_scene
from tests.mapping_reference import map_reference


# --------------------------------------------------------------------------- helpers
def _scene(means, scales, quats=None, opac=0.8) -> SurfelScene:
    means = np.asarray(means, dtype=np.float32).reshape(-1, 3)
    n = len(means)
    q = np.tile([1.0, 0, 0, 0], (n, 1)) if quats is None else np.asarray(quats)
    return SurfelScene(
        means,
        q.astype(np.float32),
        np.asarray(scales, dtype=np.float32).reshape(n, 2),
        np.full(n, opac, np.float32),
        np.zeros((n, 1, 3), np.float32),
        0,
    )


def _fused(segmented, vmask) -> FusionResult:
    seg = np.asarray(segmented, dtype=bool)
    a = len(seg)
    vm = np.asarray(vmask, dtype=np.uint32).reshape(a, -1)
    z = np.zeros(a)
    return FusionResult(
        P=seg.astype(np.float64),
        segmented=seg,
        vmask=vm * seg[:, None],
        vmask_raw=vm,
        W=z,
        Z=z,
        W_thin=z,
        n_thick=np.zeros(a, np.int32),
        n_thin=np.zeros(a, np.int32),
    )


def _view(cam: Camera, mask) -> FusionView:
    z = np.zeros((cam.height, cam.width), np.float32)
    return FusionView(cam, np.asarray(mask, dtype=np.float32), z, z, z, z)


def _random_rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q


def _random_case(seed: int, device):
    """Surfels on a unit sphere (random orientations, anisotropic, 1 % needles, a few
    NaN / outside-AABB), a synthetic fusion state and 3 views with smooth masks."""
    rng = np.random.default_rng(seed)
    n = 3000
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p *= rng.uniform(0.9, 1.1, (n, 1))
    p[:5] = np.nan
    p[5:15] *= 5.0  # beyond the P99 cube
    s = np.exp(rng.normal(np.log(0.05), 0.4, (n, 2)))
    s[15:60, 0] *= rng.uniform(5, 60, 45)  # needles
    sc = _scene(p, s, _random_rotations(rng, n))
    grid = build_occupancy(sc, GridConfig(g_max=64), device=device)
    a = len(grid)
    seg = rng.random(a) < 0.7
    vm = rng.integers(0, 2**32, (a, 2), dtype=np.uint64).astype(np.uint32)
    views, slots = [], [0, 7, 38]
    for k in range(3):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        cam = Camera.look_at(
            d * 3.0,
            rng.normal(scale=0.2, size=3),
            np.array([0, 0, 1.0]),
            width=96,
            height=72,
            fx=rng.uniform(80, 160),
        )
        yy, xx = np.mgrid[0:72, 0:96]
        m = 0.5 + 0.5 * np.sin(xx / rng.uniform(3, 9) + k) * np.cos(yy / rng.uniform(3, 9))
        views.append(_view(cam, np.clip(m, 0, 1)))
    return sc, grid, _fused(seg, vm), views, slots


def _compare(res, ref, mapper=None, fused=None, views=(), slots=()):
    """Warp result == reference (exact on every surfel the reference does not flag as
    within rounding of a threshold; the cases used here have none that differ)."""
    amb = ref["ambiguous"]
    assert amb.mean() < 0.05
    assert np.array_equal(res.pass1, ref["pass1"])
    assert np.array_equal(res.pass2, ref["pass2"])
    assert res.tau_a == pytest.approx(ref["tau_a"], rel=1e-12)
    assert res.n_needles == ref["n_needles"]
    ok = ~amb
    assert np.array_equal(res.selected[ok], ref["selected"][ok])
    assert np.abs(res.kappa[ok] - ref["kappa"][ok]).max(initial=0) <= 1e-6
    assert res.scored_per_view == [int(x) for x in ref["scored"].sum(1)]
    # in practice nothing differs at all
    assert np.array_equal(res.selected, ref["selected"])
    assert res.n_selected == int(ref["selected"].sum())
    for i, (v, s) in enumerate(zip(views, slots)):
        tot, pos, scored = mapper.view_counts(fused, v, s)
        assert np.array_equal(scored, ref["scored"][i])
        assert np.array_equal(tot[ok], ref["total_fp"][i][ok])
        assert np.array_equal(pos[ok], ref["mask_fp"][i][ok])


# --------------------------------------------------------------------------- reference
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_numpy_reference_random(seed, device):
    sc, grid, fused, views, slots = _random_case(seed, device=device)
    mapper = SurfelMapper(sc, grid, device=device)
    res = mapper.map(fused, views, slots)
    ref = map_reference(
        sc, grid.geometry, grid.codes.numpy(), fused.segmented, fused.vmask, views, slots
    )
    assert res.n_pass1 > 500 and res.n_scored > 500
    assert 0 < res.n_selected < res.n_pass2  # Pass 3 culls some, keeps some
    assert ref["total_fp"].sum() > 5000
    _compare(res, ref, mapper, fused, views, slots)
    # monotone chain f¹ ⪰ f² ⪰ f
    assert not (res.pass2 & ~res.pass1).any()
    assert not (res.selected & ~res.pass2).any()
    assert res.n_pass1 >= res.n_pass2 >= res.n_selected


def test_matches_reference_with_real_fusion(device):
    """GsFusion state and slots (view ids) fed straight in; a view undone mid-way."""
    sc = sphere_floor_scene(4000, seed=3, scale=0.03)
    grid = build_occupancy(sc, GridConfig(g_max=64), device=device)
    views = random_views(4, seed=5)
    fusion = GsFusion(grid)
    ids = [fusion.add_view(v) for v in views]
    fusion.remove_view(ids[1])
    live = [views[i] for i in (0, 2, 3)]
    slots = [ids[i] for i in (0, 2, 3)]
    fused = fusion.result()
    mapper = SurfelMapper(sc, grid, device=device)
    res = mapper.map(fused, live, slots)
    ref = map_reference(
        sc, grid.geometry, grid.codes.numpy(), fused.segmented, fused.vmask, live, slots
    )
    assert res.n_pass1 > 100 and res.n_selected > 50
    _compare(res, ref, mapper, fused, live, slots)


def test_early_out_is_exact_and_rerun_is_stable(device):
    sc, grid, fused, views, slots = _random_case(2, device=device)
    mapper = SurfelMapper(sc, grid, device=device)
    a = mapper.map(fused, views, slots)
    b = mapper.map(fused, views, slots, MappingConfig(early_out=False))
    assert np.array_equal(a.kappa, b.kappa) and np.array_equal(a.selected, b.selected)
    # a changed fusion state and view set on the same mapper (per-update re-run)
    seg2 = fused.segmented.copy()
    seg2[::3] = False
    f2 = _fused(seg2, fused.vmask_raw)
    c = mapper.map(f2, views[:2], slots[:2])
    d = map_to_surfels(sc, grid, f2, views[:2], slots[:2], device=device)
    assert np.array_equal(c.selected, d.selected) and np.array_equal(c.kappa, d.kappa)
    e = mapper.map(fused, views, slots)
    assert np.array_equal(e.selected, a.selected) and np.array_equal(e.kappa, a.kappa)


def test_ablation_switches(device):
    sc, grid, fused, views, slots = _random_case(0, device=device)
    mapper = SurfelMapper(sc, grid, device=device)
    r = mapper.map(fused, views, slots, MappingConfig(needle_filter=False, coverage_filter=False))
    assert np.array_equal(r.pass2, r.pass1) and np.array_equal(r.selected, r.pass1)
    r = mapper.map(fused, views, slots, MappingConfig(coverage_filter=False))
    assert np.array_equal(r.selected, r.pass2) and r.n_pass2 < r.n_pass1
    r0 = mapper.map(fused, views, slots)
    r = mapper.map(fused, views, slots, MappingConfig(surfel_coverage=0.0))
    assert np.array_equal(r.selected, r.pass2) and np.array_equal(r.kappa, r0.kappa)


# --------------------------------------------------------------------------- Pass 1
def _hand_grid(codes, center=(0.0, 0.0, 0.0), half=1.0, g=8, device=None):
    geo = GridGeometry(
        np.asarray(center, dtype=np.float64), half, 2 * half / g, g, half, 0.01, False
    )
    codes = np.asarray(codes, dtype=np.int64)
    return OccupancyGrid.from_codes(geo, codes, np.ones(len(codes)), device=device)


def test_pass1_admits_exactly_segmented_voxels(device):
    h = 0.25  # g = 8 over [-1, 1)³
    vc = lambda i, j, k: [-1 + (i + 0.5) * h, -1 + (j + 0.5) * h, -1 + (k + 0.5) * h]  # noqa
    seg_vox, bg_vox = (1, 2, 3), (4, 4, 4)
    means = [
        vc(*seg_vox),  # 0: segmented voxel → in
        vc(*bg_vox),  # 1: active, not segmented → out
        vc(5, 5, 5),  # 2: inactive voxel → out
        [np.nan, 0, 0],  # 3: NaN → out
        [1.5, 0, 0],  # 4: outside the cube → out
        [1.0, 0, 0],  # 5: on the +b face (|μ−c| ≥ b) → out
        [-0.999, -0.5 + 1e-3, -0.25 + 1e-3],  # 6: corner of voxel (0,2,3) → in
        np.add(vc(*seg_vox), 0.12),
    ]  # 7: same voxel, off-centre → in
    codes = morton_encode(np.array([seg_vox, bg_vox, (0, 2, 3)]))
    grid = _hand_grid(codes, device=device)
    sc = _scene(means, np.full((len(means), 2), 0.01))
    gc = grid.codes.numpy()  # the fusion state is in active-index (ascending code) order
    fused = _fused(gc != codes[1], np.zeros((3, 2), np.uint32))
    res = map_to_surfels(sc, grid, fused, [], [], device=device)
    assert res.pass1.tolist() == [True, False, False, False, False, False, True, True]
    assert voxel_codes_numpy(sc.means, grid.geometry.center, 1.0, h, 8)[6] == codes[2]
    assert np.array_equal(res.pass2, res.pass1)  # aspect 1 everywhere: no needle
    assert not res.selected.any()  # no view: κ = 0


# --------------------------------------------------------------------------- Pass 2
def test_pass2_culls_exactly_top_percent_of_all_surfels(device):
    rng = np.random.default_rng(0)
    k = rng.permutation(np.arange(1, 201))  # aspects 1 … 200, shuffled
    n = len(k)
    means = np.zeros((n, 3)) + 0.05
    scales = np.c_[k * 0.01, np.full(n, 0.01)]
    grid = _hand_grid(morton_encode(np.array([[4, 4, 4]])), device=device)
    sc = _scene(means, scales)
    res = map_to_surfels(sc, grid, _fused([True], np.zeros((1, 2))), [], [], device=device)
    assert res.pass1.all()
    assert res.tau_a == pytest.approx(198.01, rel=1e-5)  # P99 of 1 … 200 (linear)
    assert set(np.nonzero(~res.pass2)[0]) == set(np.nonzero(k >= 199)[0])
    assert res.n_needles == 2 and res.n_pass2 == 198


def test_pass2_threshold_is_over_all_surfels_not_admitted_ones(device):
    k = np.arange(1, 101)  # aspects 1 … 100; only 1 … 50 are admitted by Pass 1
    means = np.where((k <= 50)[:, None], 0.05, -0.55) * np.ones((100, 3))
    grid = _hand_grid(morton_encode(np.array([[4, 4, 4], [1, 1, 1]])), device=device)
    sc = _scene(means, np.c_[k * 0.01, np.full(100, 0.01)])
    seg = grid.codes.numpy() == morton_encode(np.array([[4, 4, 4]]))[0]
    res = map_to_surfels(sc, grid, _fused(seg, np.zeros((2, 2))), [], [], device=device)
    assert res.tau_a == pytest.approx(99.01, rel=1e-5)
    assert res.n_pass1 == 50 and res.n_pass2 == 50  # P99 of the admitted would cull #50
    assert res.n_needles == 1


# --------------------------------------------------------------------------- Pass 3
F = 100.0  # 1 px = 0.01 world units at depth 1


def _axis_cam() -> Camera:
    # pixel (20, 20) is centred on the optical axis; (x, y) ↔ world ((x−20)/100, (y−20)/100)
    return Camera(40, 40, F, F, 20.5, 20.5, np.eye(4), "axis")


def _px(x, y):
    return [(x - 20) / F, (y - 20) / F, 1.0]


def _pass3_case(device):
    """P (10,10) on the mask, Q (30,10) off it, C (10,30) on the view-0 mask but its voxel
    lacks bit 0, D (30,30) partly covered in both views, N (20,20) a 45° needle.
    All surfels face the camera; a 3.4 × 1.6 px (1σ) surfel has a 7 × 3 box."""
    cam = _axis_cam()
    yy, xx = np.mgrid[0:40, 0:40]
    m0 = (xx < 20) | ((yy >= 25) & (xx <= 28))  # D: columns 27, 28 of 27…33 → 6/21
    m1 = (yy >= 25) & (xx >= 27) & (xx <= 30)  # D: 12/21; C, P, Q: 0
    views = [_view(cam, np.where(m0, 0.9, 0.1)), _view(cam, np.where(m1, 0.7, 0.3))]
    slots = [0, 3]
    s = [0.034, 0.016]
    c45, s45 = np.cos(np.pi / 8), np.sin(np.pi / 8)
    means = [_px(10, 10), _px(30, 10), _px(10, 30), _px(30, 30), _px(20, 20)]
    scales = [s, s, s, s, [0.034 * np.sqrt(2), 0.005]]
    quats = [[1, 0, 0, 0]] * 4 + [[c45, 0, 0, s45]]
    sc = _scene(means, scales, np.array(quats))
    geo_center = (0.0, 0.0, 1.0)
    codes = voxel_codes_numpy(sc.means, np.array(geo_center), 1.0, 0.25, 8)
    assert len(set(codes[:4].tolist())) == 4 and codes[4] == codes[3]
    grid = _hand_grid(np.unique(codes), center=geo_center, device=device)
    gc = grid.codes.numpy()
    vm = np.full((len(gc), 1), 0b1001, np.uint32)  # bits 0 and 3
    vm[gc == codes[2]] = 0b1000  # C: only view 1 (slot 3) voted
    fused = _fused(np.ones(len(gc), bool), vm)
    return sc, grid, fused, views, slots


def test_pass3_hand_case(device):
    sc, grid, fused, views, slots = _pass3_case(device=device)
    cfg = MappingConfig(needle_filter=False)  # 5 surfels: P99 would cull the needle N
    mapper = SurfelMapper(sc, grid, cfg, device=device)
    res = mapper.map(fused, views, slots)
    assert res.pass2.all()
    P, Q, C, D, N = range(5)
    tot0, pos0, sc0 = mapper.view_counts(fused, views[0], 0)
    tot1, pos1, sc1 = mapper.view_counts(fused, views[1], 3)
    # P: core on the mask in view 0 → κ = 1, kept
    assert (tot0[P], pos0[P]) == (21, 21) and res.kappa[P] == 1.0 and res.selected[P]
    # Q: core off the mask in both views → κ = 0, culled
    assert (tot0[Q], pos0[Q]) == (21, 0) and res.kappa[Q] == 0.0 and not res.selected[Q]
    # C: fully on the view-0 mask, but its voxel has no bit 0 → not scored there;
    # scored in view 1, where it is off the mask → κ = 0, culled
    assert not sc0[C] and tot0[C] == 0 and sc1[C] and (tot1[C], pos1[C]) == (21, 0)
    assert res.kappa[C] == 0.0 and not res.selected[C]
    # D: κ_0 = 6/21, κ_1 = 12/21 → κ = max = 12/21 ≥ ½, kept
    assert (tot0[D], pos0[D]) == (21, 6) and (tot1[D], pos1[D]) == (21, 12)
    assert res.kappa[D] == pytest.approx(12 / 21, abs=1e-7) and res.selected[D]
    # N: 45° needle, 1σ box 7 × 7 = 49 pixels, 29 inside the 3σ ellipse
    # (|dx−dy| ≤ 1: 7 + 12; |dx−dy| = 2 with |dx+dy| ≤ 6: 10; hand count)
    assert tot0[N] == 29
    assert res.scored_per_view == [4, 5]
    ref = map_reference(
        sc, grid.geometry, grid.codes.numpy(), fused.segmented, fused.vmask, views, slots, cfg
    )
    assert not ref["ambiguous"].any()
    assert (
        ref["total_fp"][0].tolist() == tot0.tolist() and ref["mask_fp"][1].tolist() == pos1.tolist()
    )
    assert np.array_equal(ref["kappa"], res.kappa) and np.array_equal(ref["selected"], res.selected)


def test_pass3_box_is_one_sigma_and_threshold_is_tau_kappa(device):
    """An axis-aligned 3.4 × 1.6 px surfel visits 7 × 3 pixels (not the 3σ box); with the
    mask covering 10 of them κ = 10/21 < ½ → culled, τ_κ = 0.45 keeps it."""
    cam = _axis_cam()
    yy, xx = np.mgrid[0:40, 0:40]
    mask = ((xx >= 17) & (xx <= 21)) & ((yy >= 19) & (yy <= 20))  # 5 × 2 = 10 of the box
    mask |= xx == 25  # outside the 1σ box, inside the 3σ one: never counted
    sc = _scene([_px(20, 20)], [[0.034, 0.016]])
    grid = _hand_grid(
        np.unique(voxel_codes_numpy(sc.means, np.array([0, 0, 1.0]), 1.0, 0.25, 8)),
        center=(0, 0, 1.0),
        device=device,
    )
    fused = _fused([True], [[1]])
    v = _view(cam, mask.astype(np.float32))
    mapper = SurfelMapper(sc, grid, device=device)
    tot, pos, _ = mapper.view_counts(fused, v, 0)
    assert (tot[0], pos[0]) == (21, 10)
    r = mapper.map(fused, [v], [0])
    assert r.kappa[0] == pytest.approx(10 / 21, abs=1e-7) and not r.selected[0]
    r = mapper.map(fused, [v], [0], MappingConfig(surfel_coverage=0.45))
    assert r.selected[0]
    # τ_M: a mask of 0.5 everywhere counts as foreground (M̃ ≥ τ_M), 0.4999 does not
    assert mapper.map(fused, [_view(cam, np.full((40, 40), 0.5))], [0]).kappa[0] == 1.0
    assert mapper.map(fused, [_view(cam, np.full((40, 40), 0.4999))], [0]).kappa[0] == 0.0


def test_pass3_behind_camera_and_offscreen_not_counted(device):
    cam = _axis_cam()
    sc = _scene([[0, 0, -1.0], [5.0, 0, 1.0], [0, 0, 0.005]], np.full((3, 2), 0.02))
    grid = _hand_grid(
        np.unique(voxel_codes_numpy(sc.means, np.zeros(3), 8.0, 2.0, 8)), half=8.0, device=device
    )
    fused = _fused(np.ones(len(grid), bool), np.ones((len(grid), 1)))
    res = map_to_surfels(
        sc,
        grid,
        fused,
        [_view(cam, np.ones((40, 40)))],
        [0],
        MappingConfig(needle_filter=False),
        device=device,
    )
    assert res.pass2.all() and not res.selected.any() and (res.kappa == 0).all()


def test_input_validation(device):
    sc, grid, fused, views, slots = _random_case(0, device=device)
    mapper = SurfelMapper(sc, grid, device=device)
    with pytest.raises(ValueError, match="slots"):
        mapper.map(fused, views, slots[:2])
    with pytest.raises(ValueError, match="outside the bitmask"):
        mapper.map(fused, views[:1], [64])
    with pytest.raises(ValueError, match="duplicate"):
        mapper.map(fused, views[:2], [1, 1])
    bad = _fused(fused.segmented, fused.vmask_raw)
    bad.vmask = None
    with pytest.raises(ValueError, match="bitmask"):
        mapper.map(bad, views, slots)
    with pytest.raises(ValueError, match="voxels"):
        mapper.map(_fused(fused.segmented[:-1], fused.vmask_raw[:-1]), views, slots)
    with pytest.raises(ValueError):
        MappingConfig(needle_percentile=101)


def test_view_cache_add_drop_reclaim(monkeypatch, device):
    """Per-update calls with views added, undone and re-added (device mask buffers are
    appended and reclaimed) give the same result as a fresh mapper."""
    from divas_engine.mapping import passes

    monkeypatch.setattr(passes._ViewCache, "min_reclaim", 1)
    sc, grid, fused, views, slots = _random_case(1, device=device)
    extra = [_view(v.camera, 1.0 - v.mask) for v in views]  # new objects, other masks
    pool = views + extra
    mapper = SurfelMapper(sc, grid, device=device)
    rng = np.random.default_rng(0)
    for _ in range(8):
        k = int(rng.integers(1, 4))
        pick = sorted(rng.choice(len(pool), k, replace=False).tolist())
        vs, ss = [pool[i] for i in pick], [i * 5 for i in pick]
        got = mapper.map(fused, vs, ss)
        want = SurfelMapper(sc, grid, device=device).map(fused, vs, ss)
        assert np.array_equal(got.kappa, want.kappa) and np.array_equal(got.selected, want.selected)
    got = mapper.map(fused, pool[:2], [0, 5], MappingConfig(mask_threshold=0.7))
    want = SurfelMapper(sc, grid, device=device).map(
        fused, pool[:2], [0, 5], MappingConfig(mask_threshold=0.7)
    )
    assert np.array_equal(got.kappa, want.kappa)


def test_pass3_uses_the_view_cameras_own_near_clip(device):
    """Pass 3 scores a surfel in a view only beyond that view's near plane — the camera's
    own ``near`` when it is larger than ``MappingConfig.near`` (what the renderer drew)."""
    cam = _axis_cam()
    sc = _scene([[0, 0, 0.5], [0, 0, 2.0]], np.full((2, 2), 0.005))
    grid = _hand_grid(
        np.unique(voxel_codes_numpy(sc.means, np.zeros(3), 8.0, 2.0, 8)), half=8.0, device=device
    )
    fused = _fused(np.ones(len(grid), bool), np.ones((len(grid), 1)))
    cfg = MappingConfig(needle_filter=False)
    full = np.ones((40, 40))
    plain = map_to_surfels(sc, grid, fused, [_view(cam, full)], [0], cfg, device=device)
    assert plain.selected.tolist() == [True, True]
    clipped_views = [_view(cam.with_near(1.0), full)]
    clipped = map_to_surfels(sc, grid, fused, clipped_views, [0], cfg, device=device)
    assert clipped.selected.tolist() == [False, True] and clipped.kappa[0] == 0.0
    ref = map_reference(
        sc, grid.geometry, grid.codes.numpy(), fused.segmented, fused.vmask, clipped_views, [0], cfg
    )
    assert np.array_equal(ref["selected"], clipped.selected)
    # a camera near below the config's changes nothing
    low = map_to_surfels(
        sc, grid, fused, [_view(cam.with_near(1e-4), full)], [0], cfg, device=device
    )
    assert np.array_equal(low.kappa, plain.kappa)
