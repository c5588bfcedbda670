# Two commands (see README): `make demo` and `make test`. Each creates .venv if missing.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
DEMO   ?= demo_out

.PHONY: demo test test-engine test-kernels test-addon test-cuda lint bench clean extension

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
