"""The 3D graph segmenter's lean primitives (no stored colour / normal / κ / σ / reach /
index of a surfel scene, computed for the rows a prompt reads) give the whole scene's
features bit for bit, and they, the voxel graph, the supports' primitive test and the
segmenter's selections, scores and masks agree with :mod:`tests.graph3d_reference` (an
independent reference written from the documented definitions) within float rounding."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.kinds import SceneKind
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.segment import Graph3DSegmenter, SceneBinding
from divas_engine.segment.graph3d import Seeds
from divas_engine.segment.graph3d import segmenter as sm
from divas_engine.segment.graph3d.config import Graph3DConfig
from divas_engine.segment.graph3d.primitives import ScenePrimitives
from divas_engine.segment.graph3d.supports import support_nodes, support_primitives
from divas_engine.segment.graph3d.voxel_graph import VoxelGraph, build_voxel_graph
from tests.graph3d_cases import ball_with_leaves, grid_ball_and_box, touching_boxes
from tests.graph3d_reference import (
    graph_by_cell,
    reference_primitives,
    reference_support_primitives,
    reference_voxel_graph,
)

UP = np.array([0.0, 0.0, 1.0])


def row_selections(m: int, seed: int) -> list[np.ndarray]:
    """Ways a prompt reads rows of ``m`` primitives: all, sorted, shuffled, repeated, a
    bool mask, none."""
    rng = np.random.default_rng(seed)
    return [
        np.arange(m),
        np.sort(rng.choice(m, m // 3, replace=False)),
        rng.permutation(m)[: m // 2],
        rng.integers(0, m, 50),
        rng.random(m) < 0.4,
        np.zeros(0, np.int64),
    ]


def _scene(name: str):
    if name == "gs3d":  # 3DGS: κ from scale_n, extents of the large Gaussians
        return ball_with_leaves(SceneKind.GS3D).scene
    if name == "gs2d":  # native surfels: κ = 1, no extents
        return ball_with_leaves(SceneKind.GS2D).scene
    return touching_boxes().scene


@pytest.fixture(scope="module", params=["gs3d", "gs2d", "boxes"])
def scene(request):
    return _scene(request.param)


@pytest.mark.parametrize("floor", ["all", "some"])
def test_features_of_rows_are_the_whole_scenes(scene, floor):
    """``lab_of`` / ``normals_of`` / ``kappa_of`` / ``sigma_of`` / ``reach_of`` of any rows
    (sorted, shuffled, repeated, a mask, none) equal those rows of the whole scene's,
    bit for bit, and the reference's features within float32 rounding; nothing but the
    scene's own arrays is kept."""
    op = scene.opacities
    cut = float(op.min()) if floor == "all" else float(np.quantile(op, 0.3))
    if floor == "some" and not (op < cut).any():
        scene.opacities[::3] = 0.5 * cut  # make some surfels fall below the floor
    prims = ScenePrimitives.from_scene(scene, cut, UP)
    ref = reference_primitives(scene, cut)
    if floor == "all":
        assert prims.index is None and np.shares_memory(prims.points, scene.means)
    else:
        assert prims.index is not None and len(prims) < len(scene)
    assert all(getattr(prims, f) is None for f in ("lab", "normals", "kappa", "reach", "sigma"))
    every = np.arange(len(prims))
    whole = {
        "lab": prims.lab_of(every),
        "normals": prims.normals_of(every),
        "kappa": prims.kappa_of(every),
        "sigma": prims.sigma_of(every),
        "reach": prims.reach_of(every),
    }
    assert (whole["kappa"] is None) == (scene.scale_n is None)
    kappa = np.ones(len(prims), np.float32) if whole["kappa"] is None else whole["kappa"]
    np.testing.assert_allclose(whole["lab"], ref.lab, atol=1e-3)
    np.testing.assert_allclose(whole["normals"], ref.normals, atol=1e-6)
    np.testing.assert_allclose(kappa, ref.kappa, atol=1e-6)
    np.testing.assert_allclose(whole["sigma"], ref.sigma, rtol=1e-6)
    np.testing.assert_allclose(whole["reach"], ref.reach, rtol=1e-6)
    for rows in row_selections(len(prims), seed=5):
        np.testing.assert_array_equal(prims.rows_of(rows), ref.index[rows])
        np.testing.assert_array_equal(prims.lab_of(rows), whole["lab"][rows])
        np.testing.assert_array_equal(prims.normals_of(rows), whole["normals"][rows])
        kap = prims.kappa_of(rows)
        assert (kap is None) == (whole["kappa"] is None)
        if kap is not None:
            np.testing.assert_array_equal(kap, whole["kappa"][rows])
        np.testing.assert_array_equal(prims.sigma_of(rows), whole["sigma"][rows])
        np.testing.assert_array_equal(prims.reach_of(rows), whole["reach"][rows])
        assert prims.lab_of(rows).dtype == np.float32 == prims.normals_of(rows).dtype


