"""Tests for dualarm_mpc.logic.ltl: construction, parser, printer round trip, NNF, placeholders."""

from __future__ import annotations

import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies import formulas, traces

from dualarm_mpc.logic.evaluate import truth_table
from dualarm_mpc.logic.ltl import (
    FALSE,
    TRUE,
    WX,
    Always,
    And,
    Atom,
    Const,
    Equiv,
    Eventually,
    F,
    Formula,
    G,
    Implies,
    M,
    Next,
    Not,
    Or,
    R,
    Release,
    StrongRelease,
    U,
    Until,
    W,
    WeakNext,
    WeakUntil,
    X,
    Xor,
    conj,
    disj,
    eta,
    theta,
)
from dualarm_mpc.logic.parser import MAX_DEPTH, LTLSyntaxError, parse
from dualarm_mpc.logic.transform import atoms, nnf, partial, placeholders, substitute

a, b, c = Atom("a"), Atom("b"), Atom("c")
GROUND = [a, b, eta(1, 3), theta(2)]
ALL_ATOMS = [*GROUND, Atom("Xa"), Atom("WX_1"), eta("i", "j"), theta("j"), Atom("p_1", (2, "l"))]
FAST = settings(max_examples=200, deadline=None)


# --- construction ---------------------------------------------------------------------------------


def test_python_api_builds_the_same_nodes_as_text() -> None:
    rule = G((eta(1, 3) & WX(~eta(1, 3))) >> WX(theta(3)))
    assert rule == parse("G(eta[1,3] & WX !eta[1,3] -> WX theta[3])")
    assert a | b == Or((a, b))
    assert ~a == Not(a)
    assert (X(a), F(a), U(a, b), R(a, b)) == (Next(a), Eventually(a), Until(a, b), Release(a, b))
    assert (W(a, b), M(a, b), a ^ b) == (WeakUntil(a, b), StrongRelease(a, b), Xor(a, b))
    assert (TRUE, FALSE) == (Const(True), Const(False))


def test_nodes_are_hashable_and_structural() -> None:
    assert len({eta(1, 3), Atom("eta", (1, 3)), parse("eta[1,3]")}) == 1
    assert Next(a) != WeakNext(a)
    assert hash(G(a & b)) == hash(parse("G(a & b)"))


def test_conj_disj() -> None:
    assert (conj([]), disj([])) == (TRUE, FALSE)
    assert conj([a]) == a == disj([a])
    assert conj(x for x in (a, b, c)) == And((a, b, c))
    assert disj([a, b]) == Or((a, b))


@pytest.mark.parametrize(
    "build",
    [
        lambda: And((a,)),
        lambda: Or(()),
        lambda: Atom("G"),
        lambda: Atom("xor"),
        lambda: Atom("True"),
        lambda: Atom("last"),
        lambda: Atom("1a"),
        lambda: Atom("eta", (True,)),
        lambda: Atom("eta", (-1,)),
        lambda: Atom("eta", ("i j",)),
    ],
)
def test_constructors_reject_bad_input(build) -> None:
    with pytest.raises(ValueError):
        build()


def test_constructors_reject_non_formulas() -> None:
    with pytest.raises(TypeError):
        G("a")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        Const(1)  # type: ignore[arg-type]


# --- parser ---------------------------------------------------------------------------------------


def test_paper_rules() -> None:
    e12, e22 = eta(1, 2), eta(2, 2)
    assert parse("G((eta[1,2] -> WX !eta[2,2]) & (eta[2,2] -> WX !eta[1,2]))") == G(
        Implies(e12, WX(~e22)) & Implies(e22, WX(~e12))
    )
    assert parse("F theta[1] & F theta[2] | F theta[3]") == Or(
        (And((F(theta(1)), F(theta(2)))), F(theta(3)))
    )


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("a & b & c", And((a, b, c))),
        ("a | b | c", Or((a, b, c))),
        ("(a & b) & c", And((And((a, b)), c))),
        ("a | b & c", Or((a, And((b, c))))),
        ("a & b -> c | a", Implies(And((a, b)), Or((c, a)))),
        ("a -> b -> c", Implies(a, Implies(b, c))),
        ("a U b R c", Until(a, Release(b, c))),
        ("a U b & c", And((Until(a, b), c))),
        ("!a U b", Until(Not(a), b)),
        ("G a U b", Until(G(a), b)),
        ("G F !a", G(F(Not(a)))),
        ("~X a", Not(X(a))),
        ("N a", WX(a)),
        ("X true | false", Or((X(TRUE), FALSE))),
        ("Xa & WXb", And((X(a), WX(b)))),  # Spot's X, flloat's WX, touching their argument
        ('"Xa" & X1', And((Atom("Xa"), Atom("X1")))),  # a quoted atom; X and a digit is an atom
        ("GFa", G(F(a))),
        ("XXeta[1,3]", X(X(eta(1, 3)))),
        ("G!a", G(Not(a))),
        ("a -> b <-> c", Implies(a, Equiv(b, c))),  # one level, right-associative (Spot)
        ("a <-> b -> c", Equiv(a, Implies(b, c))),
        ("a | b xor c & a", Or((a, Xor(b, And((c, a)))))),  # | looser than xor looser than &
        ("a xor b xor c", Xor(Xor(a, b), c)),  # left-associative
        ("a U b W c M a", Until(a, WeakUntil(b, StrongRelease(c, a)))),
        ("a W b & c", And((WeakUntil(a, b), c))),
        ("a R b U c", Release(a, Until(b, c))),  # Spot's; ltlf2dfa reads (a R b) U c
        ("G a W b", WeakUntil(G(a), b)),
        ("  theta[ j ] ", theta("j")),
        ("eta[i,3]", eta("i", 3)),
        ("p_1[2, l]", Atom("p_1", (2, "l"))),
        ("((a))", a),
    ],
)
def test_precedence_and_associativity(text: str, expected: Formula) -> None:
    assert parse(text) == expected


