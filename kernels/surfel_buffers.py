"""A surfel scene resident on one Warp device (:func:`upload_surfels`, once per scene)
and host gathers of some of its rows (:func:`surfel_rows`), shared by the rasterizer
(``divas_kernels.rasterize``) and the passes over its binnings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from . import render_defaults as RD
from .scratch import scratch_empty

__all__ = ["SurfelBuffers", "upload_surfels", "surfel_rows"]


@dataclass
class SurfelBuffers:
    """A surfel scene resident on one device (uploaded once).

    Attributes:
        means, tu, tv: ``[N]`` vec3 centre and scaled tangents ``s_1 R_0``, ``s_2 R_1``.
        opacity: ``[N]`` opacity.
        rho_cut: ``[N]`` ``2 ln(255·opacity)`` (≤ 0: never visible).
        sh: ``[N, K]`` vec3 SH coefficients; ``sh_degree`` 0..3.
    """

    means: wp.array
    tu: wp.array
    tv: wp.array
    opacity: wp.array
    rho_cut: wp.array
    sh: wp.array
    sh_degree: int
    device: wp.context.Device

    def __len__(self) -> int:
        return self.means.shape[0]


def upload_surfels(
    means: np.ndarray,
    rotations: np.ndarray,
    scales: np.ndarray,
    opacities: np.ndarray,
    sh: np.ndarray,
    sh_degree: int,
    device,
    alpha_min: float = RD.ALPHA_MIN,
) -> SurfelBuffers:
    """A surfel scene on ``device`` (a copy on CUDA; on the CPU the float32 arrays are
    shared, not copied). ``rotations`` ``[N,3,3]`` (columns t_u, t_v, n)."""
    n = len(means)
    if rotations.shape != (n, 3, 3) or scales.shape != (n, 2) or opacities.shape != (n,):
        raise ValueError("upload_surfels: inconsistent array shapes")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[1] != (sh_degree + 1) ** 2 or sh.shape[2] != 3:
        raise ValueError(f"upload_surfels: sh must be [N,{(sh_degree + 1) ** 2},3], got {sh.shape}")
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"upload_surfels: sh_degree {sh_degree} outside 0..3")
    tu = rotations[:, :, 0] * scales[:, :1]
    tv = rotations[:, :, 1] * scales[:, 1:2]
    op = np.asarray(opacities, dtype=np.float64)
    with np.errstate(divide="ignore"):
        rho_cut = np.where(op * 255.0 > 1.0, 2.0 * np.log(np.maximum(op, 1e-30) / alpha_min), -1.0)
    dev = wp.get_device(device)

    def put(a: np.ndarray, dtype) -> wp.array:
        # on the CPU the Warp array *is* the float32 NumPy array (no copy: the scene's
        # means and SH are held once); kernels only read these buffers
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=dev,
                        copy=not dev.is_cpu)  # fmt: skip

    return SurfelBuffers(
        means=put(means, wp.vec3),
        tu=put(tu, wp.vec3),
        tv=put(tv, wp.vec3),
        opacity=put(op, float),
        rho_cut=put(rho_cut, float),
        sh=put(sh, wp.vec3),
        sh_degree=int(sh_degree),
        device=device,
    )


def surfel_rows(buf: SurfelBuffers, rows: np.ndarray, colours: bool = True) -> SurfelBuffers:
    """The surfels ``rows`` of a CPU-resident ``buf`` as a scene of their own (a host
    gather of the uploaded arrays: the same float32 values, so a render of the rows is
    the render of those surfels in ``buf``). ``colours`` False: no SH (zero, degree 0),
    for value renders only. CPU only: on CUDA render the whole scene."""
    if not buf.device.is_cpu:
        raise ValueError("surfel_rows: a host gather, for CPU-resident surfels only")
    idx = np.asarray(rows, np.int64)
    dev = buf.device

    def take(a: wp.array, dtype) -> wp.array:
        out = scratch_empty((len(idx), *a.shape[1:]), dtype, dev)  # a pool's, in its scope
        # mode 'clip' (the rows are valid): 'raise' would buffer a copy of the output
        np.take(a.numpy(), idx, axis=0, out=out.numpy(), mode="clip")
        return out

    if not colours:
        sh = scratch_empty((len(idx), 1), wp.vec3, dev)
        sh.zero_()

    return SurfelBuffers(
        means=take(buf.means, wp.vec3),
        tu=take(buf.tu, wp.vec3),
        tv=take(buf.tv, wp.vec3),
        opacity=take(buf.opacity, float),
        rho_cut=take(buf.rho_cut, float),
        sh=take(buf.sh, wp.vec3) if colours else sh,
        sh_degree=buf.sh_degree if colours else 0,
        device=dev,
    )
