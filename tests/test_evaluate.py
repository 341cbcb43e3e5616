"""Tests for logic.evaluate: every operator by hand, especially at the trace's last step."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from strategies import formulas, traces

from dualarm_mpc.logic.evaluate import evaluate, truth_table
from dualarm_mpc.logic.ltl import FALSE, TRUE, WX, Atom, Equiv, F, G, M, R, U, W, X, eta, theta
from dualarm_mpc.logic.parser import parse
from dualarm_mpc.logic.transform import atoms

a, b = Atom("a"), Atom("b")
FAST = settings(max_examples=200, deadline=None)


def tt(text: str, **values: str) -> str:
    """Truth table of ``text`` as a 0/1 string, given each atom's values as a 0/1 string."""
    horizon = len(next(iter(values.values()))) - 1
    trace = {Atom(name): [ch == "1" for ch in v] for name, v in values.items()}
    return "".join("1" if v else "0" for v in truth_table(parse(text), trace, horizon))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("true", "1111"),
        ("false", "0000"),
        ("a", "0110"),
        ("!a", "1001"),
        ("a & b", "0100"),
        ("a | b", "1110"),
        ("a -> b", "1101"),
        ("X a", "1100"),  # false at T whatever a is
        ("WX a", "1101"),  # true at T
        ("X true", "1110"),
        ("WX false", "0001"),
        ("G a", "0000"),
        ("G b", "0000"),
        ("F a", "1110"),
        ("F b", "1100"),
        ("G !a", "0001"),  # true at T, false from the last a on
        ("a U b", "1100"),  # no b from step 2 on
        ("b U a", "1110"),
        ("a R b", "1100"),
        ("false R b", "0000"),  # = G b
        ("true U a", "1110"),  # = F a
        ("F G a", "0000"),  # = a at T
        ("F G !a", "1111"),
        ("a <-> b", "0101"),
        ("a xor b", "1010"),
        ("a W b", "1100"),  # a U b, or a to the last step: from step 2 neither
        ("b W a", "1110"),
        ("!a W b", "1101"),  # no b after step 1, but !a from step 3 to the end
        ("a M b", "1100"),  # b up to and including a step with a (step 1), which must come
        ("b M a", "0100"),
        ("true M b", "1100"),  # = b
        ("a M true", "1110"),  # = F a
        ("false W b", "1100"),  # = b
        ("a W false", "0000"),  # = G a
    ],
)
def test_operators(text: str, expected: str) -> None:
    assert tt(text, a="0110", b="1100") == expected


@pytest.mark.parametrize(
    ("text", "a_values", "b_values", "expected"),
    [
        ("a U b", "1110", "0001", "1111"),  # b at T reached through a
        ("a U b", "1100", "0001", "0001"),  # a breaks at 2, before b
        ("a U b", "1111", "0000", "0000"),  # b never: strong until fails even with G a
        ("a R b", "0000", "1111", "1111"),  # G b suffices: release needs no a
        ("a R b", "0100", "1100", "1100"),  # a releases b at step 1 (b must hold there too)
        ("a R b", "0100", "1000", "0000"),  # b must also hold where a releases it
        ("a R b", "0001", "0001", "0001"),
        ("X X a", "0001", "0000", "0100"),
        ("WX WX a", "0000", "0000", "0011"),
        ("F G a", "0101", "0000", "1111"),  # F G a = a at T
        ("G F a", "0101", "0000", "1111"),  # also = a at T in LTLf
    ],
)
def test_edge_cases(text: str, a_values: str, b_values: str, expected: str) -> None:
    assert tt(text, a=a_values, b=b_values) == expected


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("X a", "0"),
        ("WX a", "1"),
        ("G a", "1"),
        ("F a", "1"),
        ("a U b", "0"),
        ("a R b", "0"),
        ("a U a", "1"),
        ("b R a", "1"),
        ("b W a", "1"),
        ("a W b", "1"),  # a to the last step (the only one)
        ("b M a", "0"),
        ("a M a", "1"),
    ],
)
def test_single_step_trace(text: str, expected: str) -> None:
    assert tt(text, a="1", b="0") == expected


