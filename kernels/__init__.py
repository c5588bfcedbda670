"""Warp kernels of DivAS. Every kernel runs on ``cpu`` and ``cuda``; the device is a
parameter of the Python wrapper, never hard-coded. The engine calls only the
wrappers listed in ``__all__`` (never ``wp.launch`` directly).
"""

__all__: list[str] = []
