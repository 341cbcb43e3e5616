# Two commands a fresh machine needs: `make demo` and `make test`. Each creates .venv if missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= out

.PHONY: demo test test-fast bench lint clean

$(BIN)/dualarm-mpc: pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q -e '.[test]'
	touch $@

# The plan is made as on the robot (closed_loop.ON_ROBOT): each object aimed at its own slot of its
# goal, keeping 1 cm from the others.
demo: $(BIN)/dualarm-mpc
	mkdir -p $(OUT)
	$(BIN)/dualarm-mpc plan table1_vc --rule 2 --set 'goal_margin: 0.03' --set 'goal_slots: true' \
		--set 'object_clearance: 0.01' --out $(OUT)/plan.json --plot $(OUT)/plan.png
	$(BIN)/dualarm-mpc simulate table1_vc --rule 2 --html $(OUT)/replay.html \
		--summary $(OUT)/summary.json

# -n auto: a pytest-xdist worker per core; much of the suite (Drake's physics, the controller's
# Python systems) runs on one core, so two workers take 0.6 of the serial time on 2 cores.
# worksteal: the two paper scenes in Drake are a third of the suite; an idle worker takes over
# what is left of the other's queue. -rs: a skipped test says why.
PYTEST := $(BIN)/python -m pytest -q -rs -n auto --dist worksteal

test: $(BIN)/dualarm-mpc
	$(PYTEST)

# The quick loop while working: everything but the tests marked slow (closed loop, Chromium,
# subprocesses, Dask), about a minute.
test-fast: $(BIN)/dualarm-mpc
	$(PYTEST) -m 'not slow'

bench: $(BIN)/dualarm-mpc
	$(BIN)/python bench/table2.py

lint: $(BIN)/dualarm-mpc
	$(BIN)/ruff check dualarm_mpc tests bench examples

clean:
	rm -rf $(VENV) $(OUT)
