"""The first centroid-view probe at full resolution (ViewConfig.probe_full_first):
the same views as the paper's low-resolution probes, the view's render made once."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.segment.oracle import OracleSegmenter
from divas_engine.session import Session, SessionConfig
from divas_engine.views import GsCentroidPlanner, ViewConfig, occluded_fraction

from .test_centroid import _occluded_click


@pytest.fixture(scope="module")
def occluded():
    from divas_engine.render.surfel_renderer import SurfelRenderer
    from divas_engine.synthetic import generate_scene

    s = generate_scene("occluded", None, size=30_000, seed=0)
    return s, SurfelRenderer(s.scene, device="cpu")


class _Counting:
    """A renderer that counts its full renders and probe depth renders."""

    def __init__(self, inner):
        self.inner, self.renders, self.depths = inner, [], 0

    def render(self, camera, scale=1.0):
        self.renders.append((camera, scale))
        return self.inner.render(camera, scale)

    def render_depth(self, camera, scale=1.0, window=None):
        self.depths += 1
        return self.inner.render_depth(camera, scale, window)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _clicks(s, r):
    """Two opaque pixels on each of the first five training cameras, plus the vase pixel
    behind the pillar (whose first radius is occluded)."""
    out = []
    for cam in s.cameras[:5]:
        buf = r.render(cam)
        ys, xs = np.nonzero((buf.alpha > 0.9) & (buf.D_med > 0))
        for k in np.random.default_rng(3).choice(len(xs), 2, replace=False):
            out.append((cam, buf, (xs[k] + 0.5, ys[k] + 0.5)))
    out.append(_occluded_click(s, r))
    return out


def test_full_first_probe_gives_the_papers_views_and_hands_over_its_render(occluded):
    s, r = occluded
    low = GsCentroidPlanner(s.scene, r, ViewConfig(probe_full_first=False))
    counting = _Counting(r)
    full = GsCentroidPlanner(s.scene, counting, ViewConfig())
    cfg = full.config
    taken = rejected = 0
    for anchor, buf, xy in _clicks(s, r):
        a = low.centroid_view(anchor, xy, buf, name="v")
        counting.renders.clear()
        b = full.centroid_view(anchor, xy, buf, name="v")
        # the same view: pose, strategy, radii and decisions of every probe
        assert np.array_equal(a.camera.w2c, b.camera.w2c) and a.d_cam == b.d_cam
        assert a.strategy == b.strategy and b.camera.name == "v"
        assert [(p.radius, p.accepted) for p in a.probes] == [
            (p.radius, p.accepted) for p in b.probes
        ]
        assert [p.tau_occ for p in a.probes] == [p.tau_occ for p in b.probes]
        # probe 0 was read on the full-resolution render of its camera (eq:occfrac)
        assert len(counting.renders) == 1 and counting.renders[0][1] == 1.0
        first = counting.renders[0][0]
        o, valid = occluded_fraction(r.render(first).D_med, b.probes[0].tau_occ, cfg.f_fill)
        assert b.probes[0].occluded == o and b.probes[0].valid == valid
        assert valid > 10 * a.probes[0].valid  # 16× the pixels of the low-res probe
        got, seconds = b.take_buffers()
        if b.probes[0].accepted:
            taken += 1
            # that render is the view's: bit-equal to a fresh render of the view's camera
            ref = r.render(b.camera)
            assert got is not None and got.camera is b.camera
            for name in ("rgb", "alpha", "D_min", "D_ref", "D_max", "D_mw", "D_exp", "D_med"):
                assert np.array_equal(getattr(got, name), getattr(ref, name)), name
            assert seconds > 0 and b.take_buffers() == (None, 0.0)  # given once
        else:
            rejected += 1
            assert got is None and counting.depths > 0  # the later radii: low-res probes
    assert taken >= 5 and rejected >= 2


def _spy(monkeypatch, rend) -> tuple[list, list]:
    """Record the cameras of ``rend``'s full renders and of its probe depth renders."""
    calls, depths = [], []
    orig, orig_depth = rend.render, rend.render_depth
    monkeypatch.setattr(rend, "render", lambda c, scale=1.0: calls.append(c) or orig(c, scale))
    monkeypatch.setattr(
        rend, "render_depth", lambda c, *a, **k: depths.append(c) or orig_depth(c, *a, **k)
    )
    return calls, depths