@FAST
@given(formulas([a], max_leaves=4), traces([a], 5))
def test_fg_is_last_step(f, trace) -> None:
    horizon = 5
    last = truth_table(f, trace, horizon)[horizon]
    assert evaluate(F(G(f)), trace, horizon) == last
    assert evaluate(G(F(f)), trace, horizon) == last


@FAST
@given(formulas([a, b], max_leaves=6), traces([a, b], 4))
def test_dualities_and_expansions(f, trace) -> None:
    """Identities the evaluator computes independently (it never rewrites)."""
    horizon, g = 4, b
    table = truth_table
    assert table(~X(f), trace, horizon) == table(WX(~f), trace, horizon)
    assert table(~U(f, g), trace, horizon) == table(R(~f, ~g), trace, horizon)
    assert table(U(TRUE, f), trace, horizon) == table(F(f), trace, horizon)
    assert table(R(FALSE, f), trace, horizon) == table(G(f), trace, horizon)
    assert table(U(f, g), trace, horizon) == table(g | (f & X(U(f, g))), trace, horizon)
    assert table(R(f, g), trace, horizon) == table(g & (f | WX(R(f, g))), trace, horizon)
    assert table(W(f, g), trace, horizon) == table(U(f, g) | G(f), trace, horizon)
    assert table(M(f, g), trace, horizon) == table(U(g, f & g), trace, horizon)
    assert table(~W(f, g), trace, horizon) == table(M(~f, ~g), trace, horizon)
    assert table(W(f, g), trace, horizon) == table(g | (f & WX(W(f, g))), trace, horizon)
    assert table(M(f, g), trace, horizon) == table(g & (f | X(M(f, g))), trace, horizon)
    assert table(f ^ g, trace, horizon) == table(~Equiv(f, g), trace, horizon)
    assert table(Equiv(f, g), trace, horizon) == table((f >> g) & (g >> f), trace, horizon)


def test_evaluate_at_k_and_callable_trace() -> None:
    trace = {a: [False, True, False]}
    assert [evaluate(a, trace, 2, k) for k in range(3)] == [False, True, False]
    assert evaluate(X(a), lambda atom, k: k == 1, 2) is True
    with pytest.raises(ValueError, match="outside"):
        evaluate(a, trace, 2, 3)


def test_missing_atom_is_a_key_error_naming_it() -> None:
    with pytest.raises(KeyError, match=r"eta\[1,3\]"):
        evaluate(a & eta(1, 3), {a: [True]}, 0)


def test_placeholder_atom_is_rejected() -> None:
    with pytest.raises(ValueError, match=r"theta\[j\]"):
        evaluate(theta("j"), lambda atom, k: True, 3)


def test_short_trace_and_bad_horizon_are_rejected() -> None:
    with pytest.raises(ValueError, match="need 4"):
        evaluate(a, {a: [True, True]}, 3)
    with pytest.raises(ValueError, match="horizon"):
        evaluate(a, {a: [True]}, -1)


def test_each_subformula_is_evaluated_once() -> None:
    """Memoized on the node: a deep formula over a long horizon reads each atom's value once per
    step, however often the atom occurs (its cost is linear in the formula's size)."""
    horizon = 40
    n = 3
    trace = {
        eta(i, j): [(k + i + j) % 4 == 0 for k in range(horizon + 1)]
        for i in (1, 2)
        for j in range(1, n + 1)
    }
    trace |= {theta(j): [k > 30 + j for k in range(horizon + 1)] for j in range(1, n + 1)}
    rules = [G(eta(i, j) & WX(~eta(i, j)) >> WX(theta(j))) for i in (1, 2) for j in range(1, n + 1)]
    f = G(F(U(rules[0], F(G(theta(1)))))) & F(theta(1) & F(theta(2) & F(theta(3))))
    for rule in rules:
        f = f & G(rule | X(U(rule, theta(2))))
    reads = []

    def read(atom, k):
        reads.append((atom, k))
        return trace[atom][k]

    assert truth_table(f, read, horizon) == truth_table(f, trace, horizon)
    assert len(reads) == len(set(reads)) == len(atoms(f)) * (horizon + 1)
