# Two commands do all the set-up on a fresh machine:
#   make demo   - create .venv, install, run the main job on the bundled defaults and data
#   make test   - create .venv, install, run the whole test suite
PYTHON ?= python3
VENV ?= .venv
BIN = $(VENV)/bin
STAMP = $(VENV)/.installed
BENCH_STAMP = $(VENV)/.installed-bench

.PHONY: demo test lint bench status clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[tests]"
	touch $(STAMP)

# The benchmarks' peers (numba: its llvmlite alone unpacks to about 170 MB) only for `make
# bench`: the tests and the demo do not use them, and CI installs from scratch.
$(BENCH_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[tests,bench]"
	touch $(BENCH_STAMP)

# The main job: the paper's test determines only the series compliance; plan-test recommends
# a test for the preloads; that test on a worn drive (bundled records) determines both
# preloads and the three dampers, flags the preload loss, and compare.png shows the two fits
# side by side; then one verified steady state; last, the forecast of the worn drive.
PRELOAD_FIT = nut_preload,bearing_preload,c_b,c_s,c_n
demo: $(STAMP)
	$(BIN)/bsfs identify --out out/identify
	$(BIN)/bsfs plan-test --fit $(PRELOAD_FIT) --out out/plan
	$(BIN)/bsfs identify --data preload-loss --fit $(PRELOAD_FIT) --compare out/identify \
		--out out/preload-loss
	$(BIN)/bsfs simulate --frequency 500 --force 5000 --verify --out out/simulate
	$(BIN)/bsfs predict --from out/preload-loss --force 100 --out out/predict

test: $(STAMP)
	$(BIN)/python tests/run_each.py

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(BENCH_STAMP)
	$(BIN)/python benchmarks/run_all.py

# README's status table from the committed outputs (benchmarks/results, docs, tests/last_run.json)
status:
	$(if $(wildcard $(BIN)/python),$(BIN)/python,$(PYTHON)) scripts/status.py

clean:
	rm -rf out .pytest_cache