def _same_graph(a: VoxelGraph, b: VoxelGraph) -> None:
    """Two graphs of the same code on the same machine: identical, field by field."""
    for f in fields(VoxelGraph):
        if f.name in ("up_height", "up_dot"):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


#: a node's principal normal is compared (and an edge's weight, which reads it) only
#: where the tensor's two largest eigenvalues differ by this share: these scenes' surfels
#: all have opacity 0.9, so a voxel across a crease often holds equal mass on two faces,
#: and its normal is then any vector of their plane (the graph's and the reference's
#: eigen-solvers pick different ones)
CLEAR_NORMAL = 1e-6


def _matches_reference(got: VoxelGraph, want: VoxelGraph, gaps: dict) -> None:
    """The same region, primitives, nodes (by cell), aggregates and edge weights within
    rounding — the graph reads float32 normals (unit to ~1e-7), the reference float64
    ones from the normalised quaternion; a normal up to its sign."""
    assert got.cells == want.cells and got.h == pytest.approx(want.h, rel=1e-12)
    np.testing.assert_allclose(got.lo, want.lo, rtol=0, atol=1e-12)
    a, b = graph_by_cell(got), graph_by_cell(want)
    assert a["prims"] == b["prims"]
    assert set(a["nodes"]) == set(b["nodes"]) and set(a["edges"]) == set(b["edges"])
    cells = list(b["nodes"])
    ours = [np.array([a["nodes"][c][k] for c in cells]) for k in range(6)]
    ref = [np.array([b["nodes"][c][k] for c in cells]) for k in range(6)]
    np.testing.assert_allclose(ours[0], ref[0], rtol=1e-6)  # mass
    np.testing.assert_allclose(ours[1], ref[1], rtol=0, atol=1e-9)  # centroid
    np.testing.assert_allclose(ours[2], ref[2], rtol=1e-6, atol=1e-6)  # colour
    np.testing.assert_allclose(ours[4], ref[4], rtol=0, atol=1e-6)  # ν
    np.testing.assert_array_equal(ours[5], ref[5])  # rim
    gap = np.array([gaps[c] for c in cells])
    clear = (ref[4] > 1e-6) & (gap > CLEAR_NORMAL)  # (ν = 0: round blobs, no normal)
    dots = np.abs(np.sum(ours[3] * ref[3], axis=1))
    assert np.all(dots[clear] > 1.0 - 1e-6), [c for c, ok in zip(cells, dots > 1 - 1e-6) if not ok]
    # an edge's weight reads the normals unless ν_i ν_j = 0
    nu = dict(zip(cells, ref[4]))
    pairs = [tuple(p) for p in b["edges"]]
    usable = [nu[i] * nu[j] == 0.0 or min(gaps[i], gaps[j]) > CLEAR_NORMAL for i, j in pairs]
    assert sum(usable) > 0.5 * len(pairs)
    keys = [frozenset(p) for p, ok in zip(pairs, usable) if ok]
    np.testing.assert_allclose(
        [a["edges"][k] for k in keys], [b["edges"][k] for k in keys], rtol=1e-5, atol=1e-12
    )


