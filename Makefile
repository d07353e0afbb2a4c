# The two commands a user types on a fresh clone: `make reproduce` and `make test`.
# Each creates .venv with the machine's python3 when it is missing and installs what it needs.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python

.PHONY: reproduce test test-fast test-science lint bench analysis docs clean

$(PY):
	$(PYTHON) -m venv $(VENV)

# What is installed is stamped with pyproject.toml's content, not compared with its time: a fresh
# clone's pyproject.toml is newer than the stamps of a .venv kept from before, yet says the same,
# and must not reinstall. An edit to pyproject.toml changes the stamp's name and reinstalls once.
STAMP := $(shell $(PYTHON) -c "import hashlib; print(hashlib.sha256(open('pyproject.toml', 'rb').read()).hexdigest()[:12])")
RUN_STAMP := $(VENV)/.installed-run-$(STAMP)
TEST_STAMP := $(VENV)/.installed-test-$(STAMP)
DOCS_STAMP := $(VENV)/.installed-docs-$(STAMP)

$(RUN_STAMP): | $(PY)
	$(PY) -m pip install -q -e .
	touch $@

$(TEST_STAMP): | $(PY)
	$(PY) -m pip install -q -e ".[test,ray,docs]"
	touch $@ $(RUN_STAMP) $(DOCS_STAMP)

$(DOCS_STAMP): | $(PY)
	$(PY) -m pip install -q -e ".[docs]"
	touch $@ $(RUN_STAMP)

reproduce: $(RUN_STAMP)
	$(VENV)/bin/loopid reproduce --out runs

# The suite runs in TEST_WORKERS processes (pytest-xdist), each test file whole in one of them
# (its module fixtures computed once), the slowest files first (tests/conftest.py);
# TEST_WORKERS=0 runs it in this process. `make test` ends with its 30 slowest tests.
TEST_WORKERS ?= 2

test: $(TEST_STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not science" --durations=30

# The edit-test loop: everything but the slow end-to-end tests (`make test` runs those too).
test-fast: $(TEST_STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not slow and not science"

# The acceptance benchmarks: the 16-seed pendulum swing-up and the readings study (CI runs them
# after make test).
test-science: $(TEST_STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder -m science

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The speed benchmarks; equivalence.py (and its rule) compares two runs, it measures nothing.
bench: $(TEST_STAMP)
	for f in benchmarks/*.py; do case $$f in */equivalence*) continue;; esac; $(PY) $$f || exit 1; done

# The scientific studies in analysis/ (one folder each, its README says what it answers), each at
# its default size. They take long: 14-16 minutes in all on two shared cores (the sum of the
# times the scripts state), and they time nothing (`make bench` is the speed benchmarks).
analysis: $(TEST_STAMP)
	$(PY) analysis/best_linear_gain/best_linear_gain.py
	$(PY) analysis/funnel_nu_t/funnel_nu_t.py
	$(PY) analysis/nu_e_identifiability/nu_e_identifiability.py
	$(PY) analysis/swingup_seeds/swingup_seeds.py
	$(PY) analysis/pg_gradient/pg_gradient_quality.py
	$(PY) analysis/pg_gradient/pg_sample_count.py

# The documentation site, offline and strict: a broken reference, a missing image or a page
# outside the navigation fails the build (tests/docs checks the same in make test, and reads the
# pages it built). The doctrees, Sphinx's cache, stay outside the site.
docs: $(DOCS_STAMP)
	$(PY) -m sphinx -n -W --keep-going -E -b html -d docs/_build/doctrees docs docs/_build/html
	@echo "open docs/_build/html/index.html"

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache docs/_build docs/_generated