@pytest.mark.parametrize(
    ("f", "text"),
    [
        (
            G(eta(1, 3) & WX(~eta(1, 3)) >> WX(theta(3))),
            "G(eta[1,3] & (WX !eta[1,3] -> WX theta[3]))",
        ),
        (
            G((eta(1, 3) & WX(~eta(1, 3))) >> WX(theta(3))),
            "G(eta[1,3] & WX !eta[1,3] -> WX theta[3])",
        ),
        (And((And((a, b)), c)), "(a & b) & c"),
        (Implies(Implies(a, b), c), "(a -> b) -> c"),
        (Until(Until(a, b), c), "(a U b) U c"),
        (Not(Not(a)), "!!a"),
        (Not(G(a | b)), "!G(a | b)"),
        (X(TRUE), "X true"),
        (Xor(a, Xor(b, c)), "a xor (b xor c)"),
        (Xor(Or((a, b)), c), "(a | b) xor c"),
        (And((Xor(a, b), c)), "(a xor b) & c"),
        (Implies(Equiv(a, b), c), "(a <-> b) -> c"),
        (WeakUntil(StrongRelease(a, b), c), "(a M b) W c"),
        (G(Atom("Xa")), 'G "Xa"'),
    ],
)
def test_printer_minimal_parentheses(f: Formula, text: str) -> None:
    assert str(f) == text


@FAST
@given(formulas(ALL_ATOMS, max_leaves=12))
def test_print_parse_round_trip(f: Formula) -> None:
    assert parse(str(f)) == f


# Spot's and ltlf2dfa's other spellings of the tokens our printer writes (docs/ltl.md).
SPELLINGS = {
    "->": ["=>", "-->"], "<->": ["<=>", "<-->"], "&": ["&&", "/\\"], "|": ["||", "\\/"],
    "xor": ["^"], "!": ["~"], "G": ["[]", "G[0:$]"], "F": ["<>", "F[0:$]"],
    "X": ["X[!]", "X[1]", "X[1!]"], "WX": ["N"], "R": ["V"], "true": ["1", "TRUE", "True"],
    "false": ["0", "FALSE"],
}
_PRINTED_TOKEN = re.compile(r'"[^"]*"|\w+(?:\[[^\]]*\])?|<->|->|[()!&|]')


@FAST
@given(formulas(ALL_ATOMS, max_leaves=12), st.randoms(use_true_random=False))
def test_spot_and_ltlf2dfa_spellings_parse_to_the_same_formula(f: Formula, rnd) -> None:
    """Each token of the printed formula in a random one of its spellings, a unary F, G or X
    touching a following name now and then as Spot prints it (``GFa``)."""
    tokens = [rnd.choice([t, *SPELLINGS.get(t, [])]) for t in _PRINTED_TOKEN.findall(str(f))]
    text = ""
    for token, after in zip(tokens, [*tokens[1:], ""], strict=True):
        touch = token in ("G", "F", "X") and after[:1].isalpha() and rnd.random() < 0.5
        text += token + ("" if touch else " ")
    assert parse(text) == f, text


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("X[3] a", X(X(X(a)))),
        ("X[0] a", a),
        ("F[1:3] a", X(a | X(a | X(a)))),  # a at one of the steps k+1..k+3, which must exist
        ("F[2..2] a", X(X(a))),
        ("F[1:$] a", X(F(a))),
        ("F[1:] a", X(F(a))),
        ("G[0:2] a", a & WX(a & WX(a))),  # a at every step k..k+2 that exists
        ("G[0:2!] a", a & X(a & X(a))),  # ... and they exist
        ("G[1,inf] a", WX(G(a))),
        ("X[] a", X(G(a))),  # Spot's X[]a is X G a
        ("last", WX(FALSE)),  # ltlf2dfa's and flloat's: k is the last step
        ('"eta[ 1 , j ]"', eta(1, "j")),
    ],
)
def test_spot_bounded_operators_and_other_sugar(text: str, expected: Formula) -> None:
    assert parse(text) == expected


