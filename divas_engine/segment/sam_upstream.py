"""Importing the SAM model packages (``segment-anything``, MobileSAM's ``mobile_sam``).

Both packages import ``torchvision`` on import, yet their models do not need it, and PyTorch's
CPU wheel has no matching torchvision on PyPI. When a plain import fails for want of
torchvision, :func:`sam_package` creates the package module without running its ``__init__``,
imports the model submodules unchanged, and while ``utils.transforms`` is imported replaces
``torchvision`` by a module whose functions raise an ImportError naming it (so the uint8
``SamPredictor.set_image`` path fails loudly; DivAS uses ``set_torch_image``). With a working
torchvision the plain import is used. The steps in full: docs/design-notes.md.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from typing import Any

__all__ = ["sam_package", "SAM_PACKAGES", "TorchvisionMissing"]

#: Python package of each model family (``mobile_sam``: MobileSAM's own package,
#: installed from its repository or the ``mobilesam-mirror`` PyPI package).
SAM_PACKAGES = ("segment_anything", "mobile_sam")

_SUBMODULES = ("modeling", "build_sam", "utils.onnx", "predictor")
_EXPORTS = {
    "build_sam": (
        "build_sam",
        "build_sam_vit_h",
        "build_sam_vit_l",
        "build_sam_vit_b",
        "build_sam_vit_t",  # MobileSAM only
        "sam_model_registry",
    ),
    "predictor": ("SamPredictor",),
}


class TorchvisionMissing(ImportError):
    """A part of a SAM package that really needs torchvision was used without it."""


def _needs_torchvision(*_: Any, **__: Any) -> Any:
    raise TorchvisionMissing(
        "this segment-anything function needs torchvision (PIL resize in "
        "ResizeLongestSide.apply_image / SamPredictor.set_image); install a torchvision "
        "matching your torch, or feed the predictor with set_torch_image"
    )


def _torchvision_placeholder() -> dict[str, types.ModuleType]:
    """Modules standing in for ``torchvision.transforms.functional`` during one import."""
    tv = types.ModuleType("torchvision")
    tr = types.ModuleType("torchvision.transforms")
    fn = types.ModuleType("torchvision.transforms.functional")
    fn.resize = _needs_torchvision
    fn.to_pil_image = _needs_torchvision
    tv.transforms, tr.functional = tr, fn
    return {m.__name__: m for m in (tv, tr, fn)}


def _import_without_init(name: str) -> types.ModuleType:
    spec = importlib.util.find_spec(name)
    if spec is None or spec.submodule_search_locations is None:
        raise ImportError(f"No module named {name!r}", name=name)
    pkg = importlib.util.module_from_spec(spec)  # __init__ is not executed
    sys.modules[name] = pkg
    try:
        saved = {k: sys.modules.get(k) for k in _torchvision_placeholder()}
        sys.modules.update(_torchvision_placeholder())
        try:
            importlib.import_module(f"{name}.utils.transforms")
        finally:
            for k, mod in saved.items():  # the placeholder never outlives this import
                if mod is None:
                    sys.modules.pop(k, None)
                else:
                    sys.modules[k] = mod
        for sub in _SUBMODULES:
            mod = importlib.import_module(f"{name}.{sub}")
            for attr in _EXPORTS.get(sub, ()):
                if hasattr(mod, attr):
                    setattr(pkg, attr, getattr(mod, attr))
    except BaseException:
        for k in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[k]
        raise

    def __getattr__(attr: str) -> Any:
        if attr == "SamAutomaticMaskGenerator":
            _needs_torchvision()
        raise AttributeError(f"module {name!r} has no attribute {attr!r}")

    pkg.__getattr__ = __getattr__
    pkg.DIVAS_IMPORTED_WITHOUT_TORCHVISION = True
    return pkg


def sam_package(name: str = "segment_anything") -> types.ModuleType:
    """The SAM package ``name`` (one of :data:`SAM_PACKAGES`), torchvision or not.

    Raises:
        ImportError: the package (or torch, or a dependency other than torchvision —
            MobileSAM's TinyViT needs ``timm``, which needs torchvision) is missing.
    """
    if name not in SAM_PACKAGES:
        raise ValueError(f"unknown SAM package {name!r}; one of {SAM_PACKAGES}")
    loaded = sys.modules.get(name)
    if loaded is not None and hasattr(loaded, "sam_model_registry"):
        return loaded
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        if not _torchvision_at_fault(exc):
            raise
    except RuntimeError as exc:  # a torchvision built for another torch fails this way
        if "torchvision" not in str(exc):
            raise
    for k in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
        del sys.modules[k]  # drop what the failed plain import left half-done
    return _import_without_init(name)


def _torchvision_at_fault(exc: ImportError) -> bool:
    missing = getattr(exc, "name", None) or ""
    return missing.split(".")[0] == "torchvision" or "torchvision" in str(exc)
