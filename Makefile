# Two entry points for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
CATALOG ?= catalog
OUT ?= site
# Content-addressed archive of the raw inputs (SQLite index, provenance events); see `cistern-archive verify`.
ARCHIVE ?= .archive
WORKERS ?= $(shell nproc 2>/dev/null || echo 1)

.PHONY: demo test test-slow test-all bench clean

$(STAMP): pyproject.toml plugins/cistern-plugins/pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]' -e plugins/cistern-plugins
	touch $(STAMP)

# rebuild exits 1 when a site is `partial` or `failed` (listed with its reasons); the demo still succeeds
# then, as every site's report was written; 2 and above (usage, catalog, environment) fail it.
demo: $(STAMP)
	$(BIN)/cistern-archive rebuild --catalog $(CATALOG) --out $(OUT) --archive $(ARCHIVE) --workers $(WORKERS) \
		|| [ $$? -eq 1 ]

# lint-imports: the layers contract in pyproject.toml (a module imports only from layers below it), and
# the plugins' contracts (matchers share helpers only through cistern_plugins.registration).
test: $(STAMP)
	$(BIN)/lint-imports --no-cache
	$(BIN)/lint-imports --no-cache plugins/cistern-plugins/pyproject.toml
	$(BIN)/python -m pytest -m "not slow" -q

# pytest exits 5 when no test is marked slow; that is not a failure.
test-slow: $(STAMP)
	$(BIN)/python -m pytest -m "slow" -q || [ $$? -eq 5 ]

test-all: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/pool.py
	$(BIN)/python benchmarks/sites.py

clean:
	rm -rf $(OUT) .pytest_cache
