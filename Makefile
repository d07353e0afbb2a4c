# The two commands a user types on a fresh clone: `make reproduce` and `make test`.
# Each creates .venv with the machine's python3 when it is missing and installs what it needs.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python

.PHONY: reproduce test test-fast test-science lint bench docs clean

$(PY):
	$(PYTHON) -m venv $(VENV)

$(VENV)/.installed-run: pyproject.toml | $(PY)
	$(PY) -m pip install -q -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(PY)
	$(PY) -m pip install -q -e ".[test,ray,docs]"
	touch $@ $(VENV)/.installed-run $(VENV)/.installed-docs

$(VENV)/.installed-docs: pyproject.toml | $(PY)
	$(PY) -m pip install -q -e ".[docs]"
	touch $@ $(VENV)/.installed-run

reproduce: $(VENV)/.installed-run
	$(VENV)/bin/loopid reproduce --out runs

# The suite runs in TEST_WORKERS processes (pytest-xdist), each test file whole in one of them
# (its module fixtures computed once), the slowest files first (tests/conftest.py);
# TEST_WORKERS=0 runs it in this process.
TEST_WORKERS ?= 2

test: $(VENV)/.installed-test
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not science"

# The edit-test loop: everything but the slow end-to-end tests (`make test` runs those too).
test-fast: $(VENV)/.installed-test
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not slow and not science"

# The acceptance benchmarks: the 16-seed pendulum swing-up and the readings study (CI runs them
# after make test).
test-science: $(VENV)/.installed-test
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m science

lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

bench: $(VENV)/.installed-test
	for f in benchmarks/*.py; do $(PY) $$f || exit 1; done

# The documentation site, offline and strict: a broken reference, a missing image or a page
# outside the navigation fails the build (tests/docs checks the same in make test).
docs: $(VENV)/.installed-docs
	$(PY) -m sphinx -n -W --keep-going -E -b html docs docs/_build/html
	@echo "open docs/_build/html/index.html"

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache docs/_build docs/_generated
