PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# one stamp per install: `make test` installs the test extra only; `make bench` adds FilterPy
STAMP := $(VENV)/.installed-test
BENCH_STAMP := $(VENV)/.installed-bench

.PHONY: test test-fast demo bench lint clean arm docs-figures

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[all,test]'
	$(BIN)/python -m firmware_c.build >/dev/null  # the C core for this host (else built at first use)
	$(BIN)/python -m sim_hil.native >/dev/null || true  # the simulator's C physics (else Python)
	# MAVProxy for the test that it shows our WIND: its headless core only (its GUI needs opencv and vtk)
	$(BIN)/python -m pip install -q --no-deps 'MAVProxy>=1.8' defusedxml || true
	touch $(STAMP)

$(BENCH_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[all,test,bench]'
	touch $(BENCH_STAMP) $(STAMP)

# the suite: two workers for what runs in process or on files, then two for the UDP tests (each on its own free
# ports; they mostly wait: 2.5 minutes where one at a time took 4), then the terminal tests (tmux) one at a time
test: $(STAMP)
	$(BIN)/ruff check balloon_core firmware_py sim_hil ground_station postflight sil study tests benchmarks tools
	$(BIN)/python -m pytest -n 2 -m "not network and not terminal"
	$(BIN)/python -m pytest -n 2 -m "network and not terminal"
	$(BIN)/python -m pytest -m "terminal"

# the quick loop: no slow, UDP, terminal or Dask tests (under 2 minutes)
test-fast: $(STAMP)
	$(BIN)/ruff check balloon_core firmware_py sim_hil ground_station postflight sil study tests benchmarks tools
	$(BIN)/python -m pytest -n 2 -m "not slow and not network and not terminal and not dask"

demo: $(STAMP)
	$(BIN)/balloon-sil --scenario paper-reference

# the C core on a Cortex-M4F under QEMU (needs gcc-arm-none-eabi, libnewlib-arm-none-eabi, qemu-system-arm)
arm: $(STAMP)
	$(BIN)/python tools/arm.py

# the figures and numbers the docs quote, from their commands (docs/sil.png, docs/study.md, docs/figures.json)
docs-figures: $(STAMP)
	$(BIN)/python tools/docs_figures.py

bench: $(BENCH_STAMP)
	$(BIN)/python -m benchmarks.run_all

lint: $(STAMP)
	$(BIN)/ruff check balloon_core firmware_py sim_hil ground_station postflight sil study tests benchmarks tools

clean:
	rm -rf $(VENV) out build *.egg-info firmware_c/build
