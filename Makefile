# Two entry points: `make demo` (embedded defaults) and `make test` (the whole suite twice:
# embedded defaults, then PostgreSQL + Redis). Both create the venv they need.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PG_URL ?= postgresql://postgres@127.0.0.1:5432/test
REDIS_URL ?= redis://127.0.0.1:6379/15
ARGS ?=

.PHONY: demo test test-embedded test-production lint openapi clean

# the service, its simulator and its research harness: three distributions
$(STAMP): pyproject.toml lab/pyproject.toml client_sim/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]' -e ./client_sim -e './lab[plots]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/indoorpos demo $(ARGS)

test: test-embedded test-production

test-embedded: $(STAMP)
	env -u INDOORPOS_DATABASE_URL -u INDOORPOS_REDIS_URL $(BIN)/pytest -q

# the core's and the dataset readers' tests (tests/positioning, tests/lab/datasets) touch no
# store: they run once, in the embedded pass
test-production: $(STAMP)
	INDOORPOS_DATABASE_URL=$(PG_URL) INDOORPOS_REDIS_URL=$(REDIS_URL) \
	INDOORPOS_TEST_REQUIRE_REDIS=1 $(BIN)/pytest -q \
	--ignore=tests/positioning --ignore=tests/lab/datasets

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports

openapi: $(STAMP)
	$(BIN)/indoorpos openapi

clean:
	rm -rf $(VENV) .indoorpos .mypy_cache .ruff_cache .pytest_cache build *.egg-info \
		lab/build lab/*.egg-info client_sim/build client_sim/*.egg-info
