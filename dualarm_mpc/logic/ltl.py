"""LTLf formulas: the immutable syntax tree, its Python construction API and its printer.

Formulas are linear temporal logic over the finite trace k = 0..T of one horizon (docs/ltl.md).
Nodes are frozen dataclasses, so they hash and compare structurally and can serve as memo keys.
The same tree is built from text (:func:`dualarm_mpc.logic.parser.parse`) or from Python
(``G(eta(1, 3) >> WX(theta(3)))``), and ``parse(str(f)) == f`` for every formula.

Text syntax, lowest to highest precedence (Spot's; every spelling in docs/ltl.md)::

    a -> b   a <-> b  implication (right-associative; also => -->), equivalence (also <=>
                      <-->; a chain a <-> b <-> c is refused: parenthesize it)
    a | b | c         disjunction (n-ary; also || \\/)
    a xor b           exclusive or (left-associative; also ^)
    a & b & c         conjunction (n-ary; also && /\\)
    a U b  a R b  a W b  a M b
                      until, release (also V), weak until, strong release (right-associative)
    !a X a WX a G a F a
                      not (also ~), strong next (also X[!]), weak next (also N), always (also []),
                      eventually (also <>); Spot's X[n], F[n:m] and G[n:m] expand to nested nexts
    ( a )  true  false  last  p  eta[1,3]  theta[j]  "eta[1,3]"
                      constants (also 1, 0), the last step (WX false), atoms (quoted as in Spot)

As in Spot, a unary F, G or X may touch its argument (``GFa`` is ``G F a``), so an atom whose
name starts with one of them and a letter is written in double quotes. Index entries are 1-based
integers (the paper's convention) or identifiers that act as placeholders, filled in later by
:func:`dualarm_mpc.logic.transform.substitute`. The words in ``KEYWORDS`` are reserved.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import ClassVar

__all__ = [
    "FALSE",
    "CONSTANTS",
    "KEYWORDS",
    "TRUE",
    "Always",
    "And",
    "Atom",
    "Binary",
    "Const",
    "Equiv",
    "Eventually",
    "F",
    "Formula",
    "G",
    "Implies",
    "M",
    "Next",
    "Not",
    "Or",
    "R",
    "Release",
    "StrongRelease",
    "U",
    "Unary",
    "Until",
    "W",
    "WX",
    "WeakNext",
    "WeakUntil",
    "X",
    "Xor",
    "conj",
    "disj",
    "eta",
    "needs_quotes",
    "theta",
]

KEYWORDS = frozenset({"X", "WX", "N", "G", "F", "U", "R", "V", "W", "M", "xor", "true", "false",
                      "last"})
CONSTANTS = {"true": True, "false": False}  # also 1 and 0; any case, as in Spot and ltlf2dfa
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


# --------------------------------------------------------------------------------------------------
# Syntax tree


class Formula:
    """Base class of all LTLf nodes; provides ``&``, ``|``, ``^``, ``~``, ``>>`` and canonical
    ``str``.

    Python's precedence is not LTL's: ``>>`` binds tighter than ``&`` and ``|``, so write
    ``(a & b) >> c``.
    """

    __slots__ = ()

    def __and__(self, other: Formula) -> Formula:
        return And((self, other)) if isinstance(other, Formula) else NotImplemented

    def __or__(self, other: Formula) -> Formula:
        return Or((self, other)) if isinstance(other, Formula) else NotImplemented

    def __xor__(self, other: Formula) -> Formula:
        return Xor(self, other) if isinstance(other, Formula) else NotImplemented

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
class Unary(Formula):
    """A node with one argument."""

    arg: Formula

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class Binary(Formula):
    """A node with two arguments; ``keyword`` is its canonical spelling."""

    lhs: Formula
    rhs: Formula
    keyword: ClassVar[str]

    def __post_init__(self) -> None:
        _check(self.lhs, self.rhs)


@dataclass(frozen=True, slots=True)
class Not(Unary):
    """Negation ``!arg``."""


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
class Implies(Binary):
    """Implication ``lhs -> rhs``."""

    keyword: ClassVar[str] = "->"


@dataclass(frozen=True, slots=True)
class Equiv(Binary):
    """Equivalence ``lhs <-> rhs``."""

    keyword: ClassVar[str] = "<->"


@dataclass(frozen=True, slots=True)
class Xor(Binary):
    """Exclusive or ``lhs xor rhs``: exactly one of the two holds."""

    keyword: ClassVar[str] = "xor"


@dataclass(frozen=True, slots=True)
class Next(Unary):
    """Strong next ``X arg``: false at the last step."""

    keyword: ClassVar[str] = "X"


@dataclass(frozen=True, slots=True)
class WeakNext(Unary):
    """Weak next ``WX arg`` (also written ``N arg``): true at the last step."""

    keyword: ClassVar[str] = "WX"


@dataclass(frozen=True, slots=True)
class Always(Unary):
    """``G arg``: arg holds from now to the last step."""

    keyword: ClassVar[str] = "G"


@dataclass(frozen=True, slots=True)
class Eventually(Unary):
    """``F arg``: arg holds at some step from now to the last."""

    keyword: ClassVar[str] = "F"


@dataclass(frozen=True, slots=True)
class Until(Binary):
    """``lhs U rhs``: rhs holds at some step, and lhs at every step before it."""

    keyword: ClassVar[str] = "U"


@dataclass(frozen=True, slots=True)
class Release(Binary):
    """``lhs R rhs``: rhs holds up to and including the first step where lhs holds (if any)."""

    keyword: ClassVar[str] = "R"


@dataclass(frozen=True, slots=True)
class WeakUntil(Binary):
    """``lhs W rhs``: lhs holds until rhs does, or to the last step if rhs never does."""

    keyword: ClassVar[str] = "W"


@dataclass(frozen=True, slots=True)
class StrongRelease(Binary):
    """``lhs M rhs``: rhs holds up to and including a step where lhs holds, and there is one."""

    keyword: ClassVar[str] = "M"


def _is_name(name: object) -> bool:
    return (isinstance(name, str) and bool(_IDENT.fullmatch(name)) and name not in KEYWORDS
            and name.lower() not in CONSTANTS and name.lower() != "last")


def needs_quotes(name: str) -> bool:
    """Whether an atom's name would read as a unary F, G, X or WX touching the rest (Spot's
    rule: ``Xa`` is ``X a``, ``X1`` an atom; flloat's and ltlf2dfa's for ``WXa``)."""
    op = "WX" if name.startswith("WX") else name[0]
    return op in ("F", "G", "X", "WX") and len(name) > len(op) \
        and not name[len(op)].isdigit()


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


def W(a: Formula, b: Formula) -> Formula:
    """``a W b`` (weak until)."""
    return WeakUntil(a, b)


def M(a: Formula, b: Formula) -> Formula:
    """``a M b`` (strong release)."""
    return StrongRelease(a, b)


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

# Binding strength (Spot's): a child is parenthesized when it binds more loosely than its slot
# requires.
_IMPLIES, _OR, _XOR, _AND, _UNTIL, _UNARY, _ATOM = range(1, 8)


def _prec(f: Formula) -> int:
    match f:
        case Implies() | Equiv():
            return _IMPLIES
        case Or():
            return _OR
        case Xor():
            return _XOR
        case And():
            return _AND
        case Until() | Release() | WeakUntil() | StrongRelease():
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
            text = f'"{text}"' if needs_quotes(name) else text
        case Not(arg):
            text = "!" + _to_text(arg, _UNARY)
        case Next(arg) | WeakNext(arg) | Always(arg) | Eventually(arg):
            inner = _to_text(arg, _UNARY)
            text = f"{f.keyword}{'' if inner.startswith('(') else ' '}{inner}"
        case And(args):  # a nested And stays nested, so it needs parentheses
            text = " & ".join(_to_text(a, _AND + 1) for a in args)
        case Or(args):
            text = " | ".join(_to_text(a, _OR + 1) for a in args)
        case Implies(lhs, rhs) | Equiv(lhs, rhs):  # right-associative; no chain of <->
            chain = isinstance(f, Equiv) and isinstance(rhs, Equiv)
            text = f"{_to_text(lhs, _IMPLIES + 1)} {f.keyword} {_to_text(rhs, _IMPLIES + chain)}"
        case Xor(lhs, rhs):  # left-associative
            text = f"{_to_text(lhs, _XOR)} xor {_to_text(rhs, _XOR + 1)}"
        case Until(lhs, rhs) | Release(lhs, rhs) | WeakUntil(lhs, rhs) | StrongRelease(lhs, rhs):
            # right-associative
            text = f"{_to_text(lhs, _UNTIL + 1)} {f.keyword} {_to_text(rhs, _UNTIL)}"
        case _:
            raise TypeError(f"not a Formula: {f!r}")
    return f"({text})" if _prec(f) < min_prec else text
