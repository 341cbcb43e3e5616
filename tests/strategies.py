"""Hypothesis strategies for LTLf formulas and finite traces (LTL and encoder tests)."""

from __future__ import annotations

from hypothesis import strategies as st

from dualarm_mpc.logic.ltl import (
    Always,
    And,
    Atom,
    Const,
    Equiv,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Release,
    StrongRelease,
    Until,
    WeakNext,
    WeakUntil,
    Xor,
)

UNARY = (Not, Next, WeakNext, Always, Eventually)
BINARY = (Implies, Equiv, Xor, Until, Release, WeakUntil, StrongRelease)


def formulas(atoms: list[Atom], max_leaves: int = 8) -> st.SearchStrategy[Formula]:
    """Random formulas over ``atoms`` using every node type (Const, Not, Implies, WX, ...).

    And/Or get 2 or 3 arguments, which may themselves be And/Or (nesting is kept, not flattened).
    """
    if not atoms:
        raise ValueError("formulas() needs at least one atom")
    leaves = st.one_of(
        st.sampled_from(atoms), st.sampled_from(atoms), st.builds(Const, st.booleans())
    )

    def extend(children: st.SearchStrategy[Formula]) -> st.SearchStrategy[Formula]:
        nary = st.lists(children, min_size=2, max_size=3).map(tuple)
        return st.one_of(
            st.sampled_from(UNARY).flatmap(lambda op: children.map(op)),
            st.sampled_from(BINARY).flatmap(lambda op: st.builds(op, children, children)),
            st.sampled_from((And, Or)).flatmap(lambda op: nary.map(op)),
        )

    return st.recursive(leaves, extend, max_leaves=max_leaves)


def traces(atoms: list[Atom], horizon: int) -> st.SearchStrategy[dict[Atom, list[bool]]]:
    """Random traces: each atom mapped to horizon + 1 booleans (steps k = 0..horizon)."""
    n = horizon + 1
    return st.fixed_dictionaries(
        {a: st.lists(st.booleans(), min_size=n, max_size=n) for a in atoms}
    )
