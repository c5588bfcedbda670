"""Build the DivAS Blender extension: pinned wheels, one zip per platform and Python.

    python blender_scripts/build_extension.py                       # all platforms, cp311 + cp313
    python blender_scripts/build_extension.py --platforms linux-x64 --python 311   # the CI variant
    python blender_scripts/build_extension.py --without-sam         # no onnxruntime (−24 MB)

Steps: (1) ``pip download --only-binary=:all:`` of each run-time dependency at the version the
Python's lock pins (:func:`pinned`) for every platform × Python into a reused wheel cache, and
``pip wheel --no-deps .`` of the engine; (2) a staging copy of ``blender_addon/`` with those
wheels and a manifest listing exactly them; (3) Blender's own packager
(``blender_ext.py build --split-platforms``, from a ``blender`` binary or the ``bpy`` module),
or the same layout written here. Each Python gets its own zip (Blender 4.2–5.0 runs 3.11,
5.1+ runs 3.13; a Blender loads only its own Python's wheels). NumPy is not bundled (Blender
ships its own). What a zip holds and why: docs/design-notes.md.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ADDON = REPO / "blender_addon"
BUILD = REPO / "build" / "extension"

#: The lock of each Python (the versions the tests passed with; ``make lock``): the
#: bundled wheels take their versions from it.
LOCKS = {"311": REPO / "constraints" / "py311.txt", "313": REPO / "constraints" / "py313.txt"}
#: Run-time dependencies of the engine (pyproject.toml) that the extension does not bundle.
NOT_BUNDLED = {"numpy": "Blender ships its own", "tqdm": "progress bars of the command line"}
#: left out by ``--without-sam`` (only the SAM ONNX segmenter imports it).
SAM_ONLY = ("onnxruntime",)
#: Blender versions of each bundled Python: (blender_version_min, blender_version_max).
BLENDER_RANGE = {"311": ("4.2.0", "5.1.0"), "313": ("5.1.0", None)}

#: Blender platform → pip platform tags (newest first; Blender 4.2 needs glibc 2.28 / macOS 11.2).
PLATFORMS = {
    "linux-x64": [
        "manylinux_2_28_x86_64",
        "manylinux_2_27_x86_64",
        "manylinux_2_17_x86_64",
        "manylinux2014_x86_64",
        "manylinux1_x86_64",
        "linux_x86_64",
    ],
    "windows-x64": ["win_amd64"],
    "macos-arm64": [
        "macosx_14_0_arm64",
        "macosx_13_0_arm64",
        "macosx_12_0_arm64",
        "macosx_11_0_arm64",
        "macosx_13_0_universal2",
        "macosx_11_0_universal2",
        "macosx_10_9_universal2",
    ],
}
PYTHONS = ("311", "313")


def runtime_dependencies() -> list[str]:
    """The engine's dependencies (``[project].dependencies``) the extension bundles."""
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    names = [re.match(r"[A-Za-z0-9_.-]+", d)[0] for d in deps]
    return [n for n in names if _norm(n) not in {_norm(k) for k in NOT_BUNDLED}]


def pinned(python: str) -> dict[str, str]:
    """``{name: version}`` of :func:`runtime_dependencies` as the lock of ``python`` pins them."""
    lock = LOCKS[python]
    found = {}
    for line in lock.read_text().splitlines():
        m = re.fullmatch(r"\s*([A-Za-z0-9_.-]+)==([^\s;#]+)\s*", line)
        if m:
            found[_norm(m[1])] = m[2]
    missing = [n for n in runtime_dependencies() if _norm(n) not in found]
    if missing:
        raise SystemExit(f"{lock} pins no version of {', '.join(missing)}: run `make lock`")
    return {n: found[_norm(n)] for n in runtime_dependencies()}


