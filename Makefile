# Two commands on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint install bytecode bench clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The package's bytecode, as a wheel install writes it. Where Python writes none itself
# (PYTHONDONTWRITEBYTECODE, as on our CI machines, or a read-only checkout), an editable
# install would compile every gfjax module from source in every process: 0.1 s of each run.
# Up to date it costs 0.05 s.
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q gfjax

demo: bytecode
	$(BIN)/gfjax demo --force
	$(BIN)/gfjax warmup --methods vote

test: lint bytecode
	$(BIN)/python -m pytest -n 2 -q

# Not part of `make test`: whole-process timings against the peer packages, judged as ratios
# to the recorded ones (experiments/results/bench_guard.md); needs ../shared/data.
bench: bytecode
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[bench]'
	$(BIN)/python experiments/bench_guard.py

lint: $(STAMP)
	$(BIN)/ruff check gfjax tests experiments

clean:
	rm -rf $(VENV) *.egg-info
