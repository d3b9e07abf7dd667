# The two commands of the README. Both bootstrap .venv themselves on a machine
# that has only Python 3 (>= 3.11), gcc and make.
PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python

.PHONY: generate test docs figures clean

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

# -n logical: one pytest-xdist worker per CPU the process may use (also with psutil installed,
# where -n auto would count physical cores only); loadgroup keeps the tests marked xdist_group
# (shared symbolic work in memory) on one worker
test: $(VENV)/.stamp-test
	$(VPY) -m pytest -q -n logical --dist loadgroup

$(VENV)/.stamp-docs: $(VENV)/.stamp-base
	$(VPY) -m pip install --quiet -e '.[docs]'
	@touch $@

# the documentation site (mkdocs.yml) into site/, warnings as errors; no network needed
docs: $(VENV)/.stamp-docs
	NO_MKDOCS_2_WARNING=1 $(VPY) -m mkdocs build --strict --site-dir site

# the figures of docs/img/, committed: the convention figures (frames, DH parameters) and the
# README's 8 IK solutions of one UR5 pose
figures: $(VENV)/.stamp-base
	$(VPY) -m derive.reports.diagrams --out docs/img
	$(VPY) -m derive plot ur5 --ik-of 10 -60 80 -20 45 30 --deg --out docs/img/ur5_ik.png

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