def _run(cmd: list[str], **kw) -> None:
    print("+", " ".join(str(c) for c in cmd), flush=True)
    subprocess.run(cmd, check=True, **kw)


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def download_wheels(platform: str, python: str, cache: Path, *, sam: bool = True) -> list[Path]:
    """The pinned wheels for one platform × Python (downloaded once into ``cache``)."""
    dest = cache / f"{platform}-cp{python}"
    dest.mkdir(parents=True, exist_ok=True)
    out = []
    for name, version in pinned(python).items():
        if not sam and name in SAM_ONLY:
            continue
        prefix = f"{_norm(name)}-{version}-"
        have = sorted(p for p in dest.glob("*.whl") if p.name.lower().startswith(prefix))
        if not have:
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--quiet",
                "--no-deps",
                "--only-binary=:all:",
                "--python-version",
                python,
                "--implementation",
                "cp",
                "--dest",
                str(dest),
                f"{name}=={version}",
            ]
            for tag in PLATFORMS[platform]:
                cmd += ["--platform", tag]
            _run(cmd)
            have = sorted(p for p in dest.glob("*.whl") if p.name.lower().startswith(prefix))
        if len(have) != 1:
            raise SystemExit(
                f"expected one {name} {version} wheel for {platform} cp{python}, got {have}"
            )
        out.append(have[0])
    return out


def engine_wheel(dest: Path) -> Path:
    """``divas-<version>-py3-none-any.whl`` from the repository (no dependencies)."""
    dest.mkdir(parents=True, exist_ok=True)
    for old in dest.glob("divas-*.whl"):
        old.unlink()
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "--wheel-dir",
            str(dest),
            str(REPO),
        ]
    )
    (whl,) = dest.glob("divas-*.whl")
    return whl


def _toml_list(values: list[str]) -> str:
    return "[\n" + "".join(f'  "{v}",\n' for v in values) + "]"


def write_manifest(
    src: Path,
    dst: Path,
    wheels: list[str],
    platforms: list[str],
    blender_range: tuple[str, str | None] | None = None,
) -> None:
    """Copy the manifest with ``wheels`` and ``platforms`` set (top-level keys, before
    tables), and with ``blender_range`` its ``blender_version_min``/``_max``."""
    text = src.read_text()
    text = re.sub(r"(?m)^(wheels|platforms)\s*=\s*\[[^\]]*\]\s*\n", "", text)
    if blender_range is not None:
        lo, hi = blender_range
        text = re.sub(r"(?m)^blender_version_(min|max)\s*=.*\n", "", text)
        head0, sep0, rest0 = text.partition("\n[")
        extra = f'\nblender_version_min = "{lo}"\n' + (
            f'blender_version_max = "{hi}"\n' if hi else ""
        )
        text = head0.rstrip("\n") + "\n" + extra + (sep0 + rest0 if sep0 else "")
    head, sep, rest = text.partition("\n[")
    block = f"\nplatforms = {_toml_list(platforms)}\nwheels = {_toml_list(wheels)}\n"
    dst.write_text(head.rstrip("\n") + "\n" + block + (sep + rest if sep else ""))


def _packager() -> list[str] | None:
    """Command prefix for Blender's extension packager, or None if none is available."""
    blender = shutil.which("blender")
    if blender:
        return [blender, "--background", "--factory-startup", "--command", "extension"]
    spec = importlib.util.find_spec("bpy")
    if spec is not None and spec.submodule_search_locations:
        for root in spec.submodule_search_locations:
            for script in Path(root).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"):
                return [sys.executable, str(script)]
    return None


