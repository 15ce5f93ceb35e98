PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed

.PHONY: install demo test test-core bench lint clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip >/dev/null
	$(PIP) install -c constraints.txt -e '.[all,dev]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/excite compare --episodes 100 --out demo_out
	@echo "plots and tables: demo_out/ (summary.json, segments.csv, *.png)"

test: $(STAMP) test-core
	$(VENV)/bin/ruff check excite envs agents tests benchmarks
	# one BLAS thread per test worker: two workers with two threads each on two cores made the
	# many small dense factorisations (excite/calibration/wander.py) 2-3x slower
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -n 2 --dist loadgroup tests

# A core-only install (numpy, scipy; no extras) in its own venv runs calibrate/segment/validate.
CORE_VENV := .venv-core
test-core:
	$(PYTHON) -m venv $(CORE_VENV)
	$(CORE_VENV)/bin/python -m pip install -q --upgrade pip
	$(CORE_VENV)/bin/python -m pip install -q -c constraints.txt .
	$(CORE_VENV)/bin/python tests/core_only.py

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

lint: $(STAMP)
	$(VENV)/bin/ruff check excite envs agents tests benchmarks

clean:
	rm -rf $(VENV) $(CORE_VENV) demo_out .pytest_cache .hypothesis
