"""The evaluator against a peer LTLf implementation on random formulas and finite traces.

The peer is flloat (the LTLf library of the ltlf2dfa authors; ltlf2dfa itself needs the MONA
binary, Spot is not on the package index), which evaluates a formula on a trace directly from De
Giacomo & Vardi's semantics. It reads ltlf2dfa's syntax: lower-case atoms and
``! & | -> <-> X WX G F U R true false last``. Our W, M and xor it has not: they are given to it by
their textbook definitions (Spot's), ``a W b = (a U b) | G a``, ``a M b = b U (a & b)`` and
``a xor b = !(a <-> b)``, not by the rewriting ``transform.nnf`` uses, so they are checked too.
Every subformula is parenthesized: flloat's precedence is not Spot's (docs/ltl.md). Traces have at
least one step (a horizon is k = 0..T, T ≥ 0); on the empty trace, which never arises here, LTLf
tools differ.
"""

from __future__ import annotations

import itertools
import random

import pytest
from strategies import BINARY, UNARY

from dualarm_mpc.logic.evaluate import truth_table
from dualarm_mpc.logic.ltl import (
    Always,
    And,
    Atom,
    Const,
    Equiv,
    Formula,
    Implies,
    Not,
    Or,
    Release,
    StrongRelease,
    Until,
    WeakUntil,
    Xor,
    eta,
    theta,
)
from dualarm_mpc.logic.parser import LTLSyntaxError, parse

LTLfParser = pytest.importorskip("flloat.parser.ltlf").LTLfParser

ATOMS = [eta(1, 1), eta(2, 1), eta(1, 2), theta(1), theta(2)]
PEER_PARSER = LTLfParser()


def peer_name(atom: Atom) -> str:
    """``eta[1,2]`` as a flloat proposition: ``eta_1_2``."""
    return "_".join([atom.name, *map(str, atom.index)])


def peer_text(f: Formula, name=peer_name) -> str:
    """``f`` in ltlf2dfa's syntax, each subformula in parentheses, atoms written by ``name``; the
    other operators are spelt there as here (docs/ltl.md)."""
    match f:
        case Const(value):
            return "true" if value else "false"
        case Atom():
            return name(f)
        case WeakUntil(a, b):
            return peer_text(Or((Until(a, b), Always(a))), name)
        case StrongRelease(a, b):
            return peer_text(Until(b, And((a, b))), name)
        case Xor(a, b):
            return peer_text(Not(Equiv(a, b)), name)
        case Not(a):
            return f"!({peer_text(a, name)})"
        case And(args) | Or(args):
            return "(" + (" & " if isinstance(f, And) else " | ").join(
                peer_text(a, name) for a in args) + ")"
        case Implies(a, b) | Equiv(a, b) | Until(a, b) | Release(a, b):
            return f"({peer_text(a, name)} {f.keyword} {peer_text(b, name)})"
    return f"{f.keyword}({peer_text(f.arg, name)})"  # X WX G F


def peer_table(peer, trace: dict[Atom, list[bool]], horizon: int) -> list[bool]:
    """The truth of flloat's formula ``peer`` at each step k = 0..horizon of ``trace``."""
    steps = [{peer_name(a): v[k] for a, v in trace.items()} for k in range(horizon + 1)]
    return [bool(peer.truth(steps, k)) for k in range(horizon + 1)]


def random_formula(rnd: random.Random, leaves: int) -> Formula:
    """A formula with ``leaves`` atoms or constants and any operators (``strategies``' own)."""
    if rnd.random() < 0.3:
        return rnd.choice(UNARY)(random_formula(rnd, leaves))
    if leaves == 1:
        return rnd.choice(ATOMS) if rnd.random() < 0.9 else Const(rnd.random() < 0.5)
    split = rnd.randint(1, leaves - 1)
    lhs, rhs = random_formula(rnd, split), random_formula(rnd, leaves - split)
    if rnd.random() < 0.25:
        return rnd.choice((And, Or))((lhs, rhs))
    return rnd.choice(BINARY)(lhs, rhs)


