# Two commands a fresh machine needs: `make demo` and `make test`. Each creates .venv if missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= out

.PHONY: demo figures test test-fast falsify bench lint docs clean

# What each target needs, installed once per change of pyproject.toml (README.md, "What each
# extra installs"): `make demo` the package alone; `make docs` it and Sphinx; the tests every
# extra (every solver, Dask, Chromium's driver, Sphinx, ...). A larger install marks the smaller
# ones it contains as done, so `make demo` after `make test` installs nothing.
$(VENV)/.installed-base: pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q -e .
	touch $@

$(VENV)/.installed-docs: pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q -e '.[docs]'
	touch $@ $(VENV)/.installed-base

$(VENV)/.installed-test: pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q -e '.[test]'
	touch $@ $(VENV)/.installed-docs $(VENV)/.installed-base

# The plan is made as on the robot (model/scenario.py, ON_ROBOT): each object aimed at its own slot
# of its goal, keeping 1 cm from the others, held under the tool.
demo: $(VENV)/.installed-base
	mkdir -p $(OUT)
	$(BIN)/dualarm-mpc plan table1_vc --rule 2 --set 'goal_margin: 0.03' --set 'goal_slots: true' \
		--set 'object_clearance: 0.01' --set 'grasp_tolerance: 0.0065' --out $(OUT)/plan.json \
		--plot $(OUT)/plan.png
	$(BIN)/dualarm-mpc simulate table1_vc --rule 2 --html $(OUT)/replay.html \
		--summary $(OUT)/summary.json --plot $(OUT)/run.png

# Every image of README.md and docs/ made anew from `make demo`'s two commands (read from the
# recipe above): plan.png, run.png, and replay.html in headless Chromium at t = 25 s, into
# docs/img/ with figures.json, the data each was made from (tests/test_figures.py checks it).
figures: $(VENV)/.installed-test
	$(BIN)/python bench/figures.py

# -n auto: a pytest-xdist worker per core; much of the suite (Drake's physics, the controller's
# Python systems) runs on one core, so two workers take 0.6 of the serial time on 2 cores.
# worksteal: the two paper scenes in Drake are a third of the suite; an idle worker takes over
# what is left of the other's queue. -rs: a skipped test says why; --durations: the slowest
# tests, which keep the suite within its ten minutes (docs/testing.md).
PYTEST := $(BIN)/python -m pytest -q -rs --durations=15 -n auto --dist worksteal

test: $(VENV)/.installed-test
	$(PYTEST) -m 'not falsify'

# The whole-task search against the monolithic MILP on 3 and 4 objects, seeds 0-9
# (tests/test_whole.py): the MILP proves each in 10 s to several minutes, hours in all; `make
# test` runs 3 objects, seed 7 (the quickest measured: 25 s alone, seed 1 55 s, seed 4 430 s).
# Also the consistency check on 500 random rules (150 in `make test`) and the motion bound on two
# more scenes (tests/test_check_sound.py, tests/test_motion.py).
falsify: $(VENV)/.installed-test
	$(PYTEST) -m falsify

# The quick loop while working: everything but the tests marked slow (closed loop, Chromium,
# subprocesses, Dask), about a minute.
test-fast: $(VENV)/.installed-test
	$(PYTEST) -m 'not slow'

bench: $(VENV)/.installed-test
	$(BIN)/python bench/table2.py

lint: $(VENV)/.installed-test
	$(BIN)/ruff check dualarm_mpc tests bench examples

# The API reference from the docstrings, into build/docs (index.html). Every reference that names
# nothing fails it (nitpicky, -W; docs/api/conf.py); -E reads every page anew, so a warning is never
# hidden by an earlier build. tests/test_docs.py runs the same build under `make test`.
SPHINX := $(BIN)/python -m sphinx -E -n -W --keep-going -q -b html

docs: $(VENV)/.installed-docs
	$(SPHINX) docs/api build/docs
	@echo "the API reference: build/docs/index.html"

clean:
	rm -rf $(VENV) $(OUT) build/docs
