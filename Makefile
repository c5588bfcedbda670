# Two commands (see README): `make demo` and `make test`. Each creates .venv if missing.
# Installs take their versions from the committed lock (constraints/py311.txt, the
# versions CI passed with; `make lock` regenerates it, `make test-latest` tries the newest).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEMO   ?= demo_out
LOCK   := constraints/py311.txt
PIP    := $(PY) -m pip install -q -c $(LOCK)

.PHONY: demo test test-sam test-sam-full test-engine test-kernels test-addon test-cuda lint bench \
	clean extension lock test-latest test-addon-matrix hooks

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip

demo: $(PY)
	$(PIP) -e .
	$(VENV)/bin/divas demo --out $(DEMO)

# the cluster extra (Ray) too: `divas batch` is tested on a local Ray
test: $(PY)
	$(PIP) -e ".[test,cluster]"
	$(MAKE) --no-print-directory lint
	$(PY) -m pytest -q

# SAM with real model graphs (random weights, nothing downloaded) and torch-ngp checkpoints:
# the torch extra, CPU wheel
test-sam: $(PY)
	$(PIP) -e ".[test,torch]"
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
	$(PIP) -e ".[test]"
	$(PY) -m pytest -q -m $(subst test-,,$@)

# The commit-msg hook: one-line subjects of at most 72 characters (.githooks/commit-msg)
hooks:
	git config core.hooksPath .githooks

# Style: ruff lint and format check (configured in pyproject.toml)
lint: $(PY)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: $(PY)
	$(PIP) -e .
	$(PY) benchmarks/bench_load.py

# Blender extension zips for linux-x64, windows-x64, macos-arm64 × cp311/cp313 (downloads wheels)
extension: $(PY)
	$(PIP) -e ".[test]"
	$(PY) blender_scripts/build_extension.py --out dist

# The add-on tier on the other Blender releases CI covers, each bpy wheel from PyPI in its
# own venv (.venv-bpy42, ...): `make test-addon-4.2` etc., `make test-addon-matrix` for all.
# 5.0 is `make test`'s own. 5.1+ runs Python 3.13 (pyenv's, else python3.13 on PATH).
ADDON_RELEASES := 4.2 4.5 5.2
BPY_4.2 := 4.2.23
BPY_4.5 := 4.5.15
BPY_5.2 := 5.2.4
PYTHON313 ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.13*/bin/python3.13) python3.13)
PYTHON_4.2 := $(PYTHON)
PYTHON_4.5 := $(PYTHON)
PYTHON_5.2 := $(PYTHON313)
LOCK_4.2 := $(LOCK)
LOCK_4.5 := $(LOCK)
LOCK_5.2 := constraints/py313.txt
# the test extra less bpy (each release has its own) and ruff (`make test` lints)
ADDON_TEST_DEPS := pytest onnx
# a watchdog over one release's tier (about 5 minutes on 2 cores)
ADDON_TIMEOUT ?= 1800

test-addon-matrix: $(addprefix test-addon-,$(ADDON_RELEASES))

# DIVAS_TEST_HARD_EXIT: tests/conftest.py ends the process once pytest has reported (bpy
# 4.5 can deadlock in its own shutdown after the last test).
test-addon-%:
	@test -n "$(BPY_$*)" || { echo "no bpy release for Blender $* ($(ADDON_RELEASES))"; exit 2; }
	test -x $(VENV)-bpy$(subst .,,$*)/bin/python || $(PYTHON_$*) -m venv $(VENV)-bpy$(subst .,,$*)
	$(VENV)-bpy$(subst .,,$*)/bin/python -m pip install -q -c $(LOCK_$*) --upgrade pip
	$(VENV)-bpy$(subst .,,$*)/bin/python -m pip install -q -c $(LOCK_$*) -e . \
		$(ADDON_TEST_DEPS) bpy==$(BPY_$*)
	DIVAS_TEST_HARD_EXIT=1 timeout $(ADDON_TIMEOUT) \
		$(VENV)-bpy$(subst .,,$*)/bin/python -m pytest -q -m addon tests/addon

# Rewrite the locks from venvs that just passed (`make test test-sam test-addon-5.2 lock`):
# every installed distribution but the checkout itself and bpy (pinned per release above
# and in pyproject.toml), local version labels dropped (torch's +cpu: pip's index picks it).
LOCK_FREEZE = -m pip freeze --all --exclude-editable --exclude bpy | sed -E 's/\+[^ ]*$$//'
lock:
	{ echo "# Python 3.11: the versions \`make test test-sam\` passed with (make lock)"; \
	  $(PY) $(LOCK_FREEZE); } > $(LOCK)
	{ echo "# Python 3.13: the versions \`make test-addon-5.2\` passed with (make lock)"; \
	  $(VENV)-bpy52/bin/python $(LOCK_FREEZE); } > $(LOCK_5.2)

# The newest release of every dependency (no lock, a fresh venv): what the next `make lock`
# would pin. Not in CI.
test-latest:
	rm -rf $(VENV)-latest
	$(PYTHON) -m venv $(VENV)-latest
	$(VENV)-latest/bin/python -m pip install -q --upgrade pip
	$(VENV)-latest/bin/python -m pip install -q -e ".[test,cluster]"
	$(VENV)-latest/bin/python -m pytest -q

clean:
	rm -rf $(DEMO) build dist *.egg-info