def test_session_click_renders_the_view_once(occluded, monkeypatch):
    s, r = occluded
    anchor, _, xy = _occluded_click(s, r)
    counts = {}
    for flag in (True, False):
        cfg = SessionConfig(view=ViewConfig(probe_full_first=flag))
        sess = Session.open(
            s.scene, s.cameras, cfg, OracleSegmenter(), "cpu", gt_values=s.labels,
            render_anchors=False,
        )  # fmt: skip
        a = sess.add_anchor(anchor, "training", 0)
        sess.render(a)
        calls, depths = _spy(monkeypatch, sess.renderer)
        ys, xs = np.nonzero((a.buffers.alpha > 0.9) & (a.buffers.D_med > 0))
        k = len(xs) // 2
        v = sess.click(a.index, (xs[k] + 0.5, ys[k] + 0.5))
        assert v.rendered and v.centroid.probes[0].accepted
        # the view's render is reported as the render, not as the camera search
        assert v.timings["render_s"] > 0 and v.timings["centroid_s"] >= 0
        if flag:
            assert v.timings["render_s"] > v.timings["centroid_s"]
        counts[flag] = (len(calls), v.camera.w2c.copy(), v.buffers.rgb.copy(), len(depths))
        sess.close()
    # the view rendered once; with the full first probe no low-res probe at all
    assert counts[True][0] == 1 and counts[False][0] == 1
    assert counts[True][3] == 0 and counts[False][3] == 1
    assert np.array_equal(counts[True][1], counts[False][1])
    assert np.array_equal(counts[True][2], counts[False][2])


def test_neighbourhood_and_its_centres_match_brute_force(occluded):
    """eq:neigh through the x-sorted slab and the y/z pre-filter: the same surfels as a
    brute-force distance pass, ascending, with their float64 centres in that order."""
    s, r = occluded
    planner = GsCentroidPlanner(s.scene, r)
    mu = s.scene.means.astype(np.float64)
    opaque = s.scene.opacities > planner.config.alpha_min
    rng = np.random.default_rng(5)
    for k in rng.choice(len(mu), 6, replace=False):
        for radius in (0.02, 0.1, 0.4):
            x = mu[k] + rng.normal(0, 0.01, 3)
            want = np.flatnonzero((np.linalg.norm(mu - x, axis=1) < radius) & opaque)
            idx, centres = planner._neighbours(x, radius)
            assert np.array_equal(idx, want) and np.array_equal(
                planner.neighbourhood(x, radius), want
            )
            assert centres.dtype == np.float64 and np.array_equal(centres, mu[want])
            # the click's unordered form: the same rows, each with its own centre
            u_idx, u_centres = planner._neighbours(x, radius, ordered=False)
            assert np.array_equal(np.sort(u_idx), want)
            assert np.array_equal(u_centres, mu[u_idx])


def test_row_norms_are_numpys_norm_bit_for_bit():
    """eq:neigh's distances equal ``np.linalg.norm`` to the last bit, on components of
    very different magnitudes (where another summation order differs)."""
    from divas_engine.views.centroid_gs import _row_norms

    rng = np.random.default_rng(1)
    c = rng.normal(size=(50_000, 3)) * 10.0 ** rng.uniform(-8, 8, size=(50_000, 3))
    x = rng.normal(size=3) * 1e-3
    rows = np.sort(rng.choice(len(c), 20_000, replace=False))
    want = np.linalg.norm(c[rows] - x, axis=1)
    assert np.array_equal(_row_norms(np.ascontiguousarray(c.T), rows, x), want)


def test_lateral_distances_are_the_reference_bit_for_bit():
    """eq:Rlat's ‖r⊥‖ equal the [n,3] reference to the last bit, so the percentile, r_init
    and the camera are the same."""
    from divas_engine.views.centroid_gs import _lateral_distances

    rng = np.random.default_rng(2)
    mu = rng.normal(size=(30_000, 3)) * 10.0 ** rng.uniform(-6, 6, size=(30_000, 3))
    x = rng.normal(size=3)
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    r = mu - x
    want = np.linalg.norm(r - np.outer(r @ v, v), axis=1)
    assert np.array_equal(_lateral_distances(mu, x, v), want)
