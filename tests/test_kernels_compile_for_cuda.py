"""Every kernel module compiles for CUDA (sm_75) with NVRTC, also on a machine without a
GPU (CI, and every session so far): the modules are found by their Warp kernels, so a new
one is covered without being listed. Running them on a GPU is covered by the tests marked
``cuda``."""

from __future__ import annotations

import importlib
import pkgutil

import pytest
import warp as wp

import divas_kernels


def _kernel_modules() -> list[str]:
    names = []
    for info in pkgutil.iter_modules(divas_kernels.__path__):
        mod = importlib.import_module(f"divas_kernels.{info.name}")
        if any(
            isinstance(v, wp.Kernel) and v.module.name == mod.__name__ for v in vars(mod).values()
        ):
            names.append(info.name)
    return names


def test_the_kernel_modules_are_found():
    # the ones the renderers, the fusion and the mapping run, at least
    want = {"rasterize", "tile_walk", "tile_binning", "raymarch", "fusion_gs"}
    want |= {"ngp_field", "raymarch_ngp"}  # instant-ngp networks
    assert want <= set(_kernel_modules())


@pytest.mark.parametrize("name", _kernel_modules())
def test_kernel_module_compiles_for_cuda(name, tmp_path):
    mod = importlib.import_module(f"divas_kernels.{name}")
    try:
        wp.compile_aot_module(mod, arch=75, module_dir=tmp_path)
    except Exception as e:  # noqa: BLE001 - a Warp without NVRTC
        if "nvrtc" in str(e).lower():
            pytest.skip(f"no NVRTC: {e}")
        raise
    assert any(p.suffix in (".cubin", ".ptx") for p in tmp_path.iterdir())
