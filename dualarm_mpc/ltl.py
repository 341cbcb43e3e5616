"""LTLf formulas: the immutable syntax tree, its text parser and printer, and negation normal form.

Formulas are linear temporal logic over the finite trace k = 0..T of one horizon (docs/ltl.md).
Nodes are frozen dataclasses, so they hash and compare structurally and can serve as memo keys.
The same tree is built from text (:func:`parse`) or from Python (``G(eta(1, 3) >> WX(theta(3)))``),
and ``parse(str(f)) == f`` for every formula.

Text syntax, lowest to highest precedence::

    a -> b            implication (right-associative)
    a | b | c         disjunction (n-ary)
    a & b & c         conjunction (n-ary)
    a U b,  a R b     until, release (right-associative)
    !a ~a X a WX a N a G a F a
                      not, strong next, weak next (WX and N are synonyms), always, eventually
    ( a )  true  false  p  eta[1,3]  theta[j]

Index entries are 1-based integers (the paper's convention) or identifiers that act as placeholders,
filled in later by :func:`substitute`. The words ``X WX N G F U R true false`` are reserved.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import ClassVar

__all__ = [
    "FALSE",
    "KEYWORDS",
    "MAX_DEPTH",
    "TRUE",
    "Always",
    "And",
    "Atom",
    "Const",
    "Eventually",
    "F",
    "Formula",
    "G",
    "Implies",
    "LTLSyntaxError",
    "Next",
    "Not",
    "Or",
    "R",
    "Release",
    "U",
    "Until",
    "WX",
    "WeakNext",
    "X",
    "atoms",
    "conj",
    "disj",
    "eta",
    "nnf",
    "parse",
    "partial",
    "placeholders",
    "size",
    "substitute",
    "theta",
]

KEYWORDS = frozenset({"X", "WX", "N", "G", "F", "U", "R", "true", "false"})
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


# --------------------------------------------------------------------------------------------------
# Syntax tree


class Formula:
    """Base class of all LTLf nodes; provides ``&``, ``|``, ``~``, ``>>`` and canonical ``str``.

    Python's precedence is not LTL's: ``>>`` binds tighter than ``&`` and ``|``, so write
    ``(a & b) >> c``.
    """

    __slots__ = ()

    def __and__(self, other: Formula) -> Formula:
        return And((self, other)) if isinstance(other, Formula) else NotImplemented

    def __or__(self, other: Formula) -> Formula:
        return Or((self, other)) if isinstance(other, Formula) else NotImplemented

    def __invert__(self) -> Formula:
        return Not(self)

    def __rshift__(self, other: Formula) -> Formula:
        return Implies(self, other) if isinstance(other, Formula) else NotImplemented

    def __str__(self) -> str:
        return _to_text(self, 0)


def _check(*children: object) -> None:
    for child in children:
        if not isinstance(child, Formula):
            raise TypeError(f"expected a Formula, got {child!r}")


@dataclass(frozen=True, slots=True)
class Const(Formula):
    """The constant ``true`` or ``false``."""

    value: bool

    def __post_init__(self) -> None:
        if not isinstance(self.value, bool):
            raise TypeError(f"Const value must be a bool, got {self.value!r}")


@dataclass(frozen=True, slots=True)
class Atom(Formula):
    """An atomic proposition ``name[index...]``; str index entries are placeholders."""

    name: str
    index: tuple[int | str, ...] = ()

    def __post_init__(self) -> None:
        if not _is_name(self.name):
            raise ValueError(f"invalid atom name {self.name!r}")
        object.__setattr__(self, "index", tuple(self.index))
        for entry in self.index:
            ok_int = isinstance(entry, int) and not isinstance(entry, bool) and entry >= 0
            if not ok_int and not (isinstance(entry, str) and _IDENT.fullmatch(entry)):
                raise ValueError(f"invalid index entry {entry!r} in atom {self.name!r}")


@dataclass(frozen=True, slots=True)
class Not(Formula):
    """Negation ``!arg``."""

    arg: Formula

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class And(Formula):
    """Conjunction of two or more formulas."""

    args: tuple[Formula, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "args", tuple(self.args))
        if len(self.args) < 2:
            raise ValueError(f"And needs at least 2 arguments, got {len(self.args)}")
        _check(*self.args)


@dataclass(frozen=True, slots=True)
class Or(Formula):
    """Disjunction of two or more formulas."""

    args: tuple[Formula, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "args", tuple(self.args))
        if len(self.args) < 2:
            raise ValueError(f"Or needs at least 2 arguments, got {len(self.args)}")
        _check(*self.args)


@dataclass(frozen=True, slots=True)
class Implies(Formula):
    """Implication ``lhs -> rhs``."""

    lhs: Formula
    rhs: Formula

    def __post_init__(self) -> None:
        _check(self.lhs, self.rhs)


@dataclass(frozen=True, slots=True)
class Next(Formula):
    """Strong next ``X arg``: false at the last step."""

    arg: Formula
    keyword: ClassVar[str] = "X"

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class WeakNext(Formula):
    """Weak next ``WX arg`` (also written ``N arg``): true at the last step."""

    arg: Formula
    keyword: ClassVar[str] = "WX"

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class Always(Formula):
    """``G arg``: arg holds from now to the last step."""

    arg: Formula
    keyword: ClassVar[str] = "G"

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class Eventually(Formula):
    """``F arg``: arg holds at some step from now to the last."""

    arg: Formula
    keyword: ClassVar[str] = "F"

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class Until(Formula):
    """``lhs U rhs``: rhs holds at some step, and lhs at every step before it."""

    lhs: Formula
    rhs: Formula
    keyword: ClassVar[str] = "U"

    def __post_init__(self) -> None:
        _check(self.lhs, self.rhs)


@dataclass(frozen=True, slots=True)
class Release(Formula):
    """``lhs R rhs``: rhs holds up to and including the first step where lhs holds (if any)."""

    lhs: Formula
    rhs: Formula
    keyword: ClassVar[str] = "R"

    def __post_init__(self) -> None:
        _check(self.lhs, self.rhs)


def _is_name(name: object) -> bool:
    return isinstance(name, str) and bool(_IDENT.fullmatch(name)) and name not in KEYWORDS


# --------------------------------------------------------------------------------------------------
# Python construction API

TRUE = Const(True)
FALSE = Const(False)


def G(f: Formula) -> Formula:
    """Always."""
    return Always(f)


def F(f: Formula) -> Formula:
    """Eventually."""
    return Eventually(f)


def X(f: Formula) -> Formula:
    """Strong next."""
    return Next(f)


def WX(f: Formula) -> Formula:
    """Weak next."""
    return WeakNext(f)


def U(a: Formula, b: Formula) -> Formula:
    """``a U b``."""
    return Until(a, b)


def R(a: Formula, b: Formula) -> Formula:
    """``a R b``."""
    return Release(a, b)


def eta(i: int | str, j: int | str) -> Atom:
    """Grasp atom ``eta[i,j]``: arm i holds object j (1-based, or placeholders)."""
    return Atom("eta", (i, j))


def theta(j: int | str) -> Atom:
    """Goal atom ``theta[j]``: object j is in its goal region (1-based, or a placeholder)."""
    return Atom("theta", (j,))


def conj(fs: Iterable[Formula]) -> Formula:
    """Conjunction of ``fs``: TRUE when empty, the formula itself when single."""
    items = tuple(fs)
    return TRUE if not items else items[0] if len(items) == 1 else And(items)


def disj(fs: Iterable[Formula]) -> Formula:
    """Disjunction of ``fs``: FALSE when empty, the formula itself when single."""
    items = tuple(fs)
    return FALSE if not items else items[0] if len(items) == 1 else Or(items)


# --------------------------------------------------------------------------------------------------
# Printer

# Binding strength: a child is parenthesized when it binds more loosely than its slot requires.
_IMPLIES, _OR, _AND, _UNTIL, _UNARY, _ATOM = range(1, 7)


def _prec(f: Formula) -> int:
    match f:
        case Implies():
            return _IMPLIES
        case Or():
            return _OR
        case And():
            return _AND
        case Until() | Release():
            return _UNTIL
        case Not() | Next() | WeakNext() | Always() | Eventually():
            return _UNARY
        case _:
            return _ATOM


def _to_text(f: Formula, min_prec: int) -> str:
    """Text of ``f``, parenthesized unless it binds at least as tightly as ``min_prec``."""
    match f:
        case Const(value):
            text = "true" if value else "false"
        case Atom(name, index):
            text = f"{name}[{','.join(map(str, index))}]" if index else name
        case Not(arg):
            text = "!" + _to_text(arg, _UNARY)
        case Next(arg) | WeakNext(arg) | Always(arg) | Eventually(arg):
            inner = _to_text(arg, _UNARY)
            text = f"{f.keyword}{'' if inner.startswith('(') else ' '}{inner}"
        case And(args):  # a nested And stays nested, so it needs parentheses
            text = " & ".join(_to_text(a, _AND + 1) for a in args)
        case Or(args):
            text = " | ".join(_to_text(a, _OR + 1) for a in args)
        case Implies(lhs, rhs):  # right-associative
            text = f"{_to_text(lhs, _IMPLIES + 1)} -> {_to_text(rhs, _IMPLIES)}"
        case Until(lhs, rhs) | Release(lhs, rhs):  # right-associative
            text = f"{_to_text(lhs, _UNTIL + 1)} {f.keyword} {_to_text(rhs, _UNTIL)}"
        case _:
            raise TypeError(f"not a Formula: {f!r}")
    return f"({text})" if _prec(f) < min_prec else text


# --------------------------------------------------------------------------------------------------
# Parser


MAX_DEPTH = 50  # nesting of operators and parentheses; far beyond any rule, well within the stack
WINDOW = 40  # characters shown on either side of a syntax error in a long formula


class LTLSyntaxError(ValueError):
    """A parse error at 0-based character offset ``position`` of ``text``; the message shows the
    text (a window around the position, if long) with a caret under it."""

    def __init__(self, message: str, text: str, position: int) -> None:
        self.text = text
        self.position = position
        start, end = max(0, position - WINDOW), min(len(text), position + WINDOW)
        shown = ("..." if start else "") + text[start:end] + ("..." if end < len(text) else "")
        shown = re.sub(r"\s", " ", shown)
        caret = position - start + (3 if start else 0)
        super().__init__(f"column {position}: {message}\n  {shown}\n  {' ' * caret}^")


@dataclass(frozen=True, slots=True)
class _Token:
    kind: str  # "word", "int", "end", or the symbol itself
    text: str
    pos: int


_TOKEN = re.compile(r"(?P<word>[A-Za-z_][A-Za-z0-9_]*)|(?P<int>[0-9]+)|(?P<sym>->|[()\[\],&|!~])")


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while True:
        while pos < len(text) and text[pos].isspace():
            pos += 1
        if pos == len(text):
            return [*tokens, _Token("end", "", pos)]
        m = _TOKEN.match(text, pos)
        if m is None:
            raise LTLSyntaxError(f"unexpected character {text[pos]!r}", text, pos)
        kind = m.lastgroup or ""
        tokens.append(_Token(m[0] if kind == "sym" else kind, m[0], pos))
        pos = m.end()


_UNARY_OPS: dict[str, Callable[[Formula], Formula]] = {
    "!": Not,
    "~": Not,
    "X": Next,
    "WX": WeakNext,
    "N": WeakNext,
    "G": Always,
    "F": Eventually,
}


class _Parser:
    """Recursive descent, one method per precedence level."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = _tokenize(text)
        self.i = 0
        self.depth = 0

    @property
    def tok(self) -> _Token:
        return self.tokens[self.i]

    def error(self, expected: str, tok: _Token | None = None) -> LTLSyntaxError:
        tok = tok or self.tok
        found = "end of input" if tok.kind == "end" else repr(tok.text)
        return LTLSyntaxError(f"expected {expected} but found {found}", self.text, tok.pos)

    def accept(self, *texts: str) -> _Token | None:
        tok = self.tok
        if tok.kind != "end" and tok.text in texts:
            self.i += 1
            return tok
        return None

    def expect(self, text: str) -> _Token:
        tok = self.accept(text)
        if tok is None:
            raise self.error(repr(text))
        return tok

    def formula(self) -> Formula:
        f = self.implies()
        if self.tok.kind != "end":
            what = "a binary operator or end of input"
            if self.tok.kind == ")":
                raise LTLSyntaxError("unbalanced ')'", self.text, self.tok.pos)
            raise self.error(what)
        return f

    def deeper(self, tok: _Token, parse: Callable[[], Formula]) -> Formula:
        """``parse()`` one level of nesting deeper; past ``MAX_DEPTH`` a syntax error at ``tok``
        (the recursion would otherwise end in a RecursionError)."""
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise LTLSyntaxError(f"nested deeper than {MAX_DEPTH} levels", self.text, tok.pos)
        f = parse()
        self.depth -= 1
        return f

    def implies(self) -> Formula:
        lhs = self.disjunction()
        op = self.accept("->")
        return Implies(lhs, self.deeper(op, self.implies)) if op else lhs

    def disjunction(self) -> Formula:
        args = [self.conjunction()]
        while self.accept("|"):
            args.append(self.conjunction())
        return args[0] if len(args) == 1 else Or(tuple(args))

    def conjunction(self) -> Formula:
        args = [self.binary_temporal()]
        while self.accept("&"):
            args.append(self.binary_temporal())
        return args[0] if len(args) == 1 else And(tuple(args))

    def binary_temporal(self) -> Formula:
        lhs = self.unary()
        op = self.accept("U", "R")
        if op is None:
            return lhs
        return (Until if op.text == "U" else Release)(lhs, self.deeper(op, self.binary_temporal))

    def unary(self) -> Formula:
        op = self.accept(*_UNARY_OPS)
        return _UNARY_OPS[op.text](self.deeper(op, self.unary)) if op else self.primary()

    def primary(self) -> Formula:
        tok = self.tok
        if self.accept("("):
            f = self.deeper(tok, self.implies)
            self.expect(")")
            return f
        if self.accept("true"):
            return TRUE
        if self.accept("false"):
            return FALSE
        if tok.kind != "word" or tok.text in KEYWORDS:
            raise self.error("a formula")
        self.i += 1
        index: list[int | str] = []
        if self.accept("["):
            index.append(self.index_entry())
            while self.accept(","):
                index.append(self.index_entry())
            self.expect("]")
        return Atom(tok.text, tuple(index))

    def index_entry(self) -> int | str:
        tok = self.tok
        if tok.kind not in ("int", "word"):
            raise self.error("an index (integer or identifier)")
        self.i += 1
        return int(tok.text) if tok.kind == "int" else tok.text


