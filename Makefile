# The two commands: `make demo` runs the demo on the bundled bags, `make test` runs the tests.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: venv test demo bench mutation clean

venv: $(STAMP)

# Re-installs only when the package metadata changes; otherwise a no-op.
$(STAMP): setup.py setup.cfg package.xml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	touch $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q test

demo: $(STAMP)
	$(PY) -m eye_in_hand.demo

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

# Before a release: plant known bugs in core/, io/ and offline code, one at a time; every one
# must make a test fail (tools/mutation.py).
mutation: $(STAMP)
	$(PY) tools/mutation.py

clean:
	rm -rf $(VENV) build install log .pytest_cache