@pytest.mark.parametrize(
    ("text", "position", "fragment"),
    [
        ("", 0, "expected a formula but found end of input"),
        ("   ", 3, "expected a formula but found end of input"),
        ("a # b", 2, "unexpected character '#'"),
        ("a $ b", 2, "expected a binary operator or end of input but found '$'"),
        ("a - b", 2, "unexpected character '-'"),
        ("G(a & F(b | c", 13, "expected ')' but found end of input"),
        ("a & b)", 5, "unbalanced ')'"),
        ("a &", 3, "expected a formula but found end of input"),
        ("a & | b", 4, "expected a formula but found '|'"),
        ("G U a", 2, "expected a formula but found 'U'"),
        ("a b", 2, "found 'b'"),
        ("eta[1,]", 6, "expected an index (integer or identifier) but found ']'"),
        ("eta[]", 4, "expected an index"),
        ("eta[1 2]", 6, "expected ']' but found '2'"),
        ('G "eta[1,3] & a', 2, "unclosed '\"'"),
        ('"G" U a', 0, "expected an atom name[index, ...] in quotes (invalid atom name 'G')"),
        ('"eta[1," U a', 0, "expected an atom name[index, ...] in quotes"),
        ('"eta[\u0661]"', 0, "expected an atom name[index, ...] in quotes"),  # an Arabic 1
        ("a xor", 5, "expected a formula but found end of input"),
        ("a W M b", 4, "expected a formula but found 'M'"),
        ("X[2 a", 4, "expected ']' but found 'a'"),
        ("X[a] b", 2, "expected a bound (an integer) but found 'a'"),
        ("F[2] a", 3, "expected ':' between the bounds of F[n:m] but found ']'"),
        ("G[3:1] a", 4, "empty range G[3:1]"),
        ("F[0:51] a", 4, "bound above 50"),
    ],
)
def test_syntax_errors_name_the_position(text: str, position: int, fragment: str) -> None:
    with pytest.raises(LTLSyntaxError) as info:
        parse(text)
    err = info.value
    assert isinstance(err, ValueError)
    assert (err.position, err.text) == (position, text)
    message = str(err)
    assert f"column {position}: " in message and fragment in message
    assert message.splitlines()[-1] == "  " + " " * position + "^"


@pytest.mark.parametrize(
    "text",
    ["(" * 300 + "a" + ")" * 300, "!" * 3000 + "a", "G " * 500 + "a", " U ".join("a" * 500),
     " -> ".join("a" * 500), "X(" * 400 + "a" + ")" * 400, " xor ".join("a" * 500),
     " W ".join("a" * 500), "F[0:30] G[0:30] a"],
)
def test_deep_nesting_is_a_syntax_error_not_a_recursion_error(text: str) -> None:
    with pytest.raises(LTLSyntaxError, match=f"nested deeper than {MAX_DEPTH} levels"):
        parse(text)


def test_nesting_up_to_the_limit_parses_and_round_trips() -> None:
    f = parse("(" * MAX_DEPTH + "a" + ")" * MAX_DEPTH)
    assert f == Atom("a")
    g = parse("!" * MAX_DEPTH + "a")
    assert parse(str(g)) == g


def test_an_error_in_a_long_formula_shows_a_window_around_it() -> None:
    """Not the whole text: a window of it with the caret under the offending token."""
    text = " & ".join(f"G eta[1,{j}]" for j in range(200)) + " & # & " + "F theta[1] & " * 100
    position = text.index("#")
    with pytest.raises(LTLSyntaxError) as info:
        parse(text)
    *_, shown, caret = str(info.value).splitlines()
    assert info.value.position == position
    assert len(shown) < 100 and shown.strip().startswith("...") and shown.endswith("...")
    assert shown[caret.index("^")] == "#"


# --- NNF ------------------------------------------------------------------------------------------


