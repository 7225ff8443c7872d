# The two commands: `make demo` runs the demo on the bundled bags, `make test` runs the tests.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TF2    := $(VENV)/.tf2_msgs

.PHONY: venv test demo bench mutation clean

venv: $(STAMP) $(TF2)

# Re-installs only when the package metadata changes; otherwise a no-op.
$(STAMP): setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	touch $(STAMP)

# tf2_msgs (/tf, /tf_static) has no PyPI wheel: build it into the venv (about 30 s once; says
# so and goes on without it where there is no compiler). See docs/development.md.
$(TF2): $(STAMP) tools/build_tf2_msgs.py
	$(PY) tools/build_tf2_msgs.py
	touch $(TF2)

test: venv
	$(PY) -m pytest -q test

demo: venv
	$(PY) -m eye_in_hand.demo

bench: venv
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

# Before a release: plant known bugs in core/, io/ and offline code, one at a time; every one
# must make a test fail (tools/mutation.py).
mutation: $(STAMP)
	$(PY) tools/mutation.py

clean:
	rm -rf $(VENV) build install log .pytest_cache
