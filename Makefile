# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Both create .venv, install torch 2.13.0 (CPU wheel, local on these machines)
# when no torch is present, then the package with its extras.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check -q
PYTEST_ARGS ?=

.PHONY: install demo test test-fast clean clean-cache

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -c "import torch" 2>/dev/null || $(PIP) install "torch==2.13.0"
	$(PIP) install -e ".[dev,train]"
	touch $@

install: $(VENV)/.installed

# The drape tests run at sigma = 1 cm (505 particles; about a minute each on one core);
# the paper's sigma = 0.5 cm takes ~10x longer (docs/drape_results.md).
demo: install
	$(PY) scripts/demo.py --out outputs
	$(PY) scripts/drape_test.py --material thick_cotton --sigma 1.0 --out outputs/drape_test --quiet
	$(PY) scripts/drape_test.py --material thin_wool --sigma 1.0 --out outputs/drape_test --quiet

# the suite, then the installed wheel used from outside the checkout (scripts/check_wheel.sh)
test: install
	$(PY) -m pytest $(PYTEST_ARGS)
	bash scripts/check_wheel.sh $(PYTHON)

test-fast: install
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

# numba's on-disk cache is invalidated only by edits to a kernel's own file, not to the
# kernels it calls from other files: after editing cloth_gym/sim, clear it.
clean-cache:
	find cloth_gym -name '*.nbi' -delete -o -name '*.nbc' -delete
	rm -rf $${XDG_CACHE_HOME:-$$HOME/.cache}/cloth_gym/numba

clean: clean-cache
	rm -rf $(VENV) outputs .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