def parse(text: str) -> Formula:
    """Parse LTLf text (syntax in the module docstring); raises :class:`LTLSyntaxError`."""
    return _Parser(text).formula()


# --------------------------------------------------------------------------------------------------
# Transformations


def nnf(f: Formula) -> Formula:
    """Negation normal form: no Implies, and Not only directly around an Atom.

    Uses the LTLf dualities ``!X a = WX !a``, ``!G a = F !a``, ``!(a U b) = !a R !b`` and their
    converses, De Morgan, ``!!a = a`` and ``!true = false``.
    """
    return _nnf(f, False)


def _nnf(f: Formula, neg: bool) -> Formula:
    match f:
        case Const(value):
            return Const(value != neg)
        case Atom():
            return Not(f) if neg else f
        case Not(arg):
            return _nnf(arg, not neg)
        case And(args):
            return (Or if neg else And)(tuple(_nnf(a, neg) for a in args))
        case Or(args):
            return (And if neg else Or)(tuple(_nnf(a, neg) for a in args))
        case Implies(lhs, rhs):
            return _nnf(Or((Not(lhs), rhs)), neg)
        case Next(arg):
            return (WeakNext if neg else Next)(_nnf(arg, neg))
        case WeakNext(arg):
            return (Next if neg else WeakNext)(_nnf(arg, neg))
        case Always(arg):
            return (Eventually if neg else Always)(_nnf(arg, neg))
        case Eventually(arg):
            return (Always if neg else Eventually)(_nnf(arg, neg))
        case Until(lhs, rhs):
            return (Release if neg else Until)(_nnf(lhs, neg), _nnf(rhs, neg))
        case Release(lhs, rhs):
            return (Until if neg else Release)(_nnf(lhs, neg), _nnf(rhs, neg))
    raise TypeError(f"not a Formula: {f!r}")


