"""MPS export (``dualarm-mpc plan --export DIR``): each horizon's MILP as a file, with an index.

For every horizon the planner tries, :class:`MpsExport` writes the *monolithic* MILP of that
step and horizon — the MLD model, pruning, the step's specification (φ_task and the rules) and
cost (17), the program ``--search monolithic`` solves — as ``stepSS_TT.mps`` (written by
HiGHS), and ``index.json`` naming each file's step, horizon, objects and the planner's status
there. With the skeleton search (the default) the planner never solves that program as one: it
solves many narrowed pieces of it, which are no instance on their own. The monolithic MILP is
what another solver can take, and its optimum is the one the search returns at that horizon
(equal, or below it where only a hand-over the search left out is cheaper: docs/search.md).

The index is rewritten after every file, so an interrupted plan leaves a complete index of the
horizons tried so far. Every file is written whole or not at all (``outputs.py``); the first write
that fails ends the export (kept in ``error``), not the plan.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from dualarm_mpc import outputs
from dualarm_mpc.horizon import HorizonProgram
from dualarm_mpc.scenario import Scenario
from dualarm_mpc.sequential import HorizonTried
from dualarm_mpc.solver import write_mps

INDEX = "index.json"
FILES = re.compile(r"step\d+_T\d+\.mps|" + re.escape(INDEX))  # every name the export writes


def exported_file(name: str) -> bool:
    """Whether the export may write a file named ``name`` in its directory."""
    return FILES.fullmatch(name) is not None


class MpsExport:
    """Writes the monolithic MILP of each horizon tried into ``directory`` (an ``on_try``
    callback of :func:`sequential.plan`)."""

    def __init__(self, scenario: Scenario, directory: str | Path) -> None:
        self.scenario = scenario
        self.directory = Path(directory)
        self.directory.mkdir(exist_ok=True)
        self.entries: list[dict] = []
        self.error: OSError | None = None

    def __call__(self, tried: HorizonTried) -> None:
        if self.error is None:
            try:
                self._export(tried)
            except OSError as err:
                self.error = err

    def _export(self, tried: HorizonTried) -> None:
        res, spec = tried.result, tried.spec
        program = HorizonProgram(self.scenario, tried.state, list(spec.objects), res.horizon)
        form = program.standard_form(spec)
        name = f"step{tried.step:02d}_T{res.horizon:02d}.mps"
        outputs.write_with(self.directory / name, lambda tmp: write_mps(form, tmp), ".mps")
        self.entries.append({
            "step": tried.step, "horizon": res.horizon,
            "objects": [self.scenario.task.objects[j].name for j in spec.objects],
            "m_o": spec.m_o, "status": res.status.value,
            "cost": res.cost if res.status.has_solution else None,
            "file": name, "variables": len(form.c), "constraints": form.A.shape[0],
            "integers": int(np.count_nonzero(form.integer)),
        })
        self._write_index()

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
