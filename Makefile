# Set-up is real: a fresh machine with Python 3.11 and pip runs `make demo` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-full bench clean

$(BIN)/python:
	$(PY) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/workbench demo --out out/demo --json out/demo/summary.json
	$(BIN)/workbench study studies/sn637_servo.toml --out out/study
	$(BIN)/workbench verify plants/p888_51_sn637_creep.toml --controller out/study/controllers/sn637_loopshape.json --out out/verify
	$(BIN)/workbench synth plants/p888_51_sn637.toml --effect creep --seed 1 --out out/calibrate/record.csv
	$(BIN)/workbench calibrate out/calibrate/record.csv --plant plants/p888_51_sn637.toml --out out/calibrate --json out/calibrate/result.json
	$(BIN)/workbench selfsense plants/p888_51_sn637_creep.toml --out out/selfsense --json out/selfsense/selfsense.json
	$(BIN)/workbench study studies/fsm_servo.toml --out out/fsm
	$(BIN)/workbench verify plants/fsm_p888_51.toml --controller out/fsm/controllers/fsm_servo.json --out out/fsm_verify

test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadfile

test-full: $(STAMP)
	WORKBENCH_FULL=1 $(BIN)/python -m pytest -q -n auto --dist loadfile

bench: $(STAMP)
	$(BIN)/workbench bench --json out/bench.json

clean:
	rm -rf $(VENV) out .pytest_cache