def _zip_ourselves(stage: Path, out: Path, version: str, platforms: list[str]) -> list[Path]:
    """Fallback: one zip per platform, manifest at the root, only that platform's wheels."""
    zips = []
    for plat in platforms:
        path = out / f"divas-{version}-{plat.replace('-', '_')}.zip"
        tags = PLATFORMS[plat]
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
            for f in sorted(stage.rglob("*")):
                rel = f.relative_to(stage).as_posix()
                if f.is_dir() or "__pycache__" in rel:
                    continue
                if (
                    rel.startswith("wheels/")
                    and "none-any" not in rel
                    and not any(t in rel for t in tags)
                ):
                    continue
                if rel == "blender_manifest.toml":
                    text = f.read_text()
                    keep = [
                        w
                        for w in re.findall(r'"(\./wheels/[^"]+)"', text)
                        if "none-any" in w or any(t in w for t in tags)
                    ]
                    tmp = stage.parent / "manifest.tmp"
                    tmp.write_text(text)
                    write_manifest(tmp, tmp, keep, [plat])
                    z.write(tmp, rel)
                    continue
                z.write(f, rel)
        zips.append(path)
    return zips


def _build_one(
    platforms: list[str], python: str, out: Path, cache: Path, *, sam: bool
) -> list[Path]:
    """The zips (one per platform) for one Python, named ``…-<platform>-cp<python>.zip``."""
    stage = BUILD / "stage" / "divas"
    if stage.exists():
        shutil.rmtree(stage)
    shutil.copytree(ADDON, stage, ignore=shutil.ignore_patterns("__pycache__", "wheels", "*.zip"))
    (stage / "wheels").mkdir()
    wheels = [engine_wheel(BUILD / "engine")]
    for plat in platforms:
        wheels += download_wheels(plat, python, cache, sam=sam)
    names = []
    for w in wheels:
        if w.name not in names:
            shutil.copy2(w, stage / "wheels" / w.name)
            names.append(w.name)
    write_manifest(
        ADDON / "blender_manifest.toml",
        stage / "blender_manifest.toml",
        [f"./wheels/{n}" for n in names],
        platforms,
        BLENDER_RANGE[python],
    )
    version = re.search(
        r'(?m)^version\s*=\s*"([^"]+)"', (stage / "blender_manifest.toml").read_text()
    )[1]
    tmp = out / f".cp{python}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    packager = _packager()
    if packager is None:
        made = _zip_ourselves(stage, tmp, version, platforms)
    else:
        _run(
            packager
            + ["build", "--source-dir", str(stage), "--output-dir", str(tmp), "--split-platforms"]
        )
        made = sorted(tmp.glob(f"divas-{version}*.zip"))
    zips = []
    for z in made:
        dst = out / f"{z.stem}-cp{python}.zip"
        z.replace(dst)
        zips.append(dst)
    shutil.rmtree(tmp)
    return zips


def build(
    platforms: list[str], pythons: list[str], out: Path, cache: Path, *, sam: bool = True
) -> list[Path]:
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("divas-*.zip"):
        old.unlink()
    zips = []
    for py in pythons:
        zips += _build_one(platforms, py, out, cache, sam=sam)
    print(f"built {len(zips)} package(s) in {time.perf_counter() - t0:.1f} s:")
    for z in zips:
        print(f"  {z}  ({z.stat().st_size / 1e6:.1f} MB)")
    return zips


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--platforms", nargs="+", choices=sorted(PLATFORMS), default=list(PLATFORMS))
    ap.add_argument("--python", nargs="+", choices=PYTHONS, default=list(PYTHONS), dest="pythons")
    ap.add_argument(
        "--out", type=Path, default=REPO / "dist", help="where the zips go (default: dist/)"
    )
    ap.add_argument(
        "--wheel-cache",
        type=Path,
        default=BUILD / "wheels",
        help="downloaded wheels, reused between builds",
    )
    ap.add_argument(
        "--without-sam", action="store_true", help="leave out onnxruntime (no SAM segmenter)"
    )
    args = ap.parse_args(argv)
    try:
        zips = build(
            args.platforms, args.pythons, args.out, args.wheel_cache, sam=not args.without_sam
        )
    except subprocess.CalledProcessError as e:
        print(
            f"build_extension: command failed ({e.returncode}): {' '.join(map(str, e.cmd))}",
            file=sys.stderr,
        )
        return 1
    return 0 if zips else 1


if __name__ == "__main__":
    sys.exit(main())
