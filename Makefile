PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test demo bench lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test,bench]'
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/ruff check firmware_py ground_station sim_hil tests benchmarks
	$(BIN)/python -m pytest

demo: $(STAMP)
	$(BIN)/balloon-sil --scenario paper-reference

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run_all

lint: $(STAMP)
	$(BIN)/ruff check firmware_py ground_station sim_hil tests benchmarks

clean:
	rm -rf $(VENV) out
