# README's commands. Every target that runs code installs the venv first when it is missing
# or older than pyproject.toml / constraints.txt.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test test-slow bench lint format clean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade "pip>=24"
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/pourbench demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	$(BIN)/pourbench bench all

lint: $(STAMP)
	$(BIN)/ruff check pourbench tests
	$(BIN)/ruff format --check pourbench tests

format: $(STAMP)
	$(BIN)/ruff check --fix pourbench tests
	$(BIN)/ruff format pourbench tests

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
