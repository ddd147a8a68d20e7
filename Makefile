# Two commands from a fresh clone: `make demo` and `make test`. Both build .venv themselves.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_OUT ?= demo_out
# options of benchmarks/bench_fidelity.py, e.g. make bench-fidelity FIDELITY_ARGS="--quick"
FIDELITY_ARGS ?=

# The operator console (web/ -> service/console/static/, shipped as package data).
CONSOLE := service/console/static/index.html
CONSOLE_SRC := $(wildcard web/src/*) web/build.mjs web/package.json web/package-lock.json

.PHONY: venv demo test test-fast lint bench bench-fidelity clean console

# The venv is filled by uv (installed into it by pip): the same packages as pip's resolver picks,
# in half of pip's time (benchmarks/bench_venv.py). uv reads no pip configuration, so
# it is handed the wheel folders pip's configuration names (where a machine keeps its CPU build
# of torch: pyproject pins torch==2.13.0, which a local 2.13.0+cpu wheel satisfies).
FIND_LINKS = $(shell $(PY) -m pip config get global.find-links 2>/dev/null)

$(STAMP): pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) on PATH"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --disable-pip-version-check uv
	$(BIN)/uv pip install -q --python $(BIN)/python --compile-bytecode \
		$(foreach f,$(FIND_LINKS),--find-links $(f)) -e ".[fast,service,dev]"
	@touch $(STAMP)

venv: $(STAMP)

# The demo's scene: the Stanford bunny of ../shared when it lies beside the clone (the project
# ships no third-party meshes), else the built-in sphere. On the bunny SH-SAS leads on both CPU
# models measured; the small sphere's order follows the machine's rounding (README).
DEMO_MESH ?= $(wildcard ../shared/data/meshes/bunny.obj)

demo: $(STAMP)
	$(BIN)/shsas demo --out $(DEMO_OUT) $(if $(DEMO_MESH),--mesh $(DEMO_MESH))

# npm ci installs exactly the lockfile's versions; --ignore-scripts: nothing to run at install
# (esbuild's binary comes as an optional dependency).
$(CONSOLE): $(CONSOLE_SRC)
	@command -v npm >/dev/null 2>&1 || { echo "need npm (Node.js 20+) on PATH to build the console"; exit 1; }
	cd web && npm ci --ignore-scripts --no-audit --no-fund && npm run build
	@touch $(CONSOLE)

console: $(CONSOLE)

# the whole suite in two runs side by side (tests/run_suite.py): the service tests, whose Redis,
# PostgreSQL, Celery worker and browser processes must get a core when they want one, and the
# science on two pytest-xdist workers (as test-fast) at the lowest CPU priority, filling the time
# the service tests spend waiting. The science run's output follows the service run's.
test: $(STAMP) $(CONSOLE)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/python tests/run_suite.py

# the inner loop: everything but the slow and the service tests (no Redis, PostgreSQL or browser),
# on two pytest-xdist workers of one torch thread each (tests/conftest.py): most of the suite is
# single-threaded Python, so one process leaves a core idle. --dist loadfile keeps each module on
# one worker, so a module fixture (a simulated survey, a trained field) is still built once.
test-fast: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -m "not slow and not service" -n 2 --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# bench_fidelity.py is left out: its full suite takes hours (make bench-fidelity runs it)
bench: $(STAMP)
	@for f in benchmarks/bench_*.py; do case $$f in *bench_fidelity.py) continue;; esac; \
		echo "== $$f"; $(BIN)/python $$f || exit 1; done

# the fidelity scoreboard (scenes x survey regimes x methods at the spec defaults)
bench-fidelity: $(STAMP)
	$(BIN)/python benchmarks/bench_fidelity.py $(FIDELITY_ARGS)

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .ruff_cache web/node_modules service/console/static
