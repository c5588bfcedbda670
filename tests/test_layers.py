"""The import rules of docs/ARCHITECTURE.md, checked on the source: no engine module
imports a layer above its own, the engine never imports ``bpy``, the kernels never
import the engine, and the add-on never imports the CLI."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ENGINE = REPO / "divas_engine"

#: Engine packages (and top-level modules) by layer, lowest first; a module may import
#: its own package and any lower layer, never a higher one or another package of its own
#: layer. Mirrors the table in docs/ARCHITECTURE.md.
LAYERS: list[set[str]] = [
    {"kinds", "errors", "geometry", "sh_rotation", "blas_threads"},
    {"camera", "scene", "output_paths", "segment_request"},
    {"scene_stats", "blender_convention", "viewport", "selection_tools"},
    {"io", "render"},
    {"fusion", "views", "export", "point_attributes"},
    {"mapping", "synthetic", "segment", "transform_export"},
    {"session"},
    {"evaluation"},
    {"cli"},
    {"__main__"},
]
RANK = {name: k for k, layer in enumerate(LAYERS) for name in layer}


def _unit(path: Path) -> str:
    rel = path.relative_to(ENGINE).parts
    return rel[0][:-3] if len(rel) == 1 else rel[0]


def _imports(path: Path):
    """(line, absolute dotted module or None, names) of every import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = list(path.relative_to(REPO).with_suffix("").parts[:-1])
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            for a in n.names:
                yield n.lineno, a.name, []
        elif isinstance(n, ast.ImportFrom):
            if n.level:
                base = pkg[: len(pkg) - (n.level - 1)]
                mod = ".".join(base + ([n.module] if n.module else []))
            else:
                mod = n.module or ""
            yield n.lineno, mod, [a.name for a in n.names]


def _engine_targets(mod: str, names: list[str]) -> list[str]:
    parts = mod.split(".")
    if parts[0] != "divas_engine":
        return []
    if len(parts) > 1:
        return [parts[1]]
    return names  # ``from divas_engine import x`` / ``from .. import x``


def _engine_files():
    return sorted(p for p in ENGINE.rglob("*.py") if _unit(p) != "__init__")


def test_every_engine_unit_has_a_layer():
    units = {_unit(p) for p in _engine_files()}
    assert units <= set(RANK), f"add {sorted(units - set(RANK))} to LAYERS and ARCHITECTURE.md"


@pytest.mark.parametrize("path", _engine_files(), ids=lambda p: str(p.relative_to(ENGINE)))
def test_engine_imports_only_downwards(path: Path):
    own = _unit(path)
    for line, mod, names in _imports(path):
        assert mod.split(".")[0] != "bpy", f"{path}:{line} imports bpy"
        for tgt in _engine_targets(mod, names):
            if tgt == own or tgt not in RANK:
                continue  # own package, or a name re-exported by the package root
            assert RANK[tgt] < RANK[own], (
                f"{path.relative_to(REPO)}:{line} imports {tgt} (layer {RANK[tgt]}) from "
                f"{own} (layer {RANK[own]}): imports must run down the layers"
            )


def test_kernels_never_import_the_engine_or_bpy():
    for path in sorted((REPO / "kernels").rglob("*.py")):
        for line, mod, _ in _imports(path):
            top = mod.split(".")[0]
            assert top not in ("divas_engine", "bpy"), f"{path}:{line} imports {mod}"


def test_addon_never_imports_the_cli():
    for path in sorted((REPO / "blender_addon").rglob("*.py")):
        for line, mod, _ in _imports(path):
            assert not mod.startswith("divas_engine.cli"), f"{path}:{line} imports {mod}"


def test_the_rule_catches_an_upward_import(tmp_path, monkeypatch):
    """The check itself: a segment module importing the session is reported."""
    bad = ENGINE / "segment" / "_layer_probe.py"
    monkeypatch.setattr(
        "tests.test_layers._imports",
        lambda p: iter([(1, "divas_engine.session", [])]) if p == bad else _imports(p),
    )
    with pytest.raises(AssertionError, match="imports must run down the layers"):
        test_engine_imports_only_downwards(bad)