def _clicks(prims: ScenePrimitives) -> list[tuple[np.ndarray, float]]:
    """Centres and radii around a few primitives (small and large regions). The centres
    are moved off the primitives by a fraction of a millimetre: a centre on a primitive
    of these lattice-built scenes puts it and its extent samples on voxel faces, where
    the last bit of a product decides the voxel (implementation and reference round
    differently)."""
    rng = np.random.default_rng(11)
    pick = rng.choice(len(prims), 3, replace=False)
    off = np.array([0.317, -0.271, 0.141]) * 1e-3
    out = [(prims.points[i].astype(np.float64) + off, r) for i in pick for r in (0.08, 0.3)]
    return [*out, (np.array([0.0, 0.0, 0.2]) + off, 0.35)]


@pytest.mark.parametrize("min_opacity", [0.0, 0.3])
def test_voxel_graph_is_the_reference(scene, min_opacity):
    """The voxel graph (nodes, aggregates, edges, weights) of several regions equals
    the reference's, with every surfel kept and with some left out; with the 3DGS
    scene's extents too (checked non-vacuous)."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(scene, min_opacity, UP)
    ref = reference_primitives(scene, min_opacity)
    grew = 0
    for centre, radius in _clicks(prims):
        g = build_voxel_graph(prims, centre, radius, cfg)
        gaps: dict = {}
        _matches_reference(g, reference_voxel_graph(ref, centre, radius, cfg, gaps), gaps)
        grew += int(len(np.unique(g.voxel_of)) < len(g))  # voxels of extents alone
    if scene.kind == SceneKind.GS3D and min_opacity == 0.0:
        assert grew > 0  # some voxels hold only a Gaussian's extent


def test_voxel_graph_of_a_density_grid_is_the_reference():
    cfg = Graph3DConfig()
    grid = grid_ball_and_box().grid
    prims = ScenePrimitives.from_scene(grid, cfg.min_opacity, UP)
    ref = reference_primitives(grid, cfg.min_opacity, grid_prims=prims)
    for centre, radius in [(np.array([0.0, 0.0, 0.36]), 0.2), (np.array([0.28, 0.0, 0.1]), 0.3)]:
        gaps: dict = {}
        want = reference_voxel_graph(ref, centre, radius, cfg, gaps)
        _matches_reference(build_voxel_graph(prims, centre, radius, cfg), want, gaps)


def test_support_primitives_are_the_reference(scene):
    """The primitives dropped as a support's (floor surfels in a kept voxel) are the
    reference's, from the graph's p · up and n · up and without them."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(scene, cfg.min_opacity, UP)
    ref = reference_primitives(scene, cfg.min_opacity)
    assert prims.grounds  # the floor
    hits = 0
    for centre, radius in _clicks(prims):
        g = build_voxel_graph(prims, centre, radius, cfg)
        pos = np.zeros(len(g), bool)
        pos[g.node_of_points(centre[None])] = True
        planes = support_nodes(g, prims, pos, cfg) & ~pos
        want = reference_support_primitives(g, ref, prims.up, planes, cfg)
        np.testing.assert_array_equal(support_primitives(g, prims, planes, cfg), want)
        g.up_height = g.up_dot = None  # the fallback: from the primitives' rows
        np.testing.assert_array_equal(support_primitives(g, prims, planes, cfg), want)
        hits += int(want.any())
    assert hits > 0


def _camera() -> Camera:
    return Camera.look_at(
        np.array([0.6, -1.3, 0.8]),
        np.array([0.0, 0.0, 0.15]),
        np.array([0.0, 0.0, 1.0]),
        width=200,
        height=150,
        fx=240.0,
    )


