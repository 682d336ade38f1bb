# README's commands. Every target that runs code installs the venv first when it is missing
# or older than pyproject.toml / constraints.txt.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test test-slow bench gpu-check lint format clean

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

# On a machine with a CUDA GPU (docs/performance.md): the gpu tests, Pour-v0's throughput at
# 256, 1024 and 4096 worlds (leaderboard/env_cuda.*), and two minutes of training with the
# liquid on the GPU, which prints SB3's env steps per second (time/fps).
gpu-check: $(STAMP)
	$(BIN)/python -m pytest -q -m gpu
	$(BIN)/pourbench bench env --device cuda --against none
	$(BIN)/pourbench train --device cuda --num-envs 256 --workers 1 --n-steps 16 \
		--no-icm --no-curriculum --eval-every-steps 0 --eval-episodes 1 --budget-s 120 \
		--out runs/gpu-check/train-$$(date +%s)

lint: $(STAMP)
	$(BIN)/ruff check pourbench tests
	$(BIN)/ruff format --check pourbench tests

format: $(STAMP)
	$(BIN)/ruff check --fix pourbench tests
	$(BIN)/ruff format pourbench tests

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
