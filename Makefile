# scrppl: the two commands a newcomer needs are `make reproduce` and `make test`.
# Both create .venv from environment.lock first when it is missing (or older than the lock).

SHELL := /bin/bash
VENV := .venv
STAMP := $(VENV)/.installed
OUT ?= results
PROFILE ?= full
SEED ?= 0
# Test workers: pytest-xdist processes (2 suits a 2-core machine).
WORKERS ?= 2
# CPU=native: every library runs this CPU's own code (SCRPPL_NATIVE_CPU=1), instead of the portable
# numerics that give the same bytes on every x86-64 machine with AVX2 (scrppl/numerics.py).
CPU ?= portable
ifeq ($(CPU),native)
export SCRPPL_NATIVE_CPU := 1
endif

# Every extra: the lock (and so `make`'s .venv) installs everything; `pip install scrppl` only the core.
LOCK_EXTRAS := --extra render --extra dask --extra test --extra book --extra dev

.PHONY: help reproduce quick test test-slow lint lock book claims student dist clean-results

help:
	@echo "make reproduce   the whole pipeline on the embedded default dataset -> $(OUT)/ (PROFILE=quick for a short run)"
	@echo "make test        the test suite (without the end-to-end runs marked slow: make test-slow)"
	@echo "make book        the executed HTML book, offline -> book/_build/html (then a browser check)"
	@echo "make claims      every chapter's asserted claims against the book profile of SEED (e.g. SEED=1)"
	@echo "make student     student copies of the exercise notebooks (solutions replaced by stubs) -> build/student"
	@echo "make dist        the sdist and wheel -> dist/ (the wheel installs the core; extras render, dask, all)"
	@echo "make lint        ruff"
	@echo "make lock        regenerate environment.lock and environment-core.lock from pyproject.toml (uv, in .venv)"

$(STAMP): environment.lock
	@bash scripts/make-venv.sh

reproduce: $(STAMP)
	$(VENV)/bin/scrppl reproduce --out $(OUT) --profile $(PROFILE) --seed $(SEED)

quick: $(STAMP)
	$(VENV)/bin/scrppl reproduce --out $(OUT)-quick --profile quick --seed $(SEED)

test: $(STAMP)
	$(VENV)/bin/python -m pytest -n $(WORKERS) -q -m "not slow"

# The long end-to-end runs (MCMC fits of whole tables, rendering datasets, the pipeline on a tree).
test-slow: $(STAMP)
	$(VENV)/bin/python -m pytest -n $(WORKERS) -q -m slow

# The book executes against the small `book` profile (results-book/); RESULTS=results uses a full run.
book: $(STAMP)
	SEED=$(SEED) $(if $(RESULTS),SCRPPL_RESULTS=$(RESULTS)) bash scripts/build-book.sh

# The chapters' claims against another seed's book profile (results-book-seed$(SEED)/): each hidden assert
# must hold for every seed, not only for the one the book is built with (scripts/book_claims.py).
claims: $(STAMP)
	bash scripts/book-claims.sh $(SEED)

student: $(STAMP)
	$(VENV)/bin/python scripts/make_student.py --out build/student

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# environment.lock: every extra (what .venv gets). environment-core.lock: the core dependencies alone, at the
# versions of environment.lock (what `pip install scrppl` needs; tests/test_dist.py installs it with the wheel).
lock: $(STAMP)
	$(VENV)/bin/uv pip compile pyproject.toml $(LOCK_EXTRAS) \
		--generate-hashes --python-version 3.12 -o environment.lock
	$(VENV)/bin/uv pip compile pyproject.toml -c environment.lock --annotation-style line \
		--generate-hashes --python-version 3.12 -o environment-core.lock

# The sdist and the wheel (built from the sdist, offline, with the locked setuptools).
dist: $(STAMP)
	bash scripts/build-dist.sh dist

clean-results:
	rm -rf $(OUT) $(OUT)-quick results-book results-book-*