def _map_atoms(f: Formula, fn: Callable[[Atom], Formula]) -> Formula:
    """Rebuild ``f`` with every Atom replaced by ``fn(atom)``."""
    match f:
        case Atom():
            return fn(f)
        case Const():
            return f
        case And(args) | Or(args):
            return type(f)(tuple(_map_atoms(a, fn) for a in args))
        case Not(a) | Next(a) | WeakNext(a) | Always(a) | Eventually(a):
            return type(f)(_map_atoms(a, fn))
        case Implies(a, b) | Until(a, b) | Release(a, b):
            return type(f)(_map_atoms(a, fn), _map_atoms(b, fn))
    raise TypeError(f"not a Formula: {f!r}")


def atoms(f: Formula) -> frozenset[Atom]:
    """The atoms occurring in ``f``."""
    found: set[Atom] = set()

    def visit(a: Atom) -> Formula:
        found.add(a)
        return a

    _map_atoms(f, visit)
    return frozenset(found)


def size(f: Formula) -> int:
    """The number of nodes of ``f`` (operators, atoms, constants)."""
    count, stack = 0, [f]
    while stack:
        g = stack.pop()
        count += 1
        if isinstance(g, And | Or):
            stack += g.args
        elif isinstance(g, Until | Release | Implies):
            stack += (g.lhs, g.rhs)
        elif not isinstance(g, Atom | Const):
            stack.append(g.arg)
    return count


