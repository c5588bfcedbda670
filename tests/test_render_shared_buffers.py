"""On the CPU the surfel renderer reads the scene's own float32 means and SH
(no second copy of the scene in Warp arrays); what it renders is unchanged (the render
tests compare the images against the NumPy reference)."""

from __future__ import annotations

import numpy as np

from divas_engine.render import make_renderer
from divas_engine.synthetic import generate_scene


def test_cpu_renderer_shares_the_scene_arrays(tmp_path):
    sc = generate_scene("ribs", tmp_path, size=3000, seed=1, grid_resolution=16, sh_degree=2)
    scene = sc.scene
    r = make_renderer(scene, device="cpu")
    buf = r._buf
    assert buf.sh.ptr == scene.sh.ctypes.data and buf.means.ptr == scene.means.ctypes.data
    assert buf.sh.shape == (len(scene), scene.sh.shape[1])
    # a Warp view of the same bytes: the values the kernels read are the scene's
    np.testing.assert_array_equal(buf.sh.numpy(), scene.sh)
    np.testing.assert_array_equal(buf.means.numpy(), scene.means)
