"""A CPU render that replaces a kept view binning writes its splats into the
dropped binning's array (no fresh pages to fault in) — only when nothing else holds that
binning or its array — and renders the same bits as a renderer that never recycles.
Checked in one pass and with the culling pass first, on 2DGS and 3DGS-derived scenes,
through views whose visible counts grow and shrink (the donor fits, is too small, or
is too large to be kept), and with the dropped binning held by someone else."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from divas_engine.render import RenderConfig
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_kernels import recycling
from divas_kernels.scratch import RECYCLE_SLACK, scratch_empty

from .test_render_fused_values import scenes  # noqa: F401  (2DGS and 3DGS-derived cases)


@pytest.fixture(params=[False, True], ids=["one_pass", "two_pass"])
def two_pass(request, monkeypatch) -> bool:
    if request.param:  # every render culls first (the 3M path), whatever the scene size
        made = RenderConfig.raster_settings

        def settings(self, camera=None):
            s = made(self, camera)
            s.cull_pass_min = 0
            return s

        monkeypatch.setattr(RenderConfig, "raster_settings", settings)
    return request.param


def _renderer(sc, device, recycle: bool) -> SurfelRenderer:
    r = SurfelRenderer(sc, device=device)
    r.binning_cache = 1  # every new camera replaces the kept binning
    r.recycle_binnings = recycle
    return r


def _cameras(cams):
    """Each camera and the same shifted by a quarter pixel (about as many visible splats:
    the donor fits), a zoom (fewer: the donor is too large to be kept) and the first
    camera again (more: too small)."""
    out = []
    for c in cams:
        out += [c, replace(c, cx=c.cx + 0.25)]
    zoom = replace(cams[0], fx=3 * cams[0].fx, fy=3 * cams[0].fy)
    return [*out, zoom, cams[0]]


@pytest.mark.parametrize("kind", ["2dgs", "3dgs"])
def test_recycled_renders_equal_fresh_ones_bit_for_bit(scenes, kind, two_pass, device):  # noqa: F811
    sc, cams = scenes[kind][:2]
    fresh, reused = _renderer(sc, device, False), _renderer(sc, device, True)
    taken, fits = 0, 0
    for cam in _cameras(cams):
        old = reused._binnings[0].splats if reused._binnings else None
        old = None if old is None else (old.ptr, old.capacity)
        a, b = fresh.render(cam), reused.render(cam)
        kept = reused._binnings[0]
        need = max(kept.n_visible, 1) * wp.types.type_size_in_bytes(kept.splats.dtype)
        ptr = kept.splats.ptr if hasattr(kept.splats, "_divas_scratch") else None
        del kept  # (a reference held here would keep it from being recycled)
        for name, x in a.as_dict().items():
            np.testing.assert_array_equal(x, b.as_dict()[name], err_msg=name)
        np.testing.assert_array_equal(
            fresh.render_values(cam, np.arange(len(sc), dtype=np.float32)),
            reused.render_values(cam, np.arange(len(sc), dtype=np.float32)),
        )
        taken += int(old is not None and ptr == old[0])
        fits += int(old is not None and need <= old[1] <= RECYCLE_SLACK * need)
    assert 2 <= fits < len(_cameras(cams)) - 1  # both kinds happen
    # every dropped array that fits is taken (CPU only)
    assert taken == (fits if wp.get_device(device).is_cpu else 0)


def test_a_held_binning_or_a_view_of_its_splats_is_not_recycled(scenes, two_pass):  # noqa: F811
    sc, cams = scenes["2dgs"][:2]
    r = _renderer(sc, "cpu", True)
    r.render(cams[0])
    held = r.kept_binning(cams[0])
    before = held.splats.numpy().copy()
    r.render(cams[1])  # drops cams[0]'s binning: someone holds it
    assert held.splats is not None
    assert r._binnings[0].splats.ptr != held.splats.ptr
    np.testing.assert_array_equal(held.splats.numpy(), before)
    del held
    view = r.kept_binning(cams[1]).splats.numpy()  # only a NumPy view of the array
    before = view.copy()
    r.render(cams[0])
    np.testing.assert_array_equal(view, before)
    assert r._binnings[0].splats.ptr != view.ctypes.data
    del view
    ptr = r._binnings[0].splats.ptr  # nothing holds it now: a next view of as many
    r.render(replace(cams[0], cx=cams[0].cx + 0.25))  # visible splats takes it
    assert r._binnings[0].splats.ptr == ptr and hasattr(r._binnings[0].splats, "_divas_scratch")


def test_a_donor_serves_one_kept_request_of_its_dtype_within_the_slack():
    donor = wp.empty(1000, dtype=wp.vec3, device="cpu")
    ptr = donor.ptr
    donors = [donor]
    del donor
    with recycling(donors):
        other = scratch_empty(500, wp.int32, "cpu", kept=True)  # another dtype: fresh
        unkept = scratch_empty(900, wp.vec3, "cpu")  # not kept: fresh
        arr = scratch_empty((900,), wp.vec3, "cpu", kept=True)
        again = scratch_empty(900, wp.vec3, "cpu", kept=True)  # the donor is spent
    assert arr.ptr == ptr and arr.shape == (900,) and arr.capacity == 1000 * 12
    assert ptr not in (other.ptr, unkept.ptr, again.ptr) and donors == []
    arr.numpy()[:] = 1.0  # the memory is the new array's
    for n in (int(1000 / RECYCLE_SLACK) - 1, 1001):  # too large a donor, too small
        donors = [wp.empty(1000, dtype=wp.vec3, device="cpu")]
        with recycling(donors):
            got = scratch_empty(n, wp.vec3, "cpu", kept=True)
        assert donors == [] and got.shape == (n,) and not hasattr(got, "_divas_scratch")


def test_a_recycled_array_recycled_again_keeps_the_first_owner():
    owner = wp.empty(100, dtype=wp.vec3, device="cpu")
    ptr, arr = owner.ptr, owner
    for _ in range(3):  # each render's binning: the memory's owner stays the first array
        donors = [arr]
        del arr
        with recycling(donors):
            arr = scratch_empty(90, wp.vec3, "cpu", kept=True)
        assert arr.ptr == ptr and arr._divas_scratch is owner


def test_the_reference_count_test_takes_only_what_nothing_else_holds():
    from divas_engine.render.surfel_renderer import _UNSHARED, _Probe, _take_unshared_splats

    # (outside the asserts: pytest's rewriting of an assert holds its temporaries)
    got = _take_unshared_splats(_Probe(), _UNSHARED)  # a temporary: taken
    assert got is not None
    held = _Probe()
    got = _take_unshared_splats(held, _UNSHARED)
    assert got is None and held.splats is not None
    kept = object()

    def probe_of(splats) -> _Probe:
        probe = _Probe()
        probe.splats = splats
        return probe

    got = _take_unshared_splats(probe_of(object()), _UNSHARED)  # the same, made apart
    assert got is not None
    got = _take_unshared_splats(probe_of(kept), _UNSHARED)  # a temporary; its splats held
    assert got is None
