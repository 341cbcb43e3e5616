"""Tests for milp.solver at its boundary: what it refuses. The MILP solves themselves are
tested in test_program.py (HiGHS) and test_backends.py (every installed backend)."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.solvers import MathematicalProgram

from dualarm_mpc.milp.backends import solve
from dualarm_mpc.milp.solver import Status, standard_form


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
def test_the_standard_form_refuses_what_no_backend_takes(add, kind) -> None:
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
