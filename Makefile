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

# The plan is made as on the robot (simulate.ON_ROBOT): each object aimed at its own slot of its goal.
demo: $(BIN)/dualarm-mpc
	mkdir -p $(OUT)
	$(BIN)/dualarm-mpc plan table1_vc --rule 2 --set 'goal_margin: 0.03' --set 'goal_slots: true' \
		--out $(OUT)/plan.json --plot $(OUT)/plan.png
	$(BIN)/dualarm-mpc simulate table1_vc --rule 2 --html $(OUT)/replay.html \
		--summary $(OUT)/summary.json

test: $(BIN)/dualarm-mpc
	$(BIN)/python -m pytest -q -rs  # -rs: a skipped test says why

# The quick loop while working: everything but the tests marked slow (closed loop, Chromium,
# subprocesses, Dask), about a minute.
test-fast: $(BIN)/dualarm-mpc
	$(BIN)/python -m pytest -q -rs -m 'not slow'

bench: $(BIN)/dualarm-mpc
	$(BIN)/python bench/table2.py

lint: $(BIN)/dualarm-mpc
	$(BIN)/ruff check dualarm_mpc tests bench examples

clean:
	rm -rf $(VENV) $(OUT)
