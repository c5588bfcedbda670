"""Centroid views (paper Sec. 3.3, App. C.3: alg:centroid_view, alg:centroid-gs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.render.buffers import RenderBuffers
from divas_engine.views import (
    GsCentroidPlanner,
    ViewConfig,
    central_patch,
    nerf_centroid_view,
    occluded_fraction,
)


@pytest.fixture(scope="module")
def occluded():
    from divas_engine.render.surfel_renderer import SurfelRenderer
    from divas_engine.synthetic import generate_scene

    s = generate_scene("occluded", None, size=30_000, seed=0)
    r = SurfelRenderer(s.scene, device="cpu")
    return s, r, GsCentroidPlanner(s.scene, r)


def _flat_buffers(cam: Camera, depth: float, alpha: float = 1.0) -> RenderBuffers:
    h, w = cam.height, cam.width
    d = np.full((h, w), depth, np.float32)
    return RenderBuffers(
        rgb=np.zeros((h, w, 3), np.float32),
        alpha=np.full((h, w), alpha, np.float32),
        D_min=d,
        D_ref=d,
        D_max=d,
        D_mw=d,
        D_exp=d,
        D_med=d,
        N_samp=np.ones((h, w), np.int32),
        camera=cam,
        kind="nerf",
    )


# ----------------------------------------------------------------------------- NeRF
@pytest.mark.parametrize("ff,lam", [(True, 0.67), (False, 0.47)])
def test_nerf_centroid_geometry(ff, lam):
    anchor = Camera.look_at(
        [0.3, -4.0, 1.0], [0, 0, 0.5], [0, 0, 1.0], width=80, height=60, fx=70.0, cx=41.0, cy=29.5
    )
    click = (20.5, 40.5)
    cv = nerf_centroid_view(anchor, click, _flat_buffers(anchor, 3.0), forward_facing=ff)
    x = anchor.unproject(np.array([click]), np.array([3.0]))[0]
    np.testing.assert_allclose(cv.target, x, atol=1e-9)
    p_new = anchor.center + lam * (x - anchor.center)
    np.testing.assert_allclose(cv.camera.center, p_new, atol=1e-9)
    assert cv.d_cam == pytest.approx((1 - lam) * np.linalg.norm(x - anchor.center))
    assert cv.camera.near == pytest.approx(ViewConfig().near_fraction * cv.d_cam)
    uv, z = cv.camera.project(x[None])
    np.testing.assert_allclose(uv[0], [anchor.cx, anchor.cy], atol=1e-6)
    assert cv.camera.up @ anchor.up > 0.9 and abs(cv.camera.right @ anchor.up) < 1e-9


def test_nerf_centroid_no_surface():
    anchor = Camera.look_at([0, -4.0, 0], [0, 0, 0], [0, 0, 1.0], width=40, height=30, fx=40.0)
    with pytest.raises(DivasInputError, match="no surface under the click"):
        nerf_centroid_view(anchor, (10, 10), _flat_buffers(anchor, 0.0))
    with pytest.raises(DivasInputError, match="no surface under the click"):
        nerf_centroid_view(anchor, (10, 10), _flat_buffers(anchor, 2.0, alpha=0.3))
    with pytest.raises(DivasInputError, match="outside"):
        nerf_centroid_view(anchor, (40.0, 10), _flat_buffers(anchor, 2.0))


def test_occluded_fraction_patch():
    d = np.ones((40, 60), np.float32)
    rs, cs = central_patch(40, 60, 0.5)
    assert (rs.stop - rs.start, cs.stop - cs.start) == (20, 30) and (rs.start, cs.start) == (10, 15)
    d[rs.start : rs.start + 5, cs] = 0.2  # 5 of 20 rows occluded
    d[rs.stop - 2 : rs.stop, cs] = 0.0  # 2 rows invalid (not counted)
    o, n = occluded_fraction(d, 0.5, 0.5)
    assert n == 18 * 30 and o == pytest.approx(5 / 18)
    assert math.isnan(occluded_fraction(np.zeros((8, 8)), 0.5, 0.5)[0])


# ----------------------------------------------------------------------------- 2DGS
def test_gs_centroid_looks_at_click(occluded):
    s, r, planner = occluded
    cams = {c.name: c for c in s.cameras}
    click = s.metadata["clicks"][0]
    anchor = cams[click["visible_in"][len(click["visible_in"]) // 2]]
    uv = anchor.project(np.array([click["xyz"]]))[0][0]
    buf = r.render(anchor)
    cv = planner.centroid_view(anchor, uv, buf, name="c0")
    z = float(buf.D_med[int(uv[1]), int(uv[0])])
    np.testing.assert_allclose(cv.target, anchor.unproject(uv[None], np.array([z]))[0], atol=1e-9)
    assert np.linalg.norm(cv.target - click["xyz"]) < 0.02
    puv, pz = cv.camera.project(cv.target[None])
    assert np.abs(puv[0] - [cv.camera.cx, cv.camera.cy]).max() < 0.5
    assert pz[0] == pytest.approx(cv.d_cam)
    # on the anchor ray, with the anchor's intrinsics and up
    ray = (cv.target - anchor.center) / np.linalg.norm(cv.target - anchor.center)
    np.testing.assert_allclose(cv.camera.forward, ray, atol=1e-9)
    assert (cv.camera.width, cv.camera.fx) == (anchor.width, anchor.fx)
    assert cv.camera.up @ anchor.up > 0.9
    # Strategy 1 dense: eq:Rphys / eq:neigh / eq:Rlat / eq:Rinit recomputed by brute force
    cfg = planner.config
    tan_half = math.tan(anchor.fov_x / 2)
    mu = s.scene.means.astype(np.float64)
    nb = (np.linalg.norm(mu - cv.target, axis=1) < cfg.p_f * z * tan_half) & (
        s.scene.opacities > cfg.alpha_min
    )
    assert cv.neighbours == nb.sum() >= 5 and cv.strategy.startswith("dense")
    rr = mu[nb] - cv.target
    r_lat = np.percentile(np.linalg.norm(rr - np.outer(rr @ ray, ray), axis=1), 90)
    assert cv.r_init == pytest.approx(r_lat / (0.5 * tan_half))
    assert (
        cv.box is not None and cv.box[0] <= uv[0] <= cv.box[2] and cv.box[1] <= uv[1] <= cv.box[3]
    )
    assert cv.probes and cv.d_cam == pytest.approx(cv.probes[-1].radius)


def _occluded_click(s, r):
    """A vase pixel right beside the pillar, seen from the training camera behind it."""
    az = np.array([math.degrees(math.atan2(c.center[1], c.center[0])) for c in s.cameras])
    low = np.array([c.center[2] < 1.0 for c in s.cameras])
    anchor = s.cameras[int(np.argmin(np.abs(az + 90) + 1000 * ~low))]
    buf = r.render(anchor)
    lab = r.render_values(anchor, s.labels.astype(np.float32))
    pil = anchor.project(np.array([[0.04, -0.62, 0.7]]))[0][0]
    ys, xs = np.nonzero((lab > 0.9) & (buf.alpha > 0.5))
    k = int(np.argmin(np.abs(xs + 0.5 - pil[0]) + 0.2 * np.abs(ys + 0.5 - pil[1])))
    return anchor, buf, (xs[k] + 0.5, ys[k] + 0.5)


def test_gs_strategy2_avoids_occluder(occluded):
    s, r, planner = occluded
    cfg = planner.config
    anchor, buf, click = _occluded_click(s, r)
    cv = planner.centroid_view(anchor, click, buf)
    assert s.labels[np.argmin(np.linalg.norm(s.scene.means - cv.target, axis=1))]
    # the probe log: decreasing radii, the first (r_init) rejected, a later one accepted
    radii = [p.radius for p in cv.probes]
    assert radii[0] == pytest.approx(cv.r_init) and np.all(np.diff(radii) < 0)
    assert cv.strategy.endswith("+probe") and not cv.probes[0].accepted and cv.probes[-1].accepted
    assert cv.d_cam > cfg.probe_min_frac * cv.r_init  # not the closest-radius fallback

    # independent check: neighbourhood by brute force, τ_occ = 0.85 z_near, O over the patch
    z = float(buf.D_med[int(click[1]), int(click[0])])
    mu = s.scene.means.astype(np.float64)
    nb = mu[
        (np.linalg.norm(mu - cv.target, axis=1) < cfg.p_f * z * math.tan(anchor.fov_x / 2))
        & (s.scene.opacities > cfg.alpha_min)
    ]

    def occ(cam):
        zc = cam.world_to_camera(nb)[:, 2]
        tau = 0.85 * zc[zc > 0].min()
        d = r.render(cam, scale=0.25).D_med
        h, w = d.shape
        patch = d[h // 4 : h // 4 + h // 2, w // 4 : w // 4 + w // 2]
        patch = patch[patch > 0]
        return np.count_nonzero(patch < tau) / patch.size

    assert occ(cv.camera) < 0.15
    first = Camera.look_at(
        cv.target - cv.r_init * cv.camera.forward,
        cv.target,
        anchor.up,
        width=anchor.width,
        height=anchor.height,
        fx=anchor.fx,
    )
    assert occ(first) >= 0.15  # the r_init view really is occluded


def test_gs_sparse_fallback_and_probe_fallback(occluded):
    s, r, _ = occluded
    # α_min above every opacity: no opaque neighbour → sparse r_init = z p_f, no box; τ_O = 0
    # rejects every probe → the closest radius
    planner = GsCentroidPlanner(s.scene, r, ViewConfig(alpha_min=1.0, tau_o=0.0, n_probes=3))
    anchor = s.cameras[10]
    buf = r.render(anchor)
    click = (anchor.cx, anchor.cy)
    z = float(buf.D_med[int(click[1]), int(click[0])])
    cv = planner.centroid_view(anchor, click, buf)
    assert cv.neighbours == 0 and cv.box is None and cv.strategy == "sparse+fallback"
    assert cv.r_init == pytest.approx(0.25 * z)
    assert cv.d_cam == pytest.approx(0.3 * cv.r_init)
    assert all(
        math.isnan(p.z_near) and p.tau_occ == pytest.approx(0.7 * p.radius)
        for p in cv.probes
        if p.valid
    )
    import json

    doc = json.loads(json.dumps(cv.to_dict(), allow_nan=False))
    assert doc["strategy"] == "sparse+fallback" and doc["box"] is None and len(doc["probes"]) == 3
    assert Camera.from_dict(doc["camera"]).width == anchor.width


def test_gs_click_on_empty_space(occluded):
    s, r, planner = occluded
    sky = Camera.look_at(
        [0, -2.0, 0.6], [0, -2.0, 9.0], [0, 1.0, 0], width=64, height=48, fx=60.0, name="sky"
    )
    buf = r.render(sky)
    assert buf.alpha[24, 32] < 0.5
    with pytest.raises(
        DivasInputError, match=r"no surface under the click at \(32.5, 24.5\) in anchor sky"
    ):
        planner.centroid_view(sky, (32.5, 24.5), buf)


def test_centroid_camera_clips_a_faint_floater_next_to_it(occluded):
    """A centroid view carries its own near clip ``near_fraction · d_cam`` (probes too),
    so a faint floater (α = 0.06 ≥ τ_sig) 2 % of d_cam in front of it — invisible to
    eq:occfrac, which reads D_med — does not set D_min over the image (that would make
    eq:behind-gate drop voxels behind see-through pixels). ``near_fraction = 0``
    restores the renderer's near alone."""
    from divas_engine.geometry import rotmat_to_quat
    from divas_engine.render.surfel_renderer import SurfelRenderer
    from divas_engine.scene import SurfelScene

    s, r, planner = occluded
    anchor, buf, click = _occluded_click(s, r)
    cv = planner.centroid_view(anchor, click, buf)
    cam = cv.camera
    assert cam.near == pytest.approx(0.05 * cv.d_cam) and cv.d_cam > 0
    assert Camera.from_dict(cv.to_dict()["camera"]).near == cam.near
    off = GsCentroidPlanner(s.scene, r, ViewConfig(near_fraction=0.0)).centroid_view(
        anchor, click, buf
    )
    assert off.camera.near == 0.0 and np.array_equal(off.camera.c2w, cam.c2w)
    with pytest.raises(ValueError, match="near_fraction"):
        ViewConfig(near_fraction=1.0)
    # the floater: a disc facing the camera at 0.02 d_cam, wide enough to fill the image
    sc = s.scene
    q = rotmat_to_quat(cam.c2w[None, :3, :3]).astype(np.float32)
    centre = (cam.center + 0.02 * cv.d_cam * cam.forward)[None]
    veil = SurfelScene(
        np.vstack([sc.means, centre]).astype(np.float32),
        np.vstack([sc.quats, q]),
        np.vstack([sc.scales, np.full((1, 2), 0.2 * cv.d_cam)]).astype(np.float32),
        np.append(sc.opacities, np.float32(0.06)),
        np.concatenate([sc.sh, sc.sh[:1]]),
        sc.sh_degree,
    )
    rv = SurfelRenderer(veil, device="cpu")
    h, w = cam.height // 2, cam.width // 2
    seen = rv.render(off.camera).D_min
    assert seen[h, w] == pytest.approx(0.02 * cv.d_cam, rel=1e-3)
    clipped = rv.render(cam).D_min
    assert np.array_equal(clipped, r.render(cam).D_min)  # as if the floater were not there
    assert clipped[h, w] > 0.5 * cv.d_cam
