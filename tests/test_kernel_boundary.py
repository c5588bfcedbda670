"""The kernel boundary: the engine reaches Warp only through the
wrappers of ``divas_kernels.__all__``."""

from __future__ import annotations

import ast
from pathlib import Path

import divas_kernels

ENGINE = Path(__file__).resolve().parents[1] / "divas_engine"
#: Engine modules allowed to import Warp themselves: none (allocation, upload and growth
#: of device buffers live in ``kernels/device_arrays.py``).
WARP_ALLOWED: set[str] = set()


def _imports(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, None
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                yield node.module, a.name


def test_engine_uses_only_exported_kernel_names():
    exported = set(divas_kernels.__all__)
    bad = []
    for p in sorted(ENGINE.rglob("*.py")):
        rel = p.relative_to(ENGINE).as_posix()
        for mod, name in _imports(p):
            if mod.startswith("divas_kernels."):
                bad.append(f"{rel}: imports submodule {mod}")
            elif mod == "divas_kernels" and name is not None and name not in exported:
                bad.append(f"{rel}: imports {name}, not in divas_kernels.__all__")
            elif mod.split(".")[0] == "warp" and rel not in WARP_ALLOWED:
                bad.append(f"{rel}: imports warp")
    assert not bad, "\n".join(bad)


def test_all_names_exist():
    missing = [n for n in divas_kernels.__all__ if not hasattr(divas_kernels, n)]
    assert not missing