def test_the_evaluator_agrees_with_flloat() -> None:
    """1000 distinct random formulas of 1 to 10 leaves with every operator, each on three random
    traces of 1 to 6 steps, compared at every step; the same formula written in ltlf2dfa's syntax
    over our atoms parses to one with the same truth. Seeded: the same formulas in every run."""
    rnd = random.Random(41)
    seen: set[Formula] = set()
    while len(seen) < 1000:
        f = random_formula(rnd, rnd.randint(1, 10))
        if f in seen:
            continue
        seen.add(f)
        text = peer_text(f)
        peer, ours = PEER_PARSER(text), parse(peer_text(f, str))
        for horizon in rnd.choices(range(6), k=3):
            trace = {a: [rnd.random() < 0.5 for _ in range(horizon + 1)] for a in ATOMS}
            table = truth_table(f, trace, horizon)
            assert table == peer_table(peer, trace, horizon), (text, horizon, trace)
            assert truth_table(ours, trace, horizon) == table, (text, horizon, trace)


@pytest.mark.parametrize(
    "text",
    [
        "G(a -> WX last)",  # last: true only at the last step
        "a U last",
        "!last & X true",
        "F(last & a)",  # a at the last step, = F G a
        "WX(false) <-> last",
        "a R (b | last)",
        "G(a -> X(!a)) & F(b)",
    ],
)
def test_ltlf2dfa_text_means_the_same_here(text: str) -> None:
    """Formulas in ltlf2dfa's own spelling (``last`` included), read by both parsers, on every
    trace over a, b of 1 to 4 steps."""
    a, b = Atom("a"), Atom("b")
    ours, peer = parse(text), PEER_PARSER(text)
    for horizon in range(4):
        for bits in itertools.product((False, True), repeat=2 * (horizon + 1)):
            trace = {a: list(bits[:horizon + 1]), b: list(bits[horizon + 1:])}
            assert truth_table(ours, trace, horizon) == peer_table(peer, trace, horizon), bits


@pytest.mark.parametrize("text", [
    "XXWX!(!WXGGG a)",  # WX touching its argument, as flloat and ltlf2dfa read it
    "(a <-> b) <-> c",  # a chain unparenthesized is refused (below)
    "!a <-> (b <-> c)",
])
def test_peers_spellings_read_by_both_mean_the_same(text: str) -> None:
    """Found in flloat's and ltlf2dfa's test suites (issue 52): read by both parsers, the same
    truth at every step of every trace over a, b, c of 1 to 3 steps."""
    names = [Atom("a"), Atom("b"), Atom("c")]
    ours, peer = parse(text), PEER_PARSER(text)
    for horizon in range(3):
        for bits in itertools.product((False, True), repeat=3 * (horizon + 1)):
            trace = {atom: list(bits[n * (horizon + 1):(n + 1) * (horizon + 1)])
                     for n, atom in enumerate(names)}
            steps = [{a.name: v[k] for a, v in trace.items()} for k in range(horizon + 1)]
            assert truth_table(ours, trace, horizon) == \
                [bool(peer.truth(steps, k)) for k in range(horizon + 1)], (text, bits)


def test_a_chain_of_equivalences_is_refused_where_peers_read_it_otherwise() -> None:
    """flloat reads ``a <-> b <-> c`` as "all three equal", not as either nesting."""
    assert str(PEER_PARSER("a <-> b <-> c").truth([{"a": False, "b": False, "c": False}], 0))
    for text in ("a <-> b <-> c", "a -> (b <-> c <-> a)"):
        with pytest.raises(LTLSyntaxError, match=r"a chain of <->"):
            parse(text)
    assert parse("a <-> b -> c <-> a") == parse("a <-> (b -> (c <-> a))")


def test_a_reversed_range_is_refused_saying_how_spot_reads_it() -> None:
    with pytest.raises(LTLSyntaxError, match=r"^column 4: empty range F\[4:2\] \(Spot reads it "
                       r"as F\[2:4\]: write that if it is meant\)"):
        parse("F[4:2] a")
