"""An RGB render keeps its per-surfel colours (and the extra value channels
blended with them) in depth order — row ``j`` is the colour of the ``j``-th visible
splat, surfel ``ids[j]`` — so the blend reads them in the order it walks the splats.
Checked against an independent NumPy evaluation of the SH colours, in one pass and with
the culling pass first, with and without candidate rows, and a second RGB render that
reuses the kept colours equals a fresh one bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.render import RenderConfig
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_kernels import rasterize_surfels

from .reference_render import sh_colors
from .test_render_fused_values import scenes  # noqa: F401  (2DGS and 3DGS-derived cases)

#: every test on both scene kinds, in one pass and with the culling pass first
pytestmark = [
    pytest.mark.parametrize("kind", ["2dgs", "3dgs"]),
    pytest.mark.parametrize("two_pass", [False, True]),
]


def _settings(cam: Camera, two_pass: bool):
    s = RenderConfig().raster_settings(cam)
    if two_pass:
        s.cull_pass_min = 0  # the culling pass first
    return s


def test_kept_colours_are_the_visible_splats_colours(scenes, kind, two_pass, device):  # noqa: F811
    sc, cams = scenes[kind][:2]
    buf = SurfelRenderer(sc, device=device).surfel_buffers
    rng = np.random.default_rng(2)
    for cam in cams:
        args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        s = _settings(cam, two_pass)
        full = rasterize_surfels(buf, *args, s, keep_binning=True).binning
        rows = np.union1d(full.ids.numpy()[: full.n_visible], rng.choice(len(sc), len(sc) // 4))
        for rw in (None, rows):
            b = rasterize_surfels(buf, *args, s, keep_binning=True, rows=rw).binning
            n = b.n_visible
            assert n > 0 and b.colors.shape[0] >= n
            ids = b.ids.numpy()[:n]
            dirs = sc.means[ids].astype(np.float64) - cam.center
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            ref = sh_colors(sc.sh[ids], sc.sh_degree, dirs)  # float64, NumPy
            np.testing.assert_allclose(b.colors.numpy()[:n], ref, rtol=1e-4, atol=1e-5)


def test_one_two_passes_and_reuse_render_the_same_bits(scenes, kind, two_pass, device):  # noqa: F811
    sc, cams = scenes[kind][:2]
    buf = SurfelRenderer(sc, device=device).surfel_buffers
    extra = np.random.default_rng(3).random((len(sc), 2), dtype=np.float32)
    for cam in cams:
        args = (cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        one = rasterize_surfels(buf, *args, _settings(cam, False), keep_binning=True)
        other = rasterize_surfels(buf, *args, _settings(cam, two_pass), keep_binning=True)
        again = rasterize_surfels(buf, *args, _settings(cam, two_pass), binning=other.binning)
        n = one.binning.n_visible
        assert (
            other.binning.colors.numpy()[:n].tobytes() == one.binning.colors.numpy()[:n].tobytes()
        )
        for k in ("feat", "alpha", "d_min", "d_med", "n_samp"):
            a = getattr(one.out, k).numpy()
            assert np.array_equal(a, getattr(other.out, k).numpy()), k
            assert np.array_equal(a, getattr(again.out, k).numpy()), k
        # the value channels blended with the RGB (in depth order too) are a value render
        s = _settings(cam, two_pass)
        fused = rasterize_surfels(buf, *args, s, extra=extra).out.feat.numpy()
        alone = rasterize_surfels(buf, *args, s, values=extra).out.feat.numpy()
        assert np.array_equal(fused[:, 3:], alone)
        assert np.array_equal(fused[:, :3], one.out.feat.numpy())
