"""Device arrays for the engine: upload, allocation and synchronisation behind the
kernel boundary (the engine never calls Warp itself; it holds the arrays these return
and passes them back to the wrappers, reading results with ``array.numpy()``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._launch import init_warp, resolve_device

__all__ = [
    "DeviceArray",
    "Device",
    "to_device",
    "device_zeros",
    "device_append",
    "device_synchronize",
    "cuda_device_count",
    "is_device_array",
]

#: A Warp array resident on one device (what the wrappers take and return).
DeviceArray = wp.array
#: A Warp device (what :func:`resolve_device` returns).
Device = wp.Device


_WARP_DTYPES = {
    np.dtype(np.bool_): wp.bool,
    np.dtype(np.int8): wp.int8,
    np.dtype(np.uint8): wp.uint8,
    np.dtype(np.int16): wp.int16,
    np.dtype(np.uint16): wp.uint16,
    np.dtype(np.int32): wp.int32,
    np.dtype(np.uint32): wp.uint32,
    np.dtype(np.int64): wp.int64,
    np.dtype(np.uint64): wp.uint64,
    np.dtype(np.float16): wp.float16,
    np.dtype(np.float32): wp.float32,
    np.dtype(np.float64): wp.float64,
}


def _warp_dtype(dtype):
    try:
        return _WARP_DTYPES[np.dtype(dtype)]
    except KeyError:
        raise TypeError(f"no Warp scalar type for NumPy dtype {np.dtype(dtype)}") from None


def to_device(host: np.ndarray, device, *, dtype=None, vec3: bool = False) -> wp.array:
    """Copy ``host`` to ``device`` (C-contiguous, converted to ``dtype`` when given).

    ``vec3``: ``[N, 3]`` float32 rows become an ``[N]`` vec3 array.
    """
    dev = resolve_device(device) if not isinstance(device, wp.Device) else device
    a = np.ascontiguousarray(host, dtype=dtype)
    if vec3:
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.vec3, device=dev)
    return wp.array(a, dtype=_warp_dtype(a.dtype), device=dev)


def device_zeros(shape, dtype, device) -> wp.array:
    """A zero-filled device array of NumPy ``dtype``."""
    return wp.zeros(shape, dtype=_warp_dtype(dtype), device=device)


def device_append(buf: wp.array, used: int, host: np.ndarray) -> tuple[wp.array, int]:
    """Append ``host`` after the first ``used`` elements of the growable 1-D ``buf``
    (same device and element type); the capacity at least doubles when it runs out, so
    appends cost amortised O(len(host)). Returns ``(buf, used + len(host))`` — ``buf``
    is a new array when it grew (its first ``used`` elements copied over)."""
    host = np.ascontiguousarray(host).ravel()
    need = used + host.size
    if need > buf.shape[0]:
        grown = wp.empty(max(need, 2 * buf.shape[0]), dtype=buf.dtype, device=buf.device)
        if used:
            wp.copy(grown, buf, count=used)
        buf = grown
    if host.size:
        src = wp.array(host, dtype=buf.dtype, device=buf.device)
        wp.copy(buf, src, dest_offset=used, count=host.size)
    return buf, need


def device_synchronize(device) -> None:
    """Wait for every launch queued on ``device``."""
    wp.synchronize_device(device)


def cuda_device_count() -> int:
    """CUDA devices Warp can use (0 on a machine without a driver)."""
    init_warp()
    return int(wp.get_cuda_device_count())


def is_device_array(a) -> bool:
    return isinstance(a, wp.array)