def _nnf_shape_ok(f: Formula) -> bool:
    match f:
        case Not(arg):
            return isinstance(arg, Atom)
        case Implies():
            return False
        case And(args) | Or(args):
            return all(_nnf_shape_ok(x) for x in args)
        case Equiv() | Xor() | WeakUntil() | StrongRelease():
            return False
        case Next(x) | WeakNext(x) | Always(x) | Eventually(x):
            return _nnf_shape_ok(x)
        case Until(x, y) | Release(x, y):
            return _nnf_shape_ok(x) and _nnf_shape_ok(y)
    return True


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("!!a", "a"),
        ("!true", "false"),
        ("a -> b", "!a | b"),
        ("!(a & b)", "!a | !b"),
        ("!(a | b | c)", "!a & !b & !c"),
        ("!X a", "WX !a"),
        ("!WX a", "X !a"),
        ("!G a", "F !a"),
        ("!F a", "G !a"),
        ("!(a U b)", "!a R !b"),
        ("!(a R b)", "!a U !b"),
        ("!(a -> b)", "a & !b"),
        ("G(a -> X !b)", "G(!a | X !b)"),
        ("a <-> b", "a & b | !a & !b"),
        ("!(a <-> b)", "a & !b | !a & b"),
        ("a xor b", "a & !b | !a & b"),
        ("!(a xor b)", "a & b | !a & !b"),
        ("a W b", "a U b | G a"),
        ("!(a W b)", "(!a R !b) & F !a"),
        ("a M b", "(a R b) & F a"),
        ("!(a M b)", "!a U !b | G !a"),
    ],
)
def test_nnf_rules(text: str, expected: str) -> None:
    assert nnf(parse(text)) == parse(expected)


@FAST
@given(
    formulas(GROUND, max_leaves=10),
    st.integers(0, 5).flatmap(lambda T: st.tuples(st.just(T), traces(GROUND, T))),
)
def test_nnf_preserves_meaning_and_has_nnf_shape(f: Formula, horizon_trace) -> None:
    horizon, trace = horizon_trace
    g = nnf(f)
    assert _nnf_shape_ok(g)
    assert truth_table(g, trace, horizon) == truth_table(f, trace, horizon)


# --- atoms and placeholders -----------------------------------------------------------------------


def test_atoms_placeholders_substitute() -> None:
    f = parse("G(eta[i,j] -> WX theta[j]) & F p & eta[1,l]")
    assert atoms(f) == {eta("i", "j"), theta("j"), Atom("p"), eta(1, "l")}
    assert placeholders(f) == {"i", "j", "l"}
    g = substitute(f, {"i": 2, "j": 3})
    assert g == parse("G(eta[2,3] -> WX theta[3]) & F p & eta[1,l]")
    assert placeholders(g) == {"l"}
    assert placeholders(substitute(g, {"l": 1})) == frozenset()


@FAST
@given(formulas(GROUND, max_leaves=10), st.integers(0, 4).flatmap(
    lambda T: st.tuples(st.just(T), traces(GROUND, T))), st.booleans(), st.booleans())
def test_partial_evaluation_keeps_the_meaning(f: Formula, horizon_trace, va, vb) -> None:
    horizon, trace = horizon_trace
    known = {a: va, b: vb}
    trace = {**trace, a: [va] * (horizon + 1), b: [vb] * (horizon + 1)}
    assert truth_table(partial(f, known), trace, horizon) == truth_table(f, trace, horizon)


@pytest.mark.parametrize(
    ("text", "known", "expected"),
    [
        ("G(eta[1,2] & WX !eta[1,2] -> WX theta[2])", {"eta[1,2]": False}, TRUE),
        ("G(eta[1,3] -> WX !eta[1,2])", {"eta[1,2]": False}, TRUE),
        ("F eta[1,2]", {"eta[1,2]": False}, FALSE),
        ("X true", {}, parse("X true")),  # strong next is false at the last step
        ("WX false", {}, parse("WX false")),
        ("theta[1] U true", {}, TRUE),
        ("theta[1] W false", {}, parse("G theta[1]")),
        ("theta[1] M true", {}, parse("F theta[1]")),
        ("theta[1] M eta[1,2]", {"eta[1,2]": False}, FALSE),
        ("eta[1,2] W theta[1]", {"eta[1,2]": True}, TRUE),
        ("eta[1,2] M theta[1]", {"eta[1,2]": True}, parse("true M theta[1]")),
        ("eta[1,2] <-> eta[2,2]", {"eta[1,2]": False, "eta[2,2]": False}, TRUE),
        ("eta[1,2] xor eta[2,2]", {"eta[1,2]": False, "eta[2,2]": False}, FALSE),
    ],
)
def test_partial_evaluation_folds_only_what_holds_at_every_step(text, known, expected) -> None:
    atoms = {parse(k): v for k, v in known.items()}
    assert partial(parse(text), atoms) == expected
