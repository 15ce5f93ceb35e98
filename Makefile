PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
STAMP  := $(VENV)/.installed
# excite live's tests run in a venv of their own (see test-live)
ROS_VENV  := .venv-ros
ROS_STAMP := $(ROS_VENV)/.installed

.PHONY: install demo test test-fast test-core test-live bench bench-live lint clean docs

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip >/dev/null
	$(PIP) install -c constraints.txt -e '.[all,dev,docs]'
	touch $(STAMP)

install: $(STAMP)

# the headline: time to 0.5% on the slip env, the scripted baselines at their tuned speeds
DEMO_PROTOCOLS = slip_aware,learned,straight_spin:speed=0.16,umbmark:speed=0.16,arcs:speed=0.16,greedy:max_speed=0.13,random:max_speed=0.25

demo: $(STAMP)
	$(VENV)/bin/excite compare --target 0.005 --episodes 100 --protocols $(DEMO_PROTOCOLS) --out demo_out
	@echo "plots and tables: demo_out/ (summary.json, segments.csv, *.png)"

test: $(STAMP) $(ROS_STAMP) test-core docs
	$(VENV)/bin/ruff check excite envs agents tests benchmarks examples docs/hooks
	# one BLAS thread per test worker: two workers with two threads each on two cores made the
	# many small dense factorisations (excite/calibration/wander.py) 2-3x slower
	# the live tests (their own venv) run beside the main suite: they wait on simulated time
	# far more than they compute; their output follows the suite's
	mkdir -p build; EXCITE_LIVE_TESTS=1 OPENBLAS_NUM_THREADS=1 $(ROS_VENV)/bin/python -m pytest \
	    tests/live \
	    > build/live-tests.log 2>&1 & live=$$!; \
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -n 2 --dist loadgroup --ignore=tests/live tests; \
	main=$$?; wait $$live; status=$$?; cat build/live-tests.log; \
	test $$main -eq 0 && test $$status -eq 0

# excite live over real DDS, in a venv of its own with the ROS 2 wheels (the ros2 extra): their
# start-up hook re-runs every Python process of the venv with the ROS libraries on
# LD_LIBRARY_PATH, which the main suite's workers, Ray and torch need not live with. One test
# at a time: each runs a simulated robot and a live node faster than real time.
$(ROS_STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(ROS_VENV)
	$(ROS_VENV)/bin/python -m pip install -q --upgrade pip
	$(ROS_VENV)/bin/python -m pip install -q -c constraints.txt -e '.[sim,ros2,dev]'
	touch $(ROS_STAMP)

test-live: $(ROS_STAMP)
	EXCITE_LIVE_TESTS=1 OPENBLAS_NUM_THREADS=1 $(ROS_VENV)/bin/python -m pytest tests/live

# A core-only install (numpy, scipy; no extras) in its own venv runs calibrate/segment/validate.
CORE_VENV := .venv-core
test-core:
	$(PYTHON) -m venv $(CORE_VENV)
	$(CORE_VENV)/bin/python -m pip install -q --upgrade pip
	$(CORE_VENV)/bin/python -m pip install -q -c constraints.txt .
	# -P: not tests/ on sys.path (its tests/agents/ would shadow the installed agents package)
	$(CORE_VENV)/bin/python -P tests/core_only.py

# The documentation site (mkdocs.yml, docs/): warnings are errors; written to build/site.
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict --quiet

# The daily subset: everything but the tests marked slow (Monte Carlo, subprocesses, Ray,
# training); under a minute on 2 cores.
test-fast: $(STAMP)
	$(VENV)/bin/ruff check excite envs agents tests benchmarks examples docs/hooks
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -n 2 -m "not slow" --ignore=tests/live tests

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

# Live sessions against the simulated robot beside compare --target (BENCHMARKS.md).
bench-live: $(ROS_STAMP)
	OPENBLAS_NUM_THREADS=1 $(ROS_VENV)/bin/python benchmarks/bench_live.py

lint: $(STAMP)
	$(VENV)/bin/ruff check excite envs agents tests benchmarks examples docs/hooks

clean:
	rm -rf $(VENV) $(CORE_VENV) $(ROS_VENV) demo_out .pytest_cache .hypothesis
