# Two commands (see README): `make demo` and `make test`. Each creates .venv if missing.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEMO   ?= demo_out

.PHONY: demo test test-sam test-sam-full test-engine test-kernels test-addon test-cuda lint bench clean extension

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

demo: $(PY)
	$(PY) -m pip install -q -e .
	$(VENV)/bin/divas demo --out $(DEMO)

test: $(PY)
	$(PY) -m pip install -q -e ".[test]"
	$(MAKE) --no-print-directory lint
	$(PY) -m pytest -q

# SAM with real model graphs (random weights, nothing downloaded) and torch-ngp checkpoints:
# the torch extra, CPU wheel
test-sam: $(PY)
	$(PY) -m pip install -q -e ".[test,torch]"
	$(PY) -m pytest -q tests/test_sam_real_graphs.py tests/test_sam_export.py tests/test_segmenters.py \
		tests/test_io_nerf_formats.py

# Full-size ViT-B and MobileSAM (needs timm, so a working torchvision: PyPI's pairs with
# torch 2.14.1's CUDA build, ~5.5 GB, in its own venv). Minutes of CPU, ~7 GB peak. Not in CI.
SAMFULL := $(VENV)-sam-full
test-sam-full:
	test -x $(SAMFULL)/bin/python || $(PYTHON) -m venv $(SAMFULL)
	$(SAMFULL)/bin/python -m pip install -q torch==2.14.1 torchvision==0.29.1
	$(SAMFULL)/bin/python -m pip install -q -e ".[test]" segment-anything==1.0 onnx timm mobilesam-mirror
	DIVAS_TEST_FULL_SAM=1 $(SAMFULL)/bin/python -m pytest -q tests/test_sam_full.py

# One tier at a time for quick local loops (markers in pyproject.toml, assigned in tests/conftest.py)
test-engine test-kernels test-addon test-cuda: $(PY)
	$(PY) -m pip install -q -e ".[test]"
	$(PY) -m pytest -q -m $(subst test-,,$@)

# Style: ruff lint and format check (configured in pyproject.toml)
lint: $(PY)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: $(PY)
	$(PY) -m pip install -q -e .
	$(PY) benchmarks/bench_load.py

# Blender extension zips for linux-x64, windows-x64, macos-arm64 × cp311/cp313 (downloads wheels)
extension: $(PY)
	$(PY) -m pip install -q -e ".[test]"
	$(PY) blender_scripts/build_extension.py --out dist

clean:
	rm -rf $(DEMO) build dist *.egg-info
