"""``load_scene(..., max_sh_degree=d)``: the scene keeps the SH bands up to ``d`` and
everything else exactly as a full load (``divas info`` loads the DC only)."""

from __future__ import annotations

import json

import numpy as np
import plyfile
import pytest

from divas_engine import load_scene
from divas_engine.io.ply import write_ply_rows
from divas_engine.scene_stats import robust_frame

from .test_io_ply import _divas, _gaussian_rows


def _same_but_sh(a, b, k: int) -> None:
    for name in ("means", "quats", "scales", "opacities", "scale_n"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(a.source.kept_rows, b.source.kept_rows)
    assert a.source.dropped_nonfinite == b.source.dropped_nonfinite
    assert a.sh.shape == (len(b), k, 3) and a.sh.flags.c_contiguous
    assert np.array_equal(a.sh, b.sh[:, :k])


def _rows_with_bad_values():
    rows = _gaussian_rows(60, 3, 3, np.random.default_rng(7))
    rows["f_rest_40"][5] = np.nan  # channel 2, degree 3: a band DC-only does not keep
    rows["f_dc_1"][7] = np.inf  # the DC itself
    rows["f_rest_2"][9] = -np.inf  # channel 0, degree 1
    rows["f_rest_20"][11] = np.nan  # channel 1, degree 2
    bad = {5, 7, 9, 11}
    return rows, bad


@pytest.mark.parametrize("layout", ["little", "big"])  # float32 view path, per-property path
def test_kept_bands_and_the_same_dropped_rows(tmp_path, layout):
    rows, bad = _rows_with_bad_values()
    path = tmp_path / "s.ply"
    if layout == "little":
        write_ply_rows(path, {"vertex": rows})
    else:
        el = plyfile.PlyElement.describe(rows, "vertex")
        plyfile.PlyData([el], byte_order=">").write(str(path))
    full = load_scene(path)
    assert full.sh_degree == 3 and full.source.file_sh_degree is None
    # the rows with a non-finite value in *any* band are dropped, whatever is kept
    assert set(range(60)) - set(full.source.kept_rows.tolist()) == bad
    for d in (0, 1, 2):
        part = load_scene(path, max_sh_degree=d)
        assert part.sh_degree == d and part.source.file_sh_degree == 3
        _same_but_sh(part, full, (d + 1) ** 2)
    for d in (3, 5):
        same = load_scene(path, max_sh_degree=d)
        assert same.sh_degree == 3 and same.source.file_sh_degree is None
        _same_but_sh(same, full, 16)


def test_other_formats_drop_the_bands_after_decoding(real_data):
    path = real_data / "playcanvas-sog" / "playbot_lod3"  # SOG with SH degree 2
    full = load_scene(path)
    assert full.sh_degree > 0
    part = load_scene(path, max_sh_degree=0)
    assert part.source.file_sh_degree == full.sh_degree == 2 and part.source.format == "sog"
    _same_but_sh(part, full, 1)


def test_info_reports_the_file_degree_and_the_full_load_statistics(tmp_path):
    rows, _ = _rows_with_bad_values()
    path = tmp_path / "s.ply"
    write_ply_rows(path, {"vertex": rows})
    info = json.loads(_divas("info", path, "--json").stdout)
    full = load_scene(path)
    fr = robust_frame(full.means)
    assert info["sh_degree"] == 3 and info["count"] == len(full) == 56
    assert info["center"] == fr.center.tolist() and info["radius_p99"] == fr.radius
    assert info["opacity"]["median"] == float(np.percentile(full.opacities, 50))


def test_robust_frame_equals_the_float64_reference():
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 1001):
        p = (rng.standard_normal((n, 3)) * 40.0 + 3.0).astype(np.float32)
        q = p.astype(np.float64)
        c = np.median(q, axis=0)
        r = float(np.percentile(np.linalg.norm(q - c, axis=1), 99.0))
        fr = robust_frame(p)
        assert np.array_equal(fr.center, c) and fr.radius == r