def placeholders(f: Formula) -> frozenset[str]:
    """The placeholder names (str index entries) occurring in ``f``."""
    return frozenset(e for a in atoms(f) for e in a.index if isinstance(e, str))


def rename_atoms(f: Formula, mapping: Mapping[Atom, Atom]) -> Formula:
    """Replace each atom found in ``mapping`` by its image."""
    return _map_atoms(f, lambda a: mapping.get(a, a))


def substitute(f: Formula, mapping: Mapping[str, int]) -> Formula:
    """Replace placeholder index entries by ``mapping[name]``; unmapped placeholders are kept."""
    return _map_atoms(
        f,
        lambda a: Atom(
            a.name, tuple(mapping.get(e, e) if isinstance(e, str) else e for e in a.index)
        ),
    )


def partial(f: Formula, known: dict[Atom, bool]) -> Formula:
    """``f`` with the atoms of ``known`` (constant over all steps) replaced and simplified.

    Only simplifications valid at every step of an LTLf trace are made: ``X TRUE`` is not TRUE
    (strong next is false at the last step), everything else folds as in propositional logic
    (``G TRUE``, ``F TRUE``, ``WX TRUE``, ``a U TRUE``, ``a R TRUE`` are TRUE; duals for FALSE)."""
    match f:
        case Atom():
            return Const(known[f]) if f in known else f
        case Const():
            return f
        case Not(a):
            a = partial(a, known)
            return Const(not a.value) if isinstance(a, Const) else Not(a)
        case And(args) | Or(args):
            unit, zero = (TRUE, FALSE) if isinstance(f, And) else (FALSE, TRUE)
            kept = []
            for a in (partial(a, known) for a in args):
                if a == zero:
                    return zero
                if a != unit:
                    kept.append(a)
            return unit if not kept else kept[0] if len(kept) == 1 else type(f)(tuple(kept))
        case Implies(a, b):
            a, b = partial(a, known), partial(b, known)
            if a == FALSE or b == TRUE:
                return TRUE
            if a == TRUE:
                return b
            return Implies(a, b)
        case Always(a) | Eventually(a) | WeakNext(a):
            a = partial(a, known)
            return a if isinstance(a, Const) and (a.value or not isinstance(f, WeakNext)) \
                else type(f)(a)
        case Next(a):
            a = partial(a, known)
            return FALSE if a == FALSE else Next(a)
        case Until(a, b) | Release(a, b):
            a, b = partial(a, known), partial(b, known)
            if isinstance(b, Const):
                return b
            return type(f)(a, b)
    raise TypeError(f"not a Formula: {f!r}")
