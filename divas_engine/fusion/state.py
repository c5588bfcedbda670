"""Incremental, exactly undoable fusion state (eq:compact-fusion, eq:vmask).

Per active voxel the state keeps int64 fixed-point accumulators (scale 2⁵², see
``divas_kernels.fusion_common.QSCALE``): numerator W, denominator Z, the thin part of W,
thick/thin vote counts and the view-coverage bitmask. Adding a view runs its kernel
once over the active voxels, compacts the non-zero contributions into a sparse
record (active index + float32 num/den + kind) that is kept per view, and adds the
quantised record; undo subtracts the same integers.

Why fixed point: integer addition is associative and exactly invertible, so any
sequence of adds and undos, a full re-fuse in any order, and any device's launch
order all give *bit-identical* W and Z — float sums would drift with order and an
undo would leave residues. Each float32 contribution ≥ 2⁻²⁸ is represented exactly
at 2⁻⁵², so the sums are the exact sums of the kernel's float32 values. With
contributions in [0, 1] the accumulators hold up to 2¹¹ views without overflow.

The bitmask bit of a view is its *slot* (0 … max_views−1); a freed slot is reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_kernels import (
    QSCALE,
    ContributionBuffers,
    DeviceArray,
    Records,
    ViewData,
    alloc_accumulators,
    apply_records,
    compact_contributions,
    readout,
    resolve_device,
)

from .views import FusionView, upload_view

__all__ = ["IncrementalFusion", "FusionResult", "FusionCapacityError"]


class FusionCapacityError(RuntimeError):
    """More live views than the view-coverage bitmask can hold (``max_views``, when known)."""

    def __init__(self, message: str, max_views: int | None = None):
        super().__init__(message)
        self.max_views = max_views


@dataclass(eq=False)
class FusionResult:
    """Fused per-active-voxel outputs (host copies).

    Attributes:
        P: ``[A] float64`` eq:compact-fusion probability.
        segmented: ``[A] bool`` V_seg = P ≥ τ_cons.
        vmask: ``[A, words] uint32`` view bitmask, zeroed where P < τ_cons (2DGS) or None.
        vmask_raw: the bitmask before the P mask (None for NeRF).
        W, Z, W_thin: ``[A] float64`` sums (fixed point / 2⁵²).
        n_thick, n_thin: ``[A] int32`` accepted thick / thin votes.
    """

    P: np.ndarray
    segmented: np.ndarray
    vmask: np.ndarray | None
    vmask_raw: np.ndarray | None
    W: np.ndarray
    Z: np.ndarray
    W_thin: np.ndarray
    n_thick: np.ndarray
    n_thin: np.ndarray


class IncrementalFusion:
    """Base of :class:`~divas_engine.fusion.gs_fusion.GsFusion` and
    :class:`~divas_engine.fusion.nerf_fusion.NerfFusion`. Subclasses implement
    :meth:`_launch` (fill ``self._num/_den/_kind`` for one uploaded view)."""

    def __init__(
        self,
        n_active: int,
        *,
        max_views: int | None,
        eps: float,
        tau_cons: float,
        mask_pos: float,
        k_dg: float,
        device,
    ) -> None:
        self.device = resolve_device(device)
        self.n_active = int(n_active)
        self.max_views = max_views
        self._eps, self._tau_cons, self._mask_pos, self._k_dg = eps, tau_cons, mask_pos, k_dg
        words = 0 if max_views is None else (max_views + 31) // 32
        self._acc = alloc_accumulators(self.n_active, words, self.device)
        self._contrib = ContributionBuffers(self.n_active, self.device)
        c = self._contrib
        self._num, self._den, self._kind = c.num, c.den, c.kind
        self._records: dict[int, Records] = {}
        self._next_id = 0

    # --- subclass hook -------------------------------------------------------------
    def _launch(self, vd: ViewData) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- public API ----------------------------------------------------------------
    @property
    def view_ids(self) -> list[int]:
        """Ids of the live views (2DGS: the bitmask bit of each view)."""
        return sorted(self._records)

    def _free_slot(self) -> int:
        if self.max_views is None:
            while self._next_id in self._records:
                self._next_id += 1
            return self._next_id
        for s in range(self.max_views):
            if s not in self._records:
                return s
        raise FusionCapacityError(
            f"the view-coverage bitmask holds {self.max_views} views and all are in use; "
            f"undo a view or raise max_views",
            self.max_views,
        )

    def upload(self, view: FusionView) -> ViewData:
        return upload_view(
            view, mask_pos=self._mask_pos, k_dg=self._k_dg, eps=self._eps, device=self.device
        )

    def add_view(self, view: FusionView, view_id: int | None = None) -> int:
        """Fuse one view (only this view's kernel runs); returns its id."""
        if view_id is None:
            view_id = self._free_slot()
        elif view_id in self._records:
            raise ValueError(f"view id {view_id} is already fused")
        elif self.max_views is not None and not 0 <= view_id < self.max_views:
            raise FusionCapacityError(
                f"view id {view_id} outside the bitmask [0, {self.max_views})", self.max_views
            )
        vd = self.upload(view)
        self._launch(vd)
        c = self._contrib
        rec = compact_contributions(c.num, c.den, c.kind, c.flags, c.pos, device=self.device)
        apply_records(
            rec, view_id if self.max_views is not None else -1, +1, self._acc, device=self.device
        )
        self._records[view_id] = rec
        return view_id

    def remove_view(self, view_id: int) -> None:
        """Undo a view exactly (subtracts the integers its add added, clears its bit)."""
        try:
            rec = self._records.pop(view_id)
        except KeyError:
            raise KeyError(f"view id {view_id} is not fused (live: {self.view_ids})") from None
        apply_records(
            rec, view_id if self.max_views is not None else -1, -1, self._acc, device=self.device
        )

    def reset(self) -> None:
        for a in self._acc.values():
            a.zero_()
        self._records.clear()
        self._next_id = 0

    def record_bytes(self) -> int:
        return sum(r.nbytes for r in self._records.values())

    def device_result(self) -> tuple[DeviceArray, DeviceArray, DeviceArray]:
        """(P [A] float64, V_seg [A] uint8, masked bitmask [A, words] uint32) on device."""
        return readout(self._acc, self._eps, self._tau_cons, device=self.device)

    def result(self) -> FusionResult:
        p, seg, vm = self.device_result()
        has_mask = self.max_views is not None
        q = 1.0 / QSCALE
        return FusionResult(
            P=p.numpy(),
            segmented=seg.numpy().astype(bool),
            vmask=vm.numpy() if has_mask else None,
            vmask_raw=self._acc["vmask"].numpy() if has_mask else None,
            W=self._acc["w"].numpy().astype(np.float64) * q,
            Z=self._acc["z"].numpy().astype(np.float64) * q,
            W_thin=self._acc["wthin"].numpy().astype(np.float64) * q,
            n_thick=self._acc["n_thick"].numpy(),
            n_thin=self._acc["n_thin"].numpy(),
        )

    def accumulators(self) -> dict[str, np.ndarray]:
        """Raw int accumulators (tests compare these for bit-exactness)."""
        return {k: v.numpy() for k, v in self._acc.items()}
