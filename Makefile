# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test bench eval clean

$(BIN)/dynremove: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $(BIN)/dynremove

demo: $(BIN)/dynremove
	$(BIN)/dynremove demo

test: $(BIN)/dynremove
	$(BIN)/python -m pytest -q

bench: $(BIN)/dynremove
	$(BIN)/dynremove bench

eval: $(BIN)/dynremove
	$(BIN)/dynremove eval ../shared/data/davis --jobs 2

clean:
	rm -rf out build *.egg-info
