# Everything installs into a local virtual environment (.venv).
# TORCH_SPEC picks the torch build installed first; set TORCH_SPEC= (empty) to keep a torch
# you already have (create the venv with --system-site-packages yourself in that case).
PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
PY := $(VENV)/bin/python

.PHONY: install test test-all lint demo bench docs docs-serve clean

$(VENV)/.installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	if [ -n "$(TORCH_SPEC)" ]; then $(PY) -m pip install -q "$(TORCH_SPEC)"; fi
	$(PY) -m pip install -q -e ".[dev,colmap,plot,train,mesh,viewer,onnx,docs]"
	touch $@

install: $(VENV)/.installed

lint: install
	$(PY) -m ruff check .

test: install lint
	$(PY) -m pytest -q

test-all: install
	$(PY) -m pytest -q -m ""

demo: install
	$(VENV)/bin/mvsformerpp demo

bench: install
	$(PY) bench/run_all.py

# The documentation site, into site/ (strict: broken links and out-of-date generated pages fail).
docs: install
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

docs-serve: install
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs serve

clean:
	rm -rf $(VENV) build site *.egg-info src/*.egg-info .pytest_cache
