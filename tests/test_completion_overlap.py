"""A view's records made while its sparse gather runs in the background: the edge
distance, the voxel evidence of the cover and the Gaussians' geometry
are made during the walk. Reference: the records made one step after the other — the
synchronous gather (:func:`sparse_contributions`), then :func:`gaussian_evidence` of the
Gaussians with a weight and :func:`voxel_evidence` of the final cover's voxels (the
sequential path). Bit-equal, with a kept binning, with the sub-scene path and when the
gather falls back to the full pass (then the voxel part covers every voxel)."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.mapping import CompletionConfig
from divas_engine.mapping.completion import VolumetricCompletion
from divas_engine.mapping.completion_gather import sparse_contributions
from divas_engine.mapping.completion_records import (
    QSCALE,
    edge_distance,
    gaussian_evidence,
    voxel_evidence,
)
from divas_engine.render import make_renderer

from . import test_completion
from .test_completion import CPU
from .test_completion_gather import _cap

ball = test_completion.ball  # the same module-scoped fixture: the ball scene and its 4 views


def _reference(comp, view, cover):
    """The records of ``view`` on ``cover``, one step after the other."""
    pos = np.asarray(view.mask).astype(np.float32) >= np.float32(comp.config.mask_threshold)
    rho = edge_distance(pos)
    rows = comp.cells.members(cover)
    out = sparse_contributions(
        comp._renderer, view.camera, pos, rows, comp.config.gather_max_fraction
    )
    if out is None:  # the full pass
        full = comp._renderer.contributions(view.camera, pos)
        rows, out, cover = np.arange(comp.n), (full.a1.numpy(), full.a0.numpy()), None
    a1, a0 = out[0].astype(np.float64), out[1].astype(np.float64)
    q1, q0 = np.rint(a1 * QSCALE).astype(np.int64), np.rint(a0 * QSCALE).astype(np.int64)
    nz = np.flatnonzero((q1 != 0) | (q0 != 0))
    g = rows[nz].astype(np.int32)
    seen, deep = gaussian_evidence(comp, view, pos, rho, g, a1[nz] + a0[nz])
    vox = None if cover is None else comp.cells.voxels_in(np.flatnonzero(cover))
    voxels, flags = voxel_evidence(comp, view, pos, rho, vox)
    return {
        "gauss": g, "q1": q1[nz], "q0": q0[nz], "seen": seen, "deep": deep,
        "voxels": voxels, "flags": flags, "cover": cover, "rho": rho,
    }  # fmt: skip


def _check(rec, ref):
    for f in ("gauss", "q1", "q0", "seen", "deep", "voxels", "flags"):
        assert np.array_equal(getattr(rec, f), ref[f]), f
        assert getattr(rec, f).dtype == ref[f].dtype, f
    assert (rec.cover is None) == (ref["cover"] is None)
    if rec.cover is not None:
        assert np.array_equal(rec.cover, ref["cover"])


@pytest.mark.parametrize("source", ["kept", "sub-scene", "full fallback"])
def test_overlapped_records_equal_the_sequential_ones(ball, source):
    scene, labels, parts, grid, act, views = ball
    frac = 0.0 if source == "full fallback" else 1.0
    cfg = CompletionConfig(gather_max_fraction=frac)
    r = make_renderer(scene, device=CPU)
    comp = VolumetricCompletion(scene, grid, act, cfg, device=CPU, renderer=r)
    assert comp._renderer is r
    sel, seg = _cap(labels, parts, act, len(grid), scene)
    cells = np.zeros(comp.cells.n + 1, bool)
    comp.cells.dilate_into(cells, np.flatnonzero(seg))
    cells = comp.cells.rings(np.flatnonzero(cells[:-1]), 1)
    assert 0 < cells.sum() < comp.cells.n
    for v in views:
        if source == "kept":
            r.render(v.camera)
            assert r.kept_binning(v.camera) is not None
        else:  # this renderer never rendered: nothing kept
            assert r.kept_binning(v.camera) is None
        ref = _reference(comp, v, cells)
        assert (ref["cover"] is None) == (source == "full fallback")
        assert len(ref["gauss"]) > 0 and len(ref["voxels"]) > 0
        rec = comp.view_record(v, cells.copy())
        _check(rec, ref)
        assert rec.mask is None
        # the cover's widening path (``_cover_record`` with a known edge distance)
        rec2 = comp._cover_record(v, cells.copy(), *comp._mask(v))
        _check(rec2, ref)
        # a record that covers nothing yet keeps the mask and its edge distance
        empty = comp.view_record(v, np.zeros(comp.cells.n + 1, bool))
        if empty.cover is not None:
            assert np.array_equal(empty.mask[1], ref["rho"])
