# photosurf: `make demo` and `make test` each do every set-up step they need.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.photosurf-installed
OUT    ?= out
BENCH_ARGS ?=

.PHONY: setup sysdeps sysdeps-test demo test bench lint docs clean

# Debian packages photosurf needs at run time (open3d loads libusb-1.0).
SYSLIBS := libusb-1.0.so.0:libusb-1.0-0

sysdeps:
	@missing=""; for pair in $(SYSLIBS); do lib=$${pair%%:*}; pkg=$${pair##*:}; \
	  if ! ldconfig -p 2>/dev/null | grep -q "$$lib"; then missing="$$missing $$pkg"; fi; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "photosurf setup: installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null || exit 1; \
	  else \
	    echo "photosurf setup: missing system packages:$$missing -- run: sudo apt-get install$$missing" >&2; exit 1; \
	  fi; \
	fi

# The report test renders report.html in headless Chromium (Debian's chromium).
sysdeps-test:
	@if ! command -v chromium >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "photosurf setup: installing Debian package chromium (report test)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null || exit 1; \
	  else \
	    echo "photosurf setup: missing system package: chromium -- run: sudo apt-get install chromium" >&2; exit 1; \
	  fi; \
	fi

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory sysdeps
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	@touch $(STAMP)

# numba kernels compiled once into their on-disk cache (pipeline/warmup.py says why);
# redone when the kernels' sources change
WARM   := $(VENV)/.photosurf-kernels
# (every module holding a numba kernel: a new one is followed without editing this list)
KERNELS := $(shell grep -l numba matching/*.py surface/*.py pipeline/scenes.py 2>/dev/null)
$(WARM): $(STAMP) $(KERNELS)
	$(PY) -m pipeline.warmup
	@touch $(WARM)

setup: $(STAMP) $(WARM)
	@$(MAKE) --no-print-directory sysdeps

# The demo also writes the exact surface as a STEP solid (out/export/surface.step: about
# 4 KB and 0.6 CPU-ms a patch, README "CAD"), which the default export.formats leave out.
DEMO_FORMATS ?= ["ply", "glb", "step"]

demo: setup
	$(VENV)/bin/photosurf run fixtures/scenes/vase_ring.toml --out $(OUT) --set 'export.formats=$(DEMO_FORMATS)'

test: setup sysdeps-test
	$(PY) -m pytest -n 2 -q

bench: setup
	@mkdir -p benchmarks/results
	@for b in benchmarks/[!_]*.py; do echo "== $$b"; $(PY) $$b $(BENCH_ARGS) --json benchmarks/results/$$(basename $$b .py).json || exit 1; done

# The documentation site (docs/ -> site/): the docs extra, the Figures page from the benchmark
# JSON, then a strict build (a broken link, a missing API page or an unparsable docstring fails).
DOCS_STAMP := $(VENV)/.photosurf-docs-installed
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(PY) -m pip install -q -e ".[test,docs]"
	@touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(PY) docs/gen_figures.py
	$(PY) docs/gen_api.py --check
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# ruff, then the import contract of pyproject.toml [tool.importlinter] (docs/architecture.md,
# "The import rule": the layers, tests and benchmarks apart, no cycle inside a package), then the rule for
# imports inside functions (tests/function_imports.py)
lint: setup
	$(VENV)/bin/ruff check matching surface pipeline testkit tests benchmarks
	$(VENV)/bin/lint-imports --no-cache
	$(VENV)/bin/python tests/function_imports.py

clean:
	rm -rf $(VENV) $(OUT) *.egg-info .pytest_cache site docs/figures.md
