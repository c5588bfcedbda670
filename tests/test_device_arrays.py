"""The kernel boundary's device-array helpers against NumPy: growable
append buffers (the mapping's mask cache) keep every appended value at its offset."""

from __future__ import annotations

import numpy as np

import divas_kernels as dk


def test_device_append_grows_and_keeps_every_value(device):
    rng = np.random.default_rng(0)
    buf, used = dk.device_zeros(0, np.int32, device), 0
    expected: list[np.ndarray] = []
    offsets = []
    for size in (0, 5, 1, 17, 0, 64, 3):
        host = rng.integers(-(2**31), 2**31 - 1, size, dtype=np.int32)
        offsets.append(used)
        buf, used = dk.device_append(buf, used, host)
        expected.append(host)
        assert buf.shape[0] >= used
    ref = np.concatenate(expected)
    assert used == ref.size == 90
    got = buf.numpy()[:used]
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(got[offsets[3] : offsets[3] + 17], expected[3])


def test_device_append_capacity_doubles(device):
    buf, used = dk.device_zeros(4, np.uint8, device), 0
    buf, used = dk.device_append(buf, used, np.arange(4, dtype=np.uint8))
    assert buf.shape[0] == 4 and used == 4  # fits: no reallocation
    buf, used = dk.device_append(buf, used, np.array([9], np.uint8))
    assert buf.shape[0] == 8 and used == 5  # doubled, old values copied
    np.testing.assert_array_equal(buf.numpy()[:5], [0, 1, 2, 3, 9])


def test_to_device_and_zeros_round_trip(device):
    a = np.arange(12, dtype=np.uint32).reshape(4, 3)
    np.testing.assert_array_equal(dk.to_device(a, device).numpy(), a)
    z = dk.device_zeros(7, np.float32, device).numpy()
    assert z.dtype == np.float32 and not z.any()
