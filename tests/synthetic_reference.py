"""Committed reference of the 2DGS synthetic generator's files, compared with tolerances.

``decode(folder)`` turns the files ``generate_scene(name, folder, **PARAMS)`` writes into
arrays, read with ``plyfile`` / ``numpy`` / ``json`` (not the engine's readers): ``ply/<column>``
(the first :data:`ROWS` rows, a random third of the scene) and ``ply_stats/<column>``
(``[Σx, Σ|x|, Σx², min, max]``), the label, surface-id and grid arrays whole, and
``json/<file>`` (compared value by value). ``compare(ref, got)`` returns the differences beyond
the tolerances; ``python -m tests.synthetic_reference`` rewrites
``tests/data/synthetic_reference/<scene>.npz``.

Tolerances: OpenBLAS picks its ``ddot`` / ``dgemm`` kernels and NumPy its SIMD ``exp`` per CPU,
so float64 values differ by a few ulps and float32 ones by at most one. Floats are compared with
``rtol`` :data:`RTOL` plus :data:`ATOL` × the array's largest magnitude; up to
:data:`FLIP_FRACTION` (at least one) of the integers and booleans that come out of float
comparisons may flip at ulp-level ties, while any change to the generator moves far more.
"""

from __future__ import annotations

import io
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import plyfile

REFERENCE_DIR = Path(__file__).parent / "data" / "synthetic_reference"
#: arguments of ``generate_scene`` for the reference
PARAMS = {"size": 3000, "seed": 3, "grid_resolution": 16}
#: PLY rows stored whole (the rest enter through the per-column statistics)
ROWS = 1000
RTOL = 1e-5
ATOL = 1e-6
#: absolute floor of every float tolerance (all-zero columns such as the PLY normals)
TINY = 1e-30
#: fraction of float-decided integers / grid cells that may differ (at least one element)
FLIP_FRACTION = 1e-3
#: JSON keys whose integer value counts float decisions (compared like integer arrays)
COUNTED_KEYS = ("label_voxels",)
#: JSON keys holding the cameras that see a click (a float decision per camera)
VISIBILITY_KEYS = ("visible_in",)


def reference_path(name: str) -> Path:
    return REFERENCE_DIR / f"{name}.npz"


def decode(folder: Path) -> dict[str, np.ndarray]:
    """The arrays of the generator's files in ``folder`` (see the module docstring)."""
    folder = Path(folder)
    out: dict[str, np.ndarray] = {}
    for path in sorted(folder.iterdir()):
        if path.name == "scene.ply":
            rows = plyfile.PlyData.read(path)["vertex"].data
            for col in rows.dtype.names:
                x = np.asarray(rows[col])
                out[f"ply/{col}"] = x[:ROWS].copy()
                x64 = x.astype(np.float64)
                out[f"ply_stats/{col}"] = np.array(
                    [x64.sum(), np.abs(x64).sum(), (x64 * x64).sum(), x64.min(), x64.max()]
                )
        elif path.suffix == ".npy":
            out[path.stem] = np.load(path)
        elif path.suffix == ".npz":
            with np.load(path) as z:
                out.update({f"grid/{k}": z[k] for k in z.files})
        elif path.suffix == ".json":
            out[f"json/{path.name}"] = np.frombuffer(path.read_bytes(), np.uint8)
        else:
            raise AssertionError(f"unexpected generated file {path.name}")
    return out


def _allowed_flips(n: int) -> int:
    return max(1, int(FLIP_FRACTION * n))


def _compare_floats(key: str, ref: np.ndarray, got: np.ndarray, frac: bool) -> list[str]:
    ref64, got64 = ref.astype(np.float64), got.astype(np.float64)
    scale = float(np.max(np.abs(ref64))) if ref64.size else 0.0
    close = np.isclose(got64, ref64, rtol=RTOL, atol=ATOL * scale + TINY)
    bad = int((~close).sum())
    if bad == 0 or (frac and bad <= _allowed_flips(close.size)):
        return []
    worst = float(np.max(np.abs(got64 - ref64)[~close]))
    return [f"{key}: {bad} of {close.size} values off (largest difference {worst:.3g})"]


