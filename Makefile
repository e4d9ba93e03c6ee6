# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# the shared evaluation data (the tests read DYNREMOVE_DATA too)
DYNREMOVE_DATA ?= ../shared/data

.PHONY: demo test lint test-nojit bench eval clean

# the package (what `make demo` needs) ...
$(BIN)/dynremove: pyproject.toml
	@echo "installing dynremove and its dependencies into $(VENV) (about a minute, once)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	touch $(BIN)/dynremove

# ... and what the tests also exercise: pytest, HEIC input, Dask, the notebook
$(VENV)/.test-extras: $(BIN)/dynremove
	$(BIN)/python -m pip install -q -e ".[test,heic,dask,notebook]"
	touch $(VENV)/.test-extras

# the total time, and whether it included the install (the first run also compiles
# the kernels, once)
demo:
	@start=$$(date +%s); \
	if $(MAKE) -q --no-print-directory $(BIN)/dynremove 2>/dev/null; \
	then what="already installed"; else what="install included"; fi; \
	$(MAKE) --no-print-directory $(BIN)/dynremove && $(BIN)/dynremove demo && \
	echo "make demo: $$(( $$(date +%s) - start )) s in all, $$what"

test: $(VENV)/.test-extras
	$(BIN)/python -m pytest -q

lint: $(VENV)/.test-extras
	$(BIN)/python -m ruff check .

# The scan's kernels run as plain Python (numba off), as in stumpy's coverage run:
# the equations, the hand-made cases and the kernel-vs-reference test.
test-nojit: $(VENV)/.test-extras
	NUMBA_DISABLE_JIT=1 $(BIN)/python -m pytest -q -p no:cacheprovider \
		tests/test_scan_cases.py tests/test_equations.py tests/test_dbscan.py \
		"tests/test_kernel.py::test_kernel_equals_reference[paper]" \
		tests/test_kernel.py::test_similarity_map_equals_reference

bench: $(BIN)/dynremove
	$(BIN)/dynremove bench

eval: $(BIN)/dynremove
	$(BIN)/dynremove eval $(DYNREMOVE_DATA)/davis --jobs 2

clean:
	rm -rf out build *.egg-info
