"""Per-voxel fusion accumulators and per-view contribution records (eq:compact-fusion,
eq:vmask).

A view's fusion kernel writes one dense contribution per active voxel
(``num``, ``den`` float32, ``kind`` uint8: 0 none, 1 thick vote, 2 thin vote). They are
compacted to a sparse record (active index + the same float32 values) that the
session keeps, and applied to the int64 fixed-point accumulators with sign ±1 — each
active index occurs once per record, so no atomics are needed and an undo subtracts
exactly the integers the add added.
"""

from __future__ import annotations

import warp as wp

from .fusion_common import QSCALE, quantize

__all__ = [
    "Records",
    "ContributionBuffers",
    "alloc_accumulators",
    "compact_contributions",
    "apply_records",
    "readout",
]

KIND_THICK = 1
KIND_THIN = 2


@wp.kernel
def _flag_kernel(kind: wp.array(dtype=wp.uint8), flags: wp.array(dtype=int)):
    a = wp.tid()
    flags[a] = wp.where(kind[a] != wp.uint8(0), 1, 0)


@wp.kernel
def _gather_kernel(
    kind: wp.array(dtype=wp.uint8),
    num: wp.array(dtype=float),
    den: wp.array(dtype=float),
    pos: wp.array(dtype=int),
    idx_out: wp.array(dtype=wp.int32),
    num_out: wp.array(dtype=float),
    den_out: wp.array(dtype=float),
    kind_out: wp.array(dtype=wp.uint8),
):
    a = wp.tid()
    if kind[a] != wp.uint8(0):
        j = pos[a]
        idx_out[j] = wp.int32(a)
        num_out[j] = num[a]
        den_out[j] = den[a]
        kind_out[j] = kind[a]


@wp.kernel
def _apply_kernel(
    idx: wp.array(dtype=wp.int32),
    num: wp.array(dtype=float),
    den: wp.array(dtype=float),
    kind: wp.array(dtype=wp.uint8),
    slot: int,
    sign: int,
    acc_w: wp.array(dtype=wp.int64),
    acc_z: wp.array(dtype=wp.int64),
    acc_wthin: wp.array(dtype=wp.int64),
    n_thick: wp.array(dtype=wp.int32),
    n_thin: wp.array(dtype=wp.int32),
    vmask: wp.array2d(dtype=wp.uint32),
):
    r = wp.tid()
    a = int(idx[r])
    s = wp.int64(sign)
    qn = quantize(num[r]) * s
    acc_w[a] = acc_w[a] + qn
    acc_z[a] = acc_z[a] + quantize(den[r]) * s
    if kind[r] == wp.uint8(2):
        acc_wthin[a] = acc_wthin[a] + qn
        n_thin[a] = n_thin[a] + wp.int32(sign)
    else:
        n_thick[a] = n_thick[a] + wp.int32(sign)
    if slot >= 0:  # eq:vmask, bit `slot` belongs to this view alone
        word = slot >> 5
        bit = wp.uint32(1) << wp.uint32(slot & 31)
        if sign > 0:
            vmask[a, word] = vmask[a, word] | bit
        else:
            vmask[a, word] = vmask[a, word] & ~bit


@wp.kernel
def _readout_kernel(
    acc_w: wp.array(dtype=wp.int64),
    acc_z: wp.array(dtype=wp.int64),
    z_eps: wp.int64,
    tau_cons: wp.float64,
    vmask: wp.array2d(dtype=wp.uint32),
    p_out: wp.array(dtype=wp.float64),
    seg: wp.array(dtype=wp.uint8),
    vmask_out: wp.array2d(dtype=wp.uint32),
):
    a = wp.tid()
    p = wp.float64(0.0)
    z = acc_z[a]
    if z > z_eps:  # eq:compact-fusion, denom > ε
        p = wp.float64(acc_w[a]) / wp.float64(z)
    p_out[a] = p
    s = p >= tau_cons
    seg[a] = wp.where(s, wp.uint8(1), wp.uint8(0))
    for k in range(vmask.shape[1]):  # alg:gs-fusion: v_x = vmask if P ≥ τ_cons else 0
        vmask_out[a, k] = wp.where(s, vmask[a, k], wp.uint32(0))


class Records:
    """One view's sparse contribution: ``idx [R] int32``, ``num``/``den [R] float32``,
    ``kind [R] uint8`` (1 thick, 2 thin)."""

    __slots__ = ("idx", "num", "den", "kind")

    def __init__(self, idx: wp.array, num: wp.array, den: wp.array, kind: wp.array):
        self.idx, self.num, self.den, self.kind = idx, num, den, kind

    def __len__(self) -> int:
        return self.idx.shape[0]

    @property
    def nbytes(self) -> int:
        return sum(a.capacity for a in (self.idx, self.num, self.den, self.kind))