def _compare_ints(key: str, ref: np.ndarray, got: np.ndarray) -> list[str]:
    bad = int((ref != got).sum())
    if bad <= (_allowed_flips(ref.size) if ref.size else 0):
        return []
    return [f"{key}: {bad} of {ref.size} elements differ (allowed {_allowed_flips(ref.size)})"]


def _compare_stats(key: str, ref: np.ndarray, got: np.ndarray) -> list[str]:
    s, sabs, ssq, lo, hi = ref
    big = max(abs(lo), abs(hi))
    tol = RTOL * np.array([sabs, sabs, ssq, big, big]) + TINY
    if np.all(np.abs(got - ref) <= tol):
        return []
    return [f"{key}: [Σx, Σ|x|, Σx², min, max] {got.tolist()} != {ref.tolist()}"]


def _compare_json(path: str, ref, got) -> list[str]:
    if isinstance(ref, dict):
        if not isinstance(got, dict) or set(ref) != set(got):
            return [f"{path}: keys {sorted(got) if isinstance(got, dict) else got!r}"]
        out = []
        for k in ref:
            key = f"{path}.{k}"
            if k in VISIBILITY_KEYS:
                diff = set(ref[k]) ^ set(got[k])
                if len(diff) > _allowed_flips(len(ref[k])):
                    out.append(f"{key}: cameras differ {sorted(diff)}")
            elif k in COUNTED_KEYS:
                if abs(ref[k] - got[k]) > _allowed_flips(ref[k]):
                    out.append(f"{key}: {got[k]} != {ref[k]}")
            else:
                out += _compare_json(key, ref[k], got[k])
        return out
    if isinstance(ref, list):
        if not isinstance(got, list) or len(ref) != len(got):
            return [f"{path}: a list of {len(ref)} became {got!r:.80}"]
        pairs = enumerate(zip(ref, got))
        return [e for i, (a, b) in pairs for e in _compare_json(f"{path}[{i}]", a, b)]
    if isinstance(ref, float) and not isinstance(got, bool) and isinstance(got, (int, float)):
        if math.isclose(got, ref, rel_tol=RTOL, abs_tol=1e-9):
            return []
        return [f"{path}: {got!r} != {ref!r}"]
    if type(ref) is not type(got) or ref != got:
        return [f"{path}: {got!r} != {ref!r}"]
    return []


def compare(ref: dict[str, np.ndarray], got: dict[str, np.ndarray]) -> list[str]:
    """Differences between two :func:`decode` results beyond the tolerances ([] if none)."""
    if set(ref) != set(got):
        return [f"arrays: {sorted(set(ref) ^ set(got))} only on one side"]
    out: list[str] = []
    for key in sorted(ref):
        a, b = np.asarray(ref[key]), np.asarray(got[key])
        if key.startswith("json/"):
            out += _compare_json(key, json.loads(a.tobytes()), json.loads(b.tobytes()))
        elif a.shape != b.shape or a.dtype != b.dtype:
            out.append(f"{key}: {b.dtype}{b.shape} != {a.dtype}{a.shape}")
        elif key.startswith("ply_stats/"):
            out += _compare_stats(key, a, b)
        elif a.dtype.kind == "f":
            # grid cells follow the shell that owns them, a float decision between surfaces
            out += _compare_floats(key, a, b, frac=key.startswith("grid/"))
        else:
            out += _compare_ints(key, a, b)
    return out


def generate_and_decode(name: str) -> dict[str, np.ndarray]:
    from divas_engine.synthetic import generate_scene

    with tempfile.TemporaryDirectory() as d:
        generate_scene(name, d, **PARAMS)
        return decode(Path(d))


def load_reference(name: str) -> dict[str, np.ndarray]:
    with np.load(reference_path(name)) as z:
        return {k: z[k] for k in z.files}


def write_reference(name: str) -> Path:
    """Store the current generator's arrays of ``name`` (in the files' own dtypes)."""
    arrays = generate_and_decode(name)
    path = reference_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path.write_bytes(buf.getvalue())
    return path


def main(argv: list[str]) -> int:
    from divas_engine.synthetic import SCENE_NAMES

    for name in argv or SCENE_NAMES:
        p = write_reference(name)
        print(f"{p}: {p.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
