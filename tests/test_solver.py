"""Tests for dualarm_mpc.solver at its boundary: what it refuses, what it prints (nothing), and how
Drake's Gurobi/MOSEK results map to statuses. The MILP solves themselves are tested in
test_program.py."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
from pydrake.solvers import GurobiSolver, MathematicalProgram, MosekSolver

from dualarm_mpc import solver
from dualarm_mpc.solver import SolveOptions, Status, drake_result, solve, standard_form


def _linear_program() -> tuple[MathematicalProgram, np.ndarray]:
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2, "x")
    prog.AddLinearCost(np.array([1.0, 1.0]), 0.0, x)
    prog.AddBoundingBoxConstraint(0.0, 1.0, x)
    return prog, x


@pytest.mark.parametrize(
    ("add", "kind"),
    [
        (lambda p, x: p.AddQuadraticCost(x[0] * x[0]), "QuadraticCost"),
        (lambda p, x: p.AddL2NormCost(np.eye(2), np.zeros(2), x), "L2NormCost"),
        (lambda p, x: p.AddLorentzConeConstraint(np.eye(2), np.zeros(2), x),
         "LorentzConeConstraint"),
        (lambda p, x: p.AddConstraint(lambda v: [v[0] * v[1]], [0.0], [1.0], x),
         "PyFunctionConstraint"),
    ],
)
def test_the_adapter_refuses_what_highs_cannot_take(add, kind) -> None:
    """A cost or constraint HiGHS cannot take is refused by name, never dropped."""
    prog, x = _linear_program()
    add(prog, x)
    with pytest.raises(ValueError, match=kind):
        standard_form(prog)


def test_linear_equalities_and_boxes_are_passed() -> None:
    prog, x = _linear_program()
    prog.AddLinearEqualityConstraint(x[0] + x[1] == 1.5)
    r = solve(prog)
    assert r.status is Status.OPTIMAL and r.objective == pytest.approx(1.5)


def test_highs_prints_nothing() -> None:
    """HiGHS's banner went to stdout on the first solve of a process, into the CLI's table."""
    code = ("import numpy as np\n"
            "from pydrake.solvers import MathematicalProgram\n"
            "from dualarm_mpc.solver import solve\n"
            "p = MathematicalProgram(); b = p.NewBinaryVariables(2)\n"
            "p.AddLinearCost(np.array([1.0, 2.0]), 0.0, b)\n"
            "p.AddLinearConstraint(b[0] + b[1] >= 1)\n"
            "assert solve(p).status.value == 'optimal'\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)
    assert run.stdout == "" and "HiGHS" not in run.stderr, (run.stdout, run.stderr)


# --- Drake's Gurobi and MOSEK, with their results faked (no licence here) -----------------------


@dataclass
class GurobiDetails:
    optimization_status: int
    objective_bound: float = float("nan")
    error_code: int = 0


@dataclass
class MosekDetails:
    solution_status: int
    rescode: int = 0


class FakeResult:
    def __init__(self, details, cost: float = 2.0, x=(1.0, 0.0)) -> None:
        self.details, self.cost, self.x = details, cost, np.array(x)

    def get_solver_details(self):
        return self.details

    def get_optimal_cost(self) -> float:
        return self.cost

    def GetSolution(self, variables):
        return self.x


OPTIONS = {b: SolveOptions(time_limit_s=10.0, backend=b) for b in ("gurobi", "mosek")}


@pytest.mark.parametrize(
    ("backend", "details", "wall", "status"),
    [
        ("gurobi", GurobiDetails(2, 2.0), 1.0, Status.OPTIMAL),
        ("gurobi", GurobiDetails(13, 1.5), 10.0, Status.FEASIBLE),  # SUBOPTIMAL
        ("gurobi", GurobiDetails(9), 10.0, Status.TIME_LIMIT),  # Drake returns no incumbent
        ("gurobi", GurobiDetails(3), 1.0, Status.INFEASIBLE),
        ("gurobi", GurobiDetails(4), 1.0, Status.UNBOUNDED),  # infeasible or unbounded
        ("gurobi", GurobiDetails(12), 1.0, Status.ERROR),  # numeric trouble
        ("gurobi", GurobiDetails(2, 2.0, error_code=10009), 1.0, Status.ERROR),
        ("mosek", MosekDetails(9), 1.0, Status.OPTIMAL),  # integer optimal
        ("mosek", MosekDetails(2), 10.0, Status.FEASIBLE),  # an incumbent, stopped early
        ("mosek", MosekDetails(5), 1.0, Status.INFEASIBLE),
        ("mosek", MosekDetails(6), 1.0, Status.UNBOUNDED),
        ("mosek", MosekDetails(0), 10.0, Status.TIME_LIMIT),
        ("mosek", MosekDetails(0), 1.0, Status.ERROR),  # infeasible MIP or a problem: unproven
        ("mosek", MosekDetails(1, rescode=1207), 1.0, Status.ERROR),
    ],
)
def test_drake_statuses_are_mapped_honestly(backend, details, wall, status) -> None:
    r = drake_result(OPTIONS[backend], FakeResult(details), [], wall)
    assert r.status is status, r
    assert (r.x is not None) == status.has_solution
    if status is Status.OPTIMAL:
        assert r.gap == 0.0 and r.objective == 2.0
    elif status is Status.FEASIBLE:
        # Gurobi's bound gives the gap; MOSEK's does not come through Drake: unknown, not 0.
        assert r.gap == (pytest.approx(0.25) if backend == "gurobi" else np.inf)
        assert r.bound <= r.objective
    else:
        assert r.objective == np.inf and r.gap == np.inf
    if status is Status.INFEASIBLE:
        assert r.bound == np.inf


def test_a_solution_that_is_not_finite_is_no_solution() -> None:
    r = drake_result(OPTIONS["mosek"], FakeResult(MosekDetails(2), x=(np.nan, 0.0)), [], 1.0)
    assert r.status is Status.ERROR and r.x is None


@pytest.mark.parametrize(
    ("backend", "cls", "expected"),
    [
        ("gurobi", GurobiSolver, {"TimeLimit": 7.0, "MIPGap": 0.01, "Threads": 2}),
        ("mosek", MosekSolver, {"MSK_DPAR_OPTIMIZER_MAX_TIME": 7.0,
                                "MSK_DPAR_MIO_TOL_REL_GAP": 0.01, "MSK_IPAR_NUM_THREADS": 2}),
    ],
)
def test_drake_backends_get_the_time_limit_gap_and_threads(monkeypatch, backend, cls,
                                                           expected) -> None:
    """MOSEK ran without any of the three before (only Gurobi's were set)."""
    seen = {}

    class Licensed:
        def available(self) -> bool:
            return True

        def enabled(self) -> bool:
            return True

        def solver_id(self):
            return cls.id()

        def Solve(self, prog, start, options):
            seen.update(options.options[cls.id().name()])
            details = GurobiDetails(2, 1.0) if backend == "gurobi" else MosekDetails(1)
            return FakeResult(details, cost=1.0, x=np.zeros(prog.num_vars()))

    monkeypatch.setattr(f"pydrake.solvers.{cls.__name__}", Licensed)
    prog, _ = _linear_program()
    r = solver.solve(prog, SolveOptions(time_limit_s=7, mip_rel_gap=0.01, threads=2,
                                        backend=backend))
    assert r.status is Status.OPTIMAL
    assert seen == expected
