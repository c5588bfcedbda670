"""Issue 20, graph3d at 3M splats: the lean primitives (no stored colour / normal / κ /
σ / reach / index of a surfel scene, computed for the rows a prompt reads) and the
leaner voxel graph give the earlier results bit for bit — the features, the voxel
graph, the supports' primitive test, and the segmenter's selections, scores and
masks — against :mod:`tests.graph3d_reference` (the earlier code, every feature stored
for the whole scene)."""

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
    ReferenceFeatures,
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
    (sorted, shuffled, repeated, a mask, none) equal those rows of the features computed
    for the whole scene; nothing but the scene's own arrays is kept."""
    op = scene.opacities
    cut = float(op.min()) if floor == "all" else float(np.quantile(op, 0.3))
    if floor == "some" and not (op < cut).any():
        scene.opacities[::3] = 0.5 * cut  # make some surfels fall below the floor
    prims = ScenePrimitives.from_scene(scene, cut, UP)
    ref = ReferenceFeatures.of(prims)
    if floor == "all":
        assert prims.index is None and np.shares_memory(prims.points, scene.means)
    else:
        assert prims.index is not None and len(prims) < len(scene)
    assert all(getattr(prims, f) is None for f in ("lab", "normals", "kappa", "reach", "sigma"))
    for rows in row_selections(len(prims), seed=5):
        np.testing.assert_array_equal(prims.rows_of(rows), ref.index[rows])
        np.testing.assert_array_equal(prims.lab_of(rows), ref.lab[rows])
        np.testing.assert_array_equal(prims.normals_of(rows), ref.normals[rows])
        kap = prims.kappa_of(rows)
        np.testing.assert_array_equal(
            np.ones(len(ref.kappa[rows]), np.float32) if kap is None else kap, ref.kappa[rows]
        )
        assert (kap is None) == (scene.scale_n is None)
        np.testing.assert_array_equal(prims.sigma_of(rows), ref.sigma[rows])
        np.testing.assert_array_equal(prims.reach_of(rows), ref.reach[rows])
        assert prims.lab_of(rows).dtype == np.float32 == prims.normals_of(rows).dtype


def _same_graph(a: VoxelGraph, b: VoxelGraph) -> None:
    for f in fields(VoxelGraph):
        if f.name in ("up_height", "up_dot"):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


def _clicks(prims: ScenePrimitives) -> list[tuple[np.ndarray, float]]:
    """Centres and radii around a few primitives (small and large regions)."""
    rng = np.random.default_rng(11)
    pick = rng.choice(len(prims), 3, replace=False)
    out = [(prims.points[i].astype(np.float64), r) for i in pick for r in (0.08, 0.3)]
    return [*out, (np.array([0.0, 0.0, 0.2]), 0.35)]


@pytest.mark.parametrize("min_opacity", [0.0, 0.3])
def test_voxel_graph_is_the_reference(scene, min_opacity):
    """The voxel graph (nodes, aggregates, edges, weights) of several regions equals
    the earlier code's bit for bit, with every surfel kept and with some left out; with
    the 3DGS scene's extents too (checked non-vacuous)."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(scene, min_opacity, UP)
    ref = ReferenceFeatures.of(prims)
    grew = 0
    for centre, radius in _clicks(prims):
        g = build_voxel_graph(prims, centre, radius, cfg)
        _same_graph(g, reference_voxel_graph(ref, centre, radius, cfg))
        grew += int(len(np.unique(g.voxel_of)) < len(g))  # voxels of extents alone
    if scene.kind == SceneKind.GS3D and min_opacity == 0.0:
        assert grew > 0  # some voxels hold only a Gaussian's extent


def test_voxel_graph_of_a_density_grid_is_the_reference():
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(grid_ball_and_box().grid, cfg.min_opacity, UP)
    ref = ReferenceFeatures.of(prims)
    for centre, radius in [(np.array([0.0, 0.0, 0.36]), 0.2), (np.array([0.28, 0.0, 0.1]), 0.3)]:
        _same_graph(
            build_voxel_graph(prims, centre, radius, cfg),
            reference_voxel_graph(ref, centre, radius, cfg),
        )


def test_support_primitives_are_the_reference(scene):
    """The primitives dropped as a support's (floor surfels in a kept voxel) equal the
    earlier per-primitive test's, from the graph's p · up and n · up and without them."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(scene, cfg.min_opacity, UP)
    ref = ReferenceFeatures.of(prims)
    assert prims.grounds  # the floor
    hits = 0
    for centre, radius in _clicks(prims):
        g = build_voxel_graph(prims, centre, radius, cfg)
        pos = np.zeros(len(g), bool)
        pos[g.node_of_points(centre[None])] = True
        planes = support_nodes(g, prims, pos, cfg) & ~pos
        want = reference_support_primitives(g, ref, planes, cfg)
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
    """Selections, scores, advice and the rendered masks (sparse window render) of a
    few prompts equal those of the segmenter running the earlier graph and supports."""
    scene = _scene(name)
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
    ref = ReferenceFeatures.of(old.primitives())
    monkeypatch.setattr(
        sm, "build_voxel_graph", lambda p, c, rad, cfg: reference_voxel_graph(ref, c, rad, cfg)
    )
    monkeypatch.setattr(
        sm,
        "support_primitives",
        lambda g, p, pl, cfg: reference_support_primitives(g, ref, pl, cfg),
    )
    shown = 0
    for sd, (rc, masks) in zip(prompts, got, strict=True):
        want = old.cut(sd)
        np.testing.assert_array_equal(rc.selected, want.selected)
        np.testing.assert_array_equal(rc.scores, want.scores)
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
