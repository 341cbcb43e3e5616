"""MPS export (``dualarm-mpc plan --export DIR``): each horizon's MILP as a file, with an index.

For every horizon the planner tries, the caller gives :class:`MpsExport` the *monolithic* MILP of
that step and horizon in standard form — the MLD model, pruning, the step's specification (φ_task
and the rules) and cost (17), the program ``--search monolithic`` solves — and the planner's
status there; it writes the MILP as ``stepSS_TT.mps`` (written by HiGHS), and ``index.json``
naming each file's step, horizon, objects and that status. With the skeleton search (the
default) the planner never solves that program as one: it solves many narrowed pieces of it,
which are no instance on their own. The monolithic MILP is what another solver can take, and its
optimum is the one the search returns at that horizon (equal, or below it where only a hand-over
the search left out is cheaper: docs/search.md).

The index is rewritten after every file, so an interrupted plan leaves a complete index of the
horizons tried so far. Every file is written whole or not at all (``outputs.py``); the first write
that fails ends the export (kept in ``error``), not the plan.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from dualarm_mpc.base import outputs
from dualarm_mpc.milp.backends import write_mps
from dualarm_mpc.milp.solver import StandardForm, Status
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import Specification

INDEX = "index.json"
FILES = re.compile(r"step\d+_T\d+\.mps|" + re.escape(INDEX))  # every name the export writes


def exported_file(name: str) -> bool:
    """Whether the export may write a file named ``name`` in its directory."""
    return FILES.fullmatch(name) is not None


class MpsExport:
    """Writes the monolithic MILP of each horizon tried into ``directory``."""

    def __init__(self, scenario: Scenario, directory: str | Path) -> None:
        self.scenario = scenario
        self.directory = Path(directory)
        self.directory.mkdir(exist_ok=True)
        self.entries: list[dict] = []
        self.error: OSError | None = None

    def add(self, step: int, spec: Specification, horizon: int, status: Status, cost: float,
            form: StandardForm) -> None:
        """Write ``form``, the MILP of the ``step``-th sequential step (from 1) of ``spec`` at
        ``horizon``, where the planner found ``status`` and ``cost``; after a failed write,
        nothing (the export has ended)."""
        if self.error is not None:
            return
        name = f"step{step:02d}_T{horizon:02d}.mps"
        try:
            outputs.write_with(self.directory / name, lambda tmp: write_mps(form, tmp), ".mps")
            self.entries.append({
                "step": step, "horizon": horizon,
                "objects": [self.scenario.task.objects[j].name for j in spec.objects],
                "m_o": spec.m_o, "status": status.value,
                "cost": cost if status.has_solution else None,
                "file": name, "variables": len(form.c), "constraints": form.A.shape[0],
                "integers": int(np.count_nonzero(form.integer)),
            })
            self._write_index()
        except OSError as err:
            self.error = err

    def _write_index(self) -> None:
        solver = self.scenario.solver
        index = {
            "scenario": self.scenario.name, "rule": self.scenario.task.rule,
            "delivery": self.scenario.task.delivery, "search": solver.search,
            "solver": solver.backend,
            "exported": "the monolithic MILP of each horizon tried (minimize; binaries are "
                        "integer columns in [0, 1]); status and cost are the planner's there: "
                        "with the skeleton search, 'infeasible' is 'no plan without the "
                        "hand-overs the search leaves out' (docs/search.md)",
            "horizons": self.entries,
        }
        outputs.write(self.directory / INDEX, outputs.json_text(index))
