# Dev venv, tests, extension zips. Everything runs from the venv; CI starts with no .venv.
PYTHON311 := $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PYTEST_ARGS ?= tests

.PHONY: venv test extension demo bench clean

venv: $(STAMP)

# Re-installs when requirements.txt changes; bpy only exists for 3.11, so refuse others.
$(STAMP): requirements.txt
	@$(PYTHON311) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11) and "Python 3.11 is required, found " + sys.version)'
	test -x $(PY) || $(PYTHON311) -m venv $(VENV)
	$(PY) -m pip install -r requirements.txt
	touch $@

test: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_ARGS)

extension: $(STAMP)
	$(PY) tools/build_extension.py --output-dir dist

demo: $(STAMP)
	$(PY) benchmarks/demo.py

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

clean:
	rm -rf dist out
	rm -f wheels/*.whl
