# Two commands for a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck unit bench clean venv

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/safer-hil demo

lint: $(STAMP)
	$(BIN)/ruff check fsw hil_sim ground tests

typecheck: $(STAMP)
	$(BIN)/mypy fsw

unit: $(STAMP)
	$(BIN)/pytest -n 2 --dist loadfile

test: lint typecheck unit

bench: $(STAMP)
	$(BIN)/safer-fsw bench executive
	$(BIN)/safer-hil bench render

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache
