"""Tests for milp.encoding: the LTL encoder against the direct evaluator (property-based).

Each example builds a tiny MILP whose atoms are fixed (decision atoms) or linked one-sidedly to
fixed "positions" (geometric atoms), encodes a random formula, solves it with HiGHS and compares
feasibility with :func:`dualarm_mpc.logic.evaluate.evaluate`, which shares no code with the encoder.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydrake.solvers import MathematicalProgram
from strategies import formulas, traces

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.logic.ltl import Atom, F, G
from dualarm_mpc.logic.parser import parse
from dualarm_mpc.logic.transform import atoms, nnf
from dualarm_mpc.milp.backends import solve
from dualarm_mpc.milp.encoding import Encoder, EncodingError, Literal
from dualarm_mpc.milp.horizon import build_program, solve_step
from dualarm_mpc.milp.linear import Rows, bound, new_variables
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import Scenario, apply_overrides
from dualarm_mpc.model.spec import StepProblem, negated_atoms, specification
from dualarm_mpc.planning import sequential

P, Q, R = Atom("p"), Atom("q"), Atom("r")
ATOMS = [P, Q, R]
PROPERTY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
OPTIONS = SolveOptions(time_limit_s=10.0)


def horizon_and_trace(atom_list: list[Atom] = ATOMS):
    """(T, trace) with T in 1..5 and a trace over steps 0..T."""
    return st.integers(1, 5).flatmap(lambda T: st.tuples(st.just(T), traces(atom_list, T)))


def _feasible(prog: MathematicalProgram) -> bool:
    result = solve(prog, OPTIONS)
    assert result.status in (Status.OPTIMAL, Status.INFEASIBLE), result
    return result.status is Status.OPTIMAL


def decision_program(trace: dict[Atom, list[bool]], T: int):
    """A program with one binary per atom and step, fixed to ``trace``; exact literals."""
    prog = MathematicalProgram()
    index = new_variables(prog, (len(ATOMS), T + 1), "atom", binary=True)
    values = np.array([[float(v) for v in trace[a]] for a in ATOMS])
    bound(prog, index, values, values)
    row = {a: n for n, a in enumerate(ATOMS)}

    def resolve(atom: Atom, k: int) -> Literal:
        return Literal(int(index[row[atom], k]))

    return prog, index, resolve


def geometric_program(trace: dict[Atom, list[bool]], T: int, geometric: frozenset[Atom]):
    """Atoms in ``geometric`` get a FREE binary θ with θ(k) ≤ x(k), x a continuous "position"
    fixed to the trace; the others are decision atoms fixed to the trace."""
    prog = MathematicalProgram()
    index = new_variables(prog, (len(ATOMS), T + 1), "atom", binary=True)
    pos = new_variables(prog, (len(ATOMS), T + 1), "x")
    values = np.array([[float(v) for v in trace[a]] for a in ATOMS])
    bound(prog, pos, values, values)
    row = {a: n for n, a in enumerate(ATOMS)}
    rows = Rows()
    for a in ATOMS:
        n = row[a]
        if a in geometric:
            rows.add([(1, index[n]), (-1, pos[n])], ub=0)  # θ = 1 → x = 1, one-sided
        else:
            bound(prog, index[n], values[n], values[n])
    rows.emit(prog, "one-sided links")

    def resolve(atom: Atom, k: int) -> Literal:
        return Literal(int(index[row[atom], k]), geometric=atom in geometric)

    return prog, resolve


# --- decision atoms: exact ------------------------------------------------------------------------


@PROPERTY
@given(formulas(ATOMS, max_leaves=8), horizon_and_trace(), st.data())
def test_decision_atoms_feasible_iff_formula_holds(f, horizon_trace, data) -> None:
    T, trace = horizon_trace
    k = data.draw(st.integers(0, T), label="k")
    prog, _, resolve = decision_program(trace, T)
    enc = Encoder(prog, T, resolve)
    enc.require(f, k)
    enc.emit()
    assert _feasible(prog) == evaluate(f, trace, T, k), f"{f} at k={k}"


@PROPERTY
@given(formulas(ATOMS, max_leaves=8), horizon_and_trace(), st.data())
def test_truth_value_is_at_most_the_truth(f, horizon_trace, data) -> None:
    """``Encoder.truth`` (the ∧/∨ truth variables, not the shortcuts of ``require``): with all
    atoms fixed, the largest value the affine truth can take is exactly the formula's truth."""
    T, trace = horizon_trace
    k = data.draw(st.integers(0, T), label="k")
    prog, _, resolve = decision_program(trace, T)
    enc = Encoder(prog, T, resolve)
    const, coef, index = enc.truth(f, k)
    enc.emit()
    if index < 0:
        best = const
    else:
        prog.AddLinearCost(np.array([-coef]), 0.0, prog.decision_variables()[[index]])
        result = solve(prog, OPTIONS)
        assert result.status is Status.OPTIMAL, result
        best = const - result.objective
    assert best == pytest.approx(float(evaluate(f, trace, T, k)), abs=1e-6), f"{f} at k={k}"


@pytest.mark.parametrize(
    ("text", "p", "q", "k", "expected"),
    [
        ("X p", "0001", "0000", 2, True),
        ("X p", "0001", "0000", 3, False),  # strong next: false at T
        ("WX false", "0000", "0000", 3, True),  # weak next: true at T
        ("WX false", "0000", "0000", 2, False),
        ("G p", "0011", "0000", 2, True),
        ("F !p", "0011", "0000", 2, False),
        ("p U q", "1100", "0010", 0, True),
        ("p U q", "1000", "0010", 0, False),
        ("p R q", "0000", "1111", 1, True),
        ("q R p", "0000", "0111", 0, False),
        ("X X p", "0001", "0000", 2, False),  # runs off the horizon without visiting p
    ],
)
def test_operators_at_the_horizon_end(text, p, q, k, expected) -> None:
    trace = {P: [c == "1" for c in p], Q: [c == "1" for c in q], R: [False] * len(p)}
    T = len(p) - 1
    assert evaluate(parse(text), trace, T, k) is expected  # the oracle agrees with the table
    prog, _, resolve = decision_program(trace, T)
    enc = Encoder(prog, T, resolve)
    enc.require(parse(text), k)
    enc.emit()
    assert _feasible(prog) is expected


def test_identical_subformulas_share_truth_variables() -> None:
    T = 4
    trace = {a: [True] * (T + 1) for a in ATOMS}
    f = parse("F(p & q) | G(F(p & q) | r)")
    prog, _, resolve = decision_program(trace, T)
    before = prog.num_vars()
    enc = Encoder(prog, T, resolve)
    enc.truth(f)
    once = prog.num_vars() - before
    enc.truth(f)  # the same formula again: memoized, no new variables
    assert prog.num_vars() - before == once


# --- geometric atoms: one-sided -------------------------------------------------------------------


@PROPERTY
@given(formulas(ATOMS, max_leaves=8), horizon_and_trace(), st.data())
def test_geometric_atoms_sound_and_complete_in_positive_position(f, horizon_trace, data) -> None:
    """q and r geometric (θ ≤ x, θ free), p a decision atom. Without a negated geometric atom
    after NNF: feasible with the root true ⟺ the formula holds on the positions' trace."""
    T, trace = horizon_trace
    k = data.draw(st.integers(0, T), label="k")
    geometric = frozenset({Q, R})
    bad = negated_atoms(nnf(f)) & geometric
    prog, resolve = geometric_program(trace, T, geometric)
    enc = Encoder(prog, T, resolve)
    if bad:
        # The encoder must refuse (or never reach the atom); it must never encode 1 − θ.
        try:
            enc.require(f, k)
        except EncodingError as err:
            named = re.match(r"(\w+)\b", str(err))
            assert named and Atom(named.group(1)) in bad, str(err)
            return
    else:
        enc.require(f, k)
    enc.emit()
    assert _feasible(prog) == evaluate(f, trace, T, k), f"{f} at k={k}"


def test_negated_geometric_atom_would_be_unsound_and_is_rejected() -> None:
    """x_q = 1 everywhere, so ``G !q`` is false; 1 − θ over a free θ ≤ x would make it
    feasible (θ = 0). The encoder must refuse, naming the atom."""
    T = 3
    trace = {a: [True] * (T + 1) for a in ATOMS}
    prog, resolve = geometric_program(trace, T, frozenset({Q}))
    enc = Encoder(prog, T, resolve)
    with pytest.raises(EncodingError, match=r"^q\b.*negat"):
        enc.require(G(~Q))
    enc = Encoder(prog, T, resolve)
    with pytest.raises(EncodingError, match=r"^q\b"):
        enc.require(parse("p -> F q") & parse("q -> X p"))  # q -> ... puts q under a negation


def test_double_negation_of_geometric_atom_is_positive() -> None:
    T = 2
    trace = {P: [False] * 3, Q: [False, False, True], R: [False] * 3}
    prog, resolve = geometric_program(trace, T, frozenset({Q}))
    enc = Encoder(prog, T, resolve)
    enc.require(~G(~Q))  # = F q
    enc.emit()
    assert _feasible(prog)


# --- the planner's resolver: rules with bad atoms -------------------------------------------------


def _one_object_scenario(**overrides) -> Scenario:
    data = {
        "name": "one",
        "goals": {"red": [0.15, 0.35, 0.3, 0.5]},
        "objects": [{"name": "object1", "position": [0.1, 0.1], "goal": "red"}],
        "m_o": 1,
        "n_o": 1,
        "rule": 1,
        "solver": {"max_horizon": 8},
    }
    data.update(overrides)
    return apply_overrides(Scenario(), data)


def _build(scenario: Scenario, horizon: int = 4, rules: list[str] | None = None):
    """The program of ``scenario``'s one-object step; ``rules`` go straight to the encoder,
    past the check that refuses them on loading (spec.check_rule)."""
    state = State.initial(scenario)
    named = None if rules is None else [(text, parse(text)) for text in rules]
    spec = specification(scenario, [0], rules=named)
    return build_program(StepProblem(scenario, state, spec), horizon)


def test_negated_goal_atom_in_a_rule_is_rejected_naming_it() -> None:
    with pytest.raises(EncodingError, match=r"theta\[1\].*negat"):
        _build(_one_object_scenario(), rules=["G !theta[1]"])


@pytest.mark.parametrize(
    ("rule", "name"),
    [
        ("F foo", "foo"),
        ("G(eta[3,1] -> F theta[1])", r"eta\[3,1\]"),
        ("F theta[7]", r"theta\[7\]"),
        ("F eta[1]", r"eta\[1\]"),
    ],
)
def test_unknown_atom_in_a_rule_is_named(rule: str, name: str) -> None:
    with pytest.raises(EncodingError, match=rf"unknown atom {name}"):
        _build(_one_object_scenario(), rules=[rule])


def test_rule_on_an_object_outside_the_step_uses_its_constant_value() -> None:
    """Two objects, a step over object 1 only: eta[1,2] is a constant false and theta[2] the
    object's (fixed) goal membership — object 2 already sits in its goal here."""
    scenario = apply_overrides(
        Scenario(),
        {
            "goals": {"red": [0.15, 0.35, 0.3, 0.5], "blue": [-0.35, -0.15, 0.3, 0.5]},
            "objects": [
                {"name": "object1", "position": [0.1, 0.1], "goal": "red"},
                {"name": "object2", "position": [-0.25, 0.4], "goal": "blue"},
            ],
            "m_o": 1,
            "n_o": 1,
            "rule": 1,
        },
    )
    state = State.initial(scenario)
    for rules, feasible in (
        (["G theta[2]"], True),
        (["F eta[1,2]"], False),
        (["G !eta[2,2]"], True),
    ):
        s = apply_overrides(scenario, {"rules": rules})
        spec = specification(s, [0])
        res = solve_step(StepProblem(s, state, spec), 6)
        assert res.status.has_solution is feasible, rules


# --- the counting form of φ_task ------------------------------------------------------------------


@PROPERTY
@given(
    st.lists(formulas(ATOMS, max_leaves=5), min_size=1, max_size=4), horizon_and_trace(), st.data()
)
def test_require_at_least_counts(fs, horizon_trace, data) -> None:
    T, trace = horizon_trace
    m = data.draw(st.integers(0, len(fs) + 1), label="m")
    k = data.draw(st.integers(0, T), label="k")
    prog, _, resolve = decision_program(trace, T)
    enc = Encoder(prog, T, resolve)
    enc.require_at_least(m, fs, k)
    enc.emit()
    holding = sum(evaluate(f, trace, T, k) for f in fs)
    assert _feasible(prog) == (holding >= m), f"{m} of {[str(f) for f in fs]}: {holding} hold"


@PROPERTY
@given(horizon_and_trace(), st.integers(0, 4))
def test_counting_form_with_geometric_events(horizon_trace, m) -> None:
    """The planner's use: Σ_j z(F θ_j) ≥ m over one-sided geometric atoms."""
    T, trace = horizon_trace
    prog, resolve = geometric_program(trace, T, frozenset(ATOMS))
    enc = Encoder(prog, T, resolve)
    events = [F(a) for a in ATOMS]
    enc.require_at_least(m, events)
    enc.emit()
    assert _feasible(prog) == (sum(any(trace[a]) for a in ATOMS) >= m)


# --- the two task forms give the same optimum ---------------------------------------------------


@pytest.mark.parametrize("delivery", ["reach", "rest"])
def test_task_forms_give_the_same_optimal_cost(delivery: str) -> None:
    scenario = apply_overrides(
        Scenario(),
        {
            "goals": {"red": [0.2, 0.4, 0.3, 0.5], "blue": [-0.4, -0.2, 0.3, 0.5]},
            "objects": [
                {"name": "object1", "position": [0.1, 0.1], "goal": "red"},
                {"name": "object2", "position": [-0.1, 0.1], "goal": "blue"},
                {"name": "object3", "position": [0.0, 0.2], "goal": "red"},
            ],
            "m_o": 2,
            "n_o": 3,
            "rule": 2,
            "delivery": delivery,
        },
    )
    state = State.initial(scenario)
    results = {}
    for form in ("counting", "subsets"):
        s = apply_overrides(scenario, {"task_form": form})
        spec = specification(s, [0, 1, 2])
        results[form], _ = sequential.plan_step(StepProblem(s, state, spec))
    counting, subsets = results["counting"], results["subsets"]
    assert counting.status is subsets.status is Status.OPTIMAL
    assert counting.horizon == subsets.horizon
    assert counting.cost == pytest.approx(subsets.cost, abs=1e-6)
    # The subsets form really is eq. (13) literally: a disjunction of the 3 pairs.
    spec = specification(apply_overrides(scenario, {"task_form": "subsets"}), [0, 1, 2])
    assert len(spec.task().args) == 3
    assert atoms(spec.task()) == {Atom("theta", (j,)) for j in (1, 2, 3)}
