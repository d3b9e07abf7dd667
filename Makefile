# The two commands of the README. Both bootstrap .venv themselves on a machine
# that has only Python 3 (>= 3.10), gcc and make.
PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python

.PHONY: generate test clean

$(VENV)/.stamp-base: pyproject.toml
	@test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -e .
	@touch $@

$(VENV)/.stamp-test: $(VENV)/.stamp-base
	$(VPY) -m pip install --quiet -e '.[test]'
	@touch $@

generate: $(VENV)/.stamp-base
	$(VPY) -m derive generate --out generated

test: $(VENV)/.stamp-test
	$(VPY) -m pytest -q

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
