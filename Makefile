# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Both create .venv, install torch 2.13.0 (CPU wheel, local on these machines)
# when no torch is present, then the package with its extras.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check -q
PYTEST_ARGS ?= -n 2  # pytest-xdist: the two cores of the CI machine

.PHONY: install demo docs test test-fast clean clean-cache

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -c "import torch" 2>/dev/null || $(PIP) install "torch==2.13.0"
	$(PIP) install -e ".[dev,train,cluster,docs]"
	touch $@

install: $(VENV)/.installed

# the scripted experts solving each env (GIFs), the drape test of cotton and wool at sigma = 1 cm
# (about a minute each), a hanging cloth; outputs/index.md says what each file is
demo: install
	$(PY) scripts/demo.py --out outputs

# the docs site (mkdocs-material; pages from docs/ and the docstrings) into site/; warnings fail it
docs: install
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --quiet

# the suite, the docs site, then the installed wheel used from outside the checkout (scripts/check_wheel.sh)
test: install
	$(PY) -m pytest $(PYTEST_ARGS)
	$(MAKE) --no-print-directory docs
	bash scripts/check_wheel.sh $(PYTHON)

test-fast: install
	$(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

# compiled kernels live in ~/.cache/cloth_gym/numba/<hash of the kernel sources> (a fresh
# directory after every kernel edit); this removes every version of it
clean-cache:
	find cloth_gym -name '*.nbi' -delete -o -name '*.nbc' -delete
	rm -rf $${XDG_CACHE_HOME:-$$HOME/.cache}/cloth_gym/numba

clean: clean-cache
	rm -rf $(VENV) outputs site .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
