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

.PHONY: help reproduce quick test test-slow lint lock book claims student clean-results

help:
	@echo "make reproduce   the whole pipeline on the embedded default dataset -> $(OUT)/ (PROFILE=quick for a short run)"
	@echo "make test        the test suite (without the end-to-end runs marked slow: make test-slow)"
	@echo "make book        the executed HTML book, offline -> book/_build/html (then a browser check)"
	@echo "make claims      every chapter's asserted claims against the book profile of SEED (e.g. SEED=1)"
	@echo "make student     student copies of the exercise notebooks (solutions replaced by stubs) -> build/student"
	@echo "make lint        ruff"
	@echo "make lock        regenerate environment.lock from pyproject.toml (needs uv, installed in .venv)"

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

lock: $(STAMP)
	$(VENV)/bin/uv pip compile pyproject.toml --extra test --extra book --extra dev \
		--generate-hashes --python-version 3.12 -o environment.lock

clean-results:
	rm -rf $(OUT) $(OUT)-quick results-book results-book-*
