"""The session's voxel-to-surfel mapper reads the
renderer's surfel centres and scaled tangents instead of uploading its own copy. The
renderer rounds the float32 product ``R·s``, the mapper the exact float64 product of the
same float32 factors: the same float32 values, so the mapping is unchanged bit for bit.
Both are compared here against the mapper's own upload on scenes whose scales span
many orders of magnitude (down to subnormal products)."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.fusion import GridConfig, build_occupancy
from divas_engine.mapping import SurfelMapper
from divas_engine.render import make_renderer
from divas_engine.scene import SurfelScene
from tests.test_mapping import _random_case


def _wide_scene(seed: int, n: int = 20000) -> SurfelScene:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    s = np.exp(rng.uniform(np.log(1e-40), np.log(1e3), (n, 2)))  # products down to subnormal
    return SurfelScene(
        rng.normal(size=(n, 3)).astype(np.float32),
        q.astype(np.float32),
        s.astype(np.float32),
        rng.uniform(0.01, 1.0, n).astype(np.float32),
        rng.normal(size=(n, 1, 3)).astype(np.float32),
        0,
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_shared_tangents_equal_the_mappers_own(seed):
    sc = _wide_scene(seed)
    grid = build_occupancy(sc, GridConfig(g_max=32), device="cpu")
    bufs = make_renderer(sc, device="cpu").surfel_buffers
    own = SurfelMapper(sc, grid, device="cpu")
    shared = SurfelMapper(sc, grid, device="cpu", surfels=bufs)
    for name in ("_means", "_tu", "_tv"):
        a, b = getattr(own, name).numpy(), getattr(shared, name).numpy()
        assert a.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(a, b)
        # the same bytes as the renderer's (no second copy)
        assert getattr(shared, name).ptr == getattr(bufs, name[1:]).ptr
        assert getattr(own, name).ptr != getattr(bufs, name[1:]).ptr
    # not vacuous: some products are subnormal or zero in float32
    tu = shared._tu.numpy()
    tiny = np.abs(tu[tu != 0]).min()
    assert tiny < np.finfo(np.float32).tiny


@pytest.mark.parametrize("seed", [0, 2])
def test_mapping_with_shared_buffers_is_bit_identical(seed):
    sc, grid, fused, views, slots = _random_case(seed, device="cpu")
    bufs = make_renderer(sc, device="cpu").surfel_buffers
    a = SurfelMapper(sc, grid, device="cpu").map(fused, views, slots)
    b = SurfelMapper(sc, grid, device="cpu", surfels=bufs).map(fused, views, slots)
    assert a.n_selected > 0
    for name in ("pass1", "pass2", "selected", "kappa"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.scored_per_view == b.scored_per_view


def test_other_scene_buffers_are_not_taken():
    sc = _wide_scene(3, 500)
    grid = build_occupancy(sc, GridConfig(g_max=16), device="cpu")
    other = make_renderer(_wide_scene(4, 400), device="cpu").surfel_buffers
    m = SurfelMapper(sc, grid, device="cpu", surfels=other)  # wrong length: own upload
    assert m._tu.ptr != other.tu.ptr and m._tu.shape[0] == 500


def test_the_sessions_mapper_shares_the_renderers_buffers(tmp_path):
    from divas_engine.session import Session, SessionConfig
    from divas_engine.synthetic import generate_scene

    g = generate_scene("plant", tmp_path, size=4000, seed=0, sh_degree=1)
    with Session.open(g.scene, g.cameras, SessionConfig(), None, "cpu") as s:
        mapper = s.backend._ready()[2]
        bufs = s.renderer.surfel_buffers
        assert mapper._tu.ptr == bufs.tu.ptr and mapper._means.ptr == bufs.means.ptr


def test_kept_binnings_hold_no_colours_and_renders_are_unchanged(tmp_path):
    """A kept binning drops the RGB render's ``[N,3]`` SH colours (12 bytes a surfel of
    the scene); the value render that reuses it and a second RGB render of the same
    camera equal a renderer that keeps nothing, bit for bit."""
    from divas_engine.synthetic import generate_scene

    g = generate_scene("plant", tmp_path, size=6000, seed=1, sh_degree=2)
    r = make_renderer(g.scene, device="cpu")
    fresh = make_renderer(g.scene, device="cpu")
    fresh.binning_cache = 0
    keeps = make_renderer(g.scene, device="cpu")
    keeps.binning_keeps_colours = True
    cam = g.cameras[0]
    v = np.random.default_rng(0).random(len(g.scene), dtype=np.float32)
    a, b, c = r.render(cam), fresh.render(cam), keeps.render(cam)
    kept, kept_c = r.kept_binning(cam), keeps.kept_binning(cam)
    assert kept is not None and kept.colors is None
    assert kept_c.colors is not None
    assert kept.nbytes == kept_c.nbytes - kept_c.colors.capacity
    for x, y in ((a, b), (c, b), (r.render(cam), b)):
        for k, arr in x.as_dict().items():
            np.testing.assert_array_equal(arr, getattr(y, k), err_msg=k)
    np.testing.assert_array_equal(r.render_values(cam, v), fresh.render_values(cam, v))
    assert r.kept_binning(cam).colors is None and len(r._binnings) == 1