@pytest.mark.parametrize("name", ["gs3d", "boxes"])
def test_segmenter_results_are_the_reference(name, monkeypatch):
    """Selections, advice and the rendered masks (sparse window render) of a few prompts
    equal those of the segmenter running the reference graph and supports; the scores
    agree within float rounding."""
    scene = _scene(name)
    # distinct opacities: with 0.9 everywhere a crease voxel often holds the same mass on
    # two faces, its normal is then any vector of their plane (CLEAR_NORMAL) and the cut
    # would follow whichever one each eigen-solver picks
    scene.opacities[:] = np.random.default_rng(3).uniform(0.8, 1.0, len(scene))
    cam = _camera()
    r = SurfelRenderer(scene, device="cpu")

    def segmenter() -> Graph3DSegmenter:
        bind = SceneBinding(
            scene, r.render_values, up=lambda: UP, render_sparse=r.render_values_sparse
        )
        return Graph3DSegmenter(binding=bind)

    prompts = [
        Seeds(np.array([[0.0, 0.0, 0.4]]), np.zeros((0, 3))),
        Seeds(np.array([[0.12, -0.12, 0.1]]), np.zeros((0, 3))),
        Seeds(np.array([[0.0, 0.0, 0.4], [0.1, 0.1, 0.3]]), np.array([[0.0, 0.5, 0.0]])),
    ]
    lean = segmenter()
    got = []
    for sd in prompts:
        rc = lean.cut(sd)
        got.append((rc, lean.render_masks(cam, rc.selected)))
    old = segmenter()
    ref = reference_primitives(scene, old.config.min_opacity)
    monkeypatch.setattr(
        sm, "build_voxel_graph", lambda p, c, rad, cfg: reference_voxel_graph(ref, c, rad, cfg)
    )
    monkeypatch.setattr(
        sm,
        "support_primitives",
        lambda g, p, pl, cfg: reference_support_primitives(g, ref, p.up, pl, cfg),
    )
    shown = 0
    for sd, (rc, masks) in zip(prompts, got, strict=True):
        want = old.cut(sd)
        np.testing.assert_array_equal(rc.selected, want.selected)
        np.testing.assert_allclose(rc.scores, want.scores, rtol=1e-6, atol=1e-9)
        assert rc.message == want.message and rc.radius == want.radius
        np.testing.assert_array_equal(masks, old.render_masks(cam, want.selected))
        shown += int((masks.max(axis=0) > 0.5).any())
    assert shown > 0


@pytest.mark.parametrize("n", [1, 2, 3, 8, 1001, 40000])
def test_surfel_frame_is_the_robust_frame(n):
    """The primitives' scene frame (centre, P99 radius) from float32 centres a column /
    a block of rows at a time equals ``robust_frame`` of their float64 copy bit for bit
    (even and odd counts, repeated values, blocks that do not divide the rows)."""
    from divas_engine.scene_stats import robust_frame
    from divas_engine.segment.graph3d.primitives import surfel_frame

    rng = np.random.default_rng(n)
    m = (rng.standard_normal((n, 3)) * [1.0, 3.0, 0.1] + [0.5, -2.0, 7.0]).astype(np.float32)
    m[::5] = m[0]
    want = robust_frame(np.asarray(m, np.float64))
    for block in (1, 7, 1 << 18):
        got = surfel_frame(m, block)
        np.testing.assert_array_equal(got.center, want.center)
        assert got.radius == want.radius


def test_primitives_frame_is_the_scenes_robust_frame(scene):
    from divas_engine.scene_stats import robust_frame
    from divas_engine.views.ground import scene_points

    prims = ScenePrimitives.from_scene(scene, 0.0, UP)
    want = robust_frame(scene_points(scene)[0])
    np.testing.assert_array_equal(prims.center, want.center)
    assert prims.radius == want.radius