def alloc_accumulators(n: int, words: int, device) -> dict[str, wp.array]:
    """Zeroed fixed-point accumulators of ``n`` active voxels: ``w``, ``z``, ``wthin``
    (int64, scale 2⁵²), ``n_thick``, ``n_thin`` (int32) and the view bitmask
    ``vmask [n, words]`` uint32 (``[0, 0]`` when ``words`` is 0: no bitmask)."""
    return {
        "w": wp.zeros(n, dtype=wp.int64, device=device),
        "z": wp.zeros(n, dtype=wp.int64, device=device),
        "wthin": wp.zeros(n, dtype=wp.int64, device=device),
        "n_thick": wp.zeros(n, dtype=wp.int32, device=device),
        "n_thin": wp.zeros(n, dtype=wp.int32, device=device),
        "vmask": wp.zeros((n if words else 0, words), dtype=wp.uint32, device=device),
    }


class ContributionBuffers:
    """One view's dense contribution per active voxel (``num``, ``den`` float32,
    ``kind`` uint8), written by a fusion kernel, plus the ``flags``/``pos`` scratch of
    :func:`compact_contributions`."""

    __slots__ = ("num", "den", "kind", "flags", "pos")

    def __init__(self, n: int, device) -> None:
        self.num = wp.zeros(n, dtype=float, device=device)
        self.den = wp.zeros(n, dtype=float, device=device)
        self.kind = wp.zeros(n, dtype=wp.uint8, device=device)
        self.flags = wp.zeros(n, dtype=int, device=device)
        self.pos = wp.zeros(n, dtype=int, device=device)


def compact_contributions(
    num: wp.array, den: wp.array, kind: wp.array, flags: wp.array, pos: wp.array, device=None
) -> Records:
    """Sparse :class:`Records` of the voxels with ``kind != 0`` (``flags``/``pos``:
    ``[A] int`` scratch)."""
    device = device or num.device
    n = num.shape[0]
    if n == 0:
        return Records(
            *(wp.zeros(0, dtype=t, device=device) for t in (wp.int32, float, float, wp.uint8))
        )
    wp.launch(_flag_kernel, dim=n, inputs=[kind, flags], device=device)
    wp.utils.array_scan(flags, pos, inclusive=True)
    count = int(pos[n - 1 : n].numpy()[0])
    rec = Records(
        wp.empty(count, dtype=wp.int32, device=device),
        wp.empty(count, dtype=float, device=device),
        wp.empty(count, dtype=float, device=device),
        wp.empty(count, dtype=wp.uint8, device=device),
    )
    if count:
        wp.utils.array_scan(flags, pos, inclusive=False)
        wp.launch(
            _gather_kernel,
            dim=n,
            inputs=[kind, num, den, pos, rec.idx, rec.num, rec.den, rec.kind],
            device=device,
        )
    return rec


def apply_records(rec: Records, slot: int, sign: int, acc: dict, device=None) -> None:
    """Add (``sign=+1``) or subtract (``-1``) a record; set/clear bit ``slot`` (−1: none)."""
    if len(rec) == 0:
        return
    device = device or rec.idx.device
    wp.launch(
        _apply_kernel,
        dim=len(rec),
        inputs=[
            rec.idx,
            rec.num,
            rec.den,
            rec.kind,
            int(slot),
            int(sign),
            acc["w"],
            acc["z"],
            acc["wthin"],
            acc["n_thick"],
            acc["n_thin"],
            acc["vmask"],
        ],
        device=device,
    )


def readout(
    acc: dict, eps: float, tau_cons: float, device=None
) -> tuple[wp.array, wp.array, wp.array]:
    """P ``[A] float64``, V_seg ``[A] uint8`` and the P-masked view bitmask."""
    w = acc["w"]
    device = device or w.device
    n = w.shape[0]
    p = wp.empty(n, dtype=wp.float64, device=device)
    seg = wp.empty(n, dtype=wp.uint8, device=device)
    vm = wp.empty(acc["vmask"].shape, dtype=wp.uint32, device=device)
    if n:
        z_eps = int(eps * QSCALE)
        wp.launch(
            _readout_kernel,
            dim=n,
            inputs=[w, acc["z"], wp.int64(z_eps), wp.float64(tau_cons), acc["vmask"], p, seg, vm],
            device=device,
        )
    return p, seg, vm
