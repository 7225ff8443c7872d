# The two commands: `make demo` runs the demo on the bundled bags, `make test` runs the tests.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
IFACES := $(VENV)/.interfaces

.PHONY: venv test lint demo bench mutation clean

# The package's bytecode, as `pip install` of a wheel writes it: without it every process
# (each command, node, worker and test subprocess) compiles the modules it imports again where
# Python may not write bytecode itself (PYTHONDONTWRITEBYTECODE): 0.03 s of CPU per `process`
# worker, more for its main process. Only modules changed since are compiled again (0.05 s when
# nothing changed), and Python itself compiles a module edited after that in memory. A tree
# that cannot be written (read-only, another owner) is said in one line, not an error.
venv: $(STAMP) $(IFACES)
	@$(PY) -m compileall -q eye_in_hand >/dev/null 2>&1 || echo "make venv: some of the \
	package's bytecode was not written (a read-only tree, or a module that does not compile)"

# Re-installs only when the package metadata changes; otherwise a no-op.
$(STAMP): setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	touch $(STAMP)

# tf2_msgs (/tf, /tf_static) has no PyPI wheel, and eye_in_hand_interfaces (the calibration
# services) is ours: build both into the venv (about 1-2 min once; says so and goes on without
# them where there is no compiler). See docs/development.md.
$(IFACES): $(STAMP) tools/build_interfaces.py $(wildcard eye_in_hand_interfaces/*.txt \
           eye_in_hand_interfaces/*.xml eye_in_hand_interfaces/msg/* eye_in_hand_interfaces/srv/*)
	$(PY) tools/build_interfaces.py
	touch $(IFACES)

test: venv
	$(PY) -m pytest -q test

# ruff check (ruff.toml: pycodestyle, pyflakes, isort, bugbear, pyupgrade) on the package, its
# tests, benchmarks, tools and launch file; mypy (mypy.ini: strict on core/ and io/) on the
# package. docs/development.md, "Lint".
lint: venv
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

demo: venv
	$(PY) -m eye_in_hand.demo

bench: venv
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

# Plant known bugs in core/, io/, nodes/ and the offline path, one at a time, each against its
# module's own tests, in private copies of the tree (2 workers); every one must make a test
# fail (tools/mutation.py). .ci/run calls this after `make test`.
mutation: venv
	$(PY) tools/mutation.py -j 2

clean:
	rm -rf $(VENV) build install log .pytest_cache

# The oldest dependency versions the package declares (setup.py minimums, pinned in
# .ci/min-constraints.txt): a fresh build/min-venv made by the venv recipe with those pins,
# a check that the pins are what got installed, then the bag, offline and calibration tests
# in it. .ci/run calls this after `make test`.
MIN_VENV       := build/min-venv
MIN_DEPS_TESTS := test/io test/commands/test_bag_info.py test/commands/test_play.py \
                  test/commands/test_record_play_round_trip.py test/commands/test_process.py \
                  test/commands/test_calibrate_handeye_bag.py \
                  test/commands/test_calibrate_camera.py test/sim/test_output.py \
                  test/test_offline.py test/core/test_quat_scipy.py test/ros/test_outputs_cdr.py \
                  test/core/test_hot_path_bits.py

.PHONY: test-min-deps
test-min-deps:
	rm -rf $(MIN_VENV)
	PIP_CONSTRAINT=$(CURDIR)/.ci/min-constraints.txt \
	  $(MAKE) --no-print-directory venv VENV=$(MIN_VENV)
	$(MIN_VENV)/bin/python .ci/check_min_versions.py .ci/min-constraints.txt
	$(MIN_VENV)/bin/python -m pytest -q -p no:cacheprovider $(MIN_DEPS_TESTS)
