"""LTLf formulas: the immutable syntax tree, its text parser and printer, and negation normal form.

Formulas are linear temporal logic over the finite trace k = 0..T of one horizon (docs/ltl.md).
Nodes are frozen dataclasses, so they hash and compare structurally and can serve as memo keys.
The same tree is built from text (:func:`parse`) or from Python (``G(eta(1, 3) >> WX(theta(3)))``),
and ``parse(str(f)) == f`` for every formula.

Text syntax, lowest to highest precedence (Spot's; every spelling in docs/ltl.md)::

    a -> b   a <-> b  implication, equivalence (right-associative; also => <=> --> <-->)
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
:func:`substitute`. The words in ``KEYWORDS`` are reserved.
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
    "Equiv",
    "Eventually",
    "F",
    "Formula",
    "G",
    "Implies",
    "LTLSyntaxError",
    "M",
    "Next",
    "Not",
    "Or",
    "R",
    "Release",
    "StrongRelease",
    "U",
    "Until",
    "W",
    "WX",
    "WeakNext",
    "WeakUntil",
    "X",
    "Xor",
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

KEYWORDS = frozenset({"X", "WX", "N", "G", "F", "U", "R", "V", "W", "M", "xor", "true", "false",
                      "last"})
_CONSTANTS = {"true": True, "false": False}  # also 1 and 0; any case, as in Spot and ltlf2dfa
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
class _Unary(Formula):
    """A node with one argument."""

    arg: Formula

    def __post_init__(self) -> None:
        _check(self.arg)


@dataclass(frozen=True, slots=True)
class _Binary(Formula):
    """A node with two arguments; ``keyword`` is its canonical spelling."""

    lhs: Formula
    rhs: Formula
    keyword: ClassVar[str]

    def __post_init__(self) -> None:
        _check(self.lhs, self.rhs)


@dataclass(frozen=True, slots=True)
class Not(_Unary):
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
class Implies(_Binary):
    """Implication ``lhs -> rhs``."""

    keyword: ClassVar[str] = "->"


@dataclass(frozen=True, slots=True)
class Equiv(_Binary):
    """Equivalence ``lhs <-> rhs``."""

    keyword: ClassVar[str] = "<->"


@dataclass(frozen=True, slots=True)
class Xor(_Binary):
    """Exclusive or ``lhs xor rhs``: exactly one of the two holds."""

    keyword: ClassVar[str] = "xor"


@dataclass(frozen=True, slots=True)
class Next(_Unary):
    """Strong next ``X arg``: false at the last step."""

    keyword: ClassVar[str] = "X"


@dataclass(frozen=True, slots=True)
class WeakNext(_Unary):
    """Weak next ``WX arg`` (also written ``N arg``): true at the last step."""

    keyword: ClassVar[str] = "WX"


@dataclass(frozen=True, slots=True)
class Always(_Unary):
    """``G arg``: arg holds from now to the last step."""

    keyword: ClassVar[str] = "G"


@dataclass(frozen=True, slots=True)
class Eventually(_Unary):
    """``F arg``: arg holds at some step from now to the last."""

    keyword: ClassVar[str] = "F"


@dataclass(frozen=True, slots=True)
class Until(_Binary):
    """``lhs U rhs``: rhs holds at some step, and lhs at every step before it."""

    keyword: ClassVar[str] = "U"


@dataclass(frozen=True, slots=True)
class Release(_Binary):
    """``lhs R rhs``: rhs holds up to and including the first step where lhs holds (if any)."""

    keyword: ClassVar[str] = "R"


@dataclass(frozen=True, slots=True)
class WeakUntil(_Binary):
    """``lhs W rhs``: lhs holds until rhs does, or to the last step if rhs never does."""

    keyword: ClassVar[str] = "W"


@dataclass(frozen=True, slots=True)
class StrongRelease(_Binary):
    """``lhs M rhs``: rhs holds up to and including a step where lhs holds, and there is one."""

    keyword: ClassVar[str] = "M"


def _is_name(name: object) -> bool:
    return (isinstance(name, str) and bool(_IDENT.fullmatch(name)) and name not in KEYWORDS
            and name.lower() not in _CONSTANTS and name.lower() != "last")


def _needs_quotes(name: str) -> bool:
    """Whether an atom's name would read as a unary F, G or X touching the rest (Spot's rule:
    ``Xa`` is ``X a``; ``X1`` is an atom)."""
    return name[0] in "FGX" and len(name) > 1 and not name[1].isdigit()


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
            text = f'"{text}"' if _needs_quotes(name) else text
        case Not(arg):
            text = "!" + _to_text(arg, _UNARY)
        case Next(arg) | WeakNext(arg) | Always(arg) | Eventually(arg):
            inner = _to_text(arg, _UNARY)
            text = f"{f.keyword}{'' if inner.startswith('(') else ' '}{inner}"
        case And(args):  # a nested And stays nested, so it needs parentheses
            text = " & ".join(_to_text(a, _AND + 1) for a in args)
        case Or(args):
            text = " | ".join(_to_text(a, _OR + 1) for a in args)
        case Implies(lhs, rhs) | Equiv(lhs, rhs):  # right-associative
            text = f"{_to_text(lhs, _IMPLIES + 1)} {f.keyword} {_to_text(rhs, _IMPLIES)}"
        case Xor(lhs, rhs):  # left-associative
            text = f"{_to_text(lhs, _XOR)} xor {_to_text(rhs, _XOR + 1)}"
        case Until(lhs, rhs) | Release(lhs, rhs) | WeakUntil(lhs, rhs) | StrongRelease(lhs, rhs):
            # right-associative
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
    kind: str  # "word", "int", "quoted", "end", a constant, or the operator's canonical spelling
    text: str  # as written
    pos: int


_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_INT = re.compile(r"[0-9]+")
_QUOTED = re.compile(r'"[^"]*"')
_SYMBOL = re.compile(r"<-->|<->|<=>|-->|->|=>|<>|\[\]|&&|\|\||/\\|\\/|\.\.|[()\[\],&|!~^:$]")
# Spot's and ltlf2dfa's other spellings of an operator → ours.
_CANONICAL = {"=>": "->", "-->": "->", "<=>": "<->", "<-->": "<->", "&&": "&", "/\\": "&",
              "||": "|", "\\/": "|", "^": "xor", "~": "!", "[]": "G", "<>": "F", "V": "R",
              "N": "WX"}
_QUOTED_ATOM = re.compile(r"\s*([A-Za-z_]\w*)\s*(?:\[\s*(\w+(?:\s*,\s*\w+)*)\s*\])?\s*", re.ASCII)


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while True:
        while pos < len(text) and text[pos].isspace():
            pos += 1
        if pos == len(text):
            return [*tokens, _Token("end", "", pos)]
        if m := _WORD.match(text, pos):
            word, kind = m[0], "word"
            if word.lower() in (*_CONSTANTS, "last"):
                kind = word.lower()
            elif word in KEYWORDS:
                kind = _CANONICAL.get(word, word)
            elif _needs_quotes(word):  # Spot's GFa: the operator, then the rest from pos + 1
                word = kind = word[0]
        elif m := _INT.match(text, pos):
            word, kind = m[0], "int"
        elif m := _QUOTED.match(text, pos):
            word, kind = m[0], "quoted"
        elif m := _SYMBOL.match(text, pos):
            word = m[0]
            kind = _CANONICAL.get(word, word)
        elif text[pos] == '"':
            raise LTLSyntaxError("unclosed '\"'", text, pos)
        else:
            raise LTLSyntaxError(f"unexpected character {text[pos]!r}", text, pos)
        tokens.append(_Token(kind, word, pos))
        pos += len(word)


_UNARY_OPS: dict[str, Callable[[Formula], Formula]] = {
    "!": Not,
    "X": Next,
    "WX": WeakNext,
    "G": Always,
    "F": Eventually,
}
_BINARY_OPS: dict[str, Callable[[Formula, Formula], Formula]] = {
    "->": Implies,
    "<->": Equiv,
    "U": Until,
    "R": Release,
    "W": WeakUntil,
    "M": StrongRelease,
}


def _nest(wrap: Callable[[Formula], Formula], n: int, f: Formula) -> Formula:
    for _ in range(n):
        f = wrap(f)
    return f


def _bounded(op: str, n: int, m: int | None, strong: bool, f: Formula) -> Formula:
    """Spot's ``F[n:m] f`` (f at some step k+n..k+m, which must exist) and ``G[n:m] f`` (f at
    every step k+n..k+m that exists; ``G[n:m!]``: and they must exist); m = None is unbounded."""
    eventually = op == "F"
    step = Next if eventually or strong else WeakNext
    if m is None:
        body = (Eventually if eventually else Always)(f)
    else:
        body = f
        for _ in range(m - n):
            body = (Or if eventually else And)((f, step(body)))
    return _nest(step, n, body)


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

    def accept(self, *kinds: str) -> _Token | None:
        tok = self.tok
        if tok.kind in kinds:
            self.i += 1
            return tok
        return None

    def expect(self, kind: str) -> _Token:
        tok = self.accept(kind)
        if tok is None:
            raise self.error(repr(kind))
        return tok

    def formula(self) -> Formula:
        f = self.implies()
        if self.tok.kind != "end":
            what = "a binary operator or end of input"
            if self.tok.kind == ")":
                raise LTLSyntaxError("unbalanced ')'", self.text, self.tok.pos)
            raise self.error(what)
        return f

    def deeper(self, tok: _Token, parse: Callable[[], Formula], levels: int = 1) -> Formula:
        """``parse()`` ``levels`` of nesting deeper; past ``MAX_DEPTH`` a syntax error at ``tok``
        (the recursion would otherwise end in a RecursionError)."""
        self.depth += levels
        if self.depth > MAX_DEPTH:
            raise LTLSyntaxError(f"nested deeper than {MAX_DEPTH} levels", self.text, tok.pos)
        f = parse()
        self.depth -= levels
        return f

    def implies(self) -> Formula:
        lhs = self.disjunction()
        op = self.accept("->", "<->")
        return _BINARY_OPS[op.kind](lhs, self.deeper(op, self.implies)) if op else lhs

    def disjunction(self) -> Formula:
        args = [self.exclusive()]
        while self.accept("|"):
            args.append(self.exclusive())
        return args[0] if len(args) == 1 else Or(tuple(args))

    def exclusive(self) -> Formula:
        f = self.conjunction()
        depth = self.depth
        while op := self.accept("xor"):  # left-associative: each one nests the chain deeper
            f = Xor(f, self.deeper(op, self.conjunction))
            self.depth += 1
        self.depth = depth
        return f

    def conjunction(self) -> Formula:
        args = [self.binary_temporal()]
        while self.accept("&"):
            args.append(self.binary_temporal())
        return args[0] if len(args) == 1 else And(tuple(args))

    def binary_temporal(self) -> Formula:
        lhs = self.unary()
        op = self.accept("U", "R", "W", "M")
        return _BINARY_OPS[op.kind](lhs, self.deeper(op, self.binary_temporal)) if op else lhs

    def unary(self) -> Formula:
        op = self.accept(*_UNARY_OPS)
        if op is None:
            return self.primary()
        if op.text in ("X", "F", "G") and self.tok.kind == "[":
            wrap, levels = self.bounds(op)
            return wrap(self.deeper(op, self.unary, levels))
        return _UNARY_OPS[op.kind](self.deeper(op, self.unary))

    def bounds(self, op: _Token) -> tuple[Callable[[Formula], Formula], int]:
        """Spot's ``X[!]``, ``X[n]``, ``F[n:m]``, ``G[n:m]`` (also ``n..m``, ``n,m``; m may be ``$``
        or ``inf`` or left out: unbounded; a ``!`` before ``]`` asks for strong nexts): the
        expansion and the levels of nesting it counts for."""
        self.expect("[")
        if op.kind == "X":
            n = 1 if self.tok.kind == "!" else self.bound()
            self.accept("!")  # X[n!] = X[n]: our X is strong
            self.expect("]")
            return (lambda f: _nest(Next, n, f)), max(n, 1)
        n = self.bound()
        if not self.accept(":", "..", ","):
            raise self.error(f"':' between the bounds of {op.kind}[n:m]")
        m = None
        if not (self.accept("$") or self.accept_word("inf") or self.tok.kind in ("!", "]")):
            tok = self.tok
            m = self.bound()
            if m < n:
                raise LTLSyntaxError(f"empty range {op.kind}[{n}:{m}]", self.text, tok.pos)
        strong = self.accept("!") is not None
        self.expect("]")
        return (lambda f: _bounded(op.kind, n, m, strong, f)), max(n + 1 if m is None else m, 1)

    def bound(self) -> int:
        tok = self.tok
        if tok.kind != "int":
            raise self.error("a bound (an integer)")
        if int(tok.text) > MAX_DEPTH:
            raise LTLSyntaxError(f"bound above {MAX_DEPTH}", self.text, tok.pos)
        self.i += 1
        return int(tok.text)

    def accept_word(self, word: str) -> _Token | None:
        return self.accept("word") if self.tok.kind == "word" and self.tok.text == word else None

    def primary(self) -> Formula:
        tok = self.tok
        if self.accept("("):
            f = self.deeper(tok, self.implies)
            self.expect(")")
            return f
        if self.accept(*_CONSTANTS):
            return Const(_CONSTANTS[tok.kind])
        if tok.kind == "int" and tok.text in ("0", "1"):  # Spot prints the constants so
            self.i += 1
            return Const(tok.text == "1")
        if self.accept("last"):  # ltlf2dfa's and flloat's: k is the last step
            return WeakNext(FALSE)
        if self.accept("quoted"):
            return self.quoted(tok)
        if tok.kind != "word":
            raise self.error("a formula")
        self.i += 1
        index: list[int | str] = []
        if self.tok.text == "[]" and self.tok.pos == tok.pos + len(tok.text):  # eta[]
            raise LTLSyntaxError("expected an index (integer or identifier) but found ']'",
                                 self.text, self.tok.pos + 1)
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

    def quoted(self, tok: _Token) -> Atom:
        """A double-quoted atom, as Spot writes one whose name is not a plain identifier."""
        m = _QUOTED_ATOM.fullmatch(tok.text[1:-1])
        try:
            if m is None:
                raise ValueError("not an atom")
            entries = re.split(r"\s*,\s*", m[2]) if m[2] else []
            return Atom(m[1], tuple(int(e) if e.isdigit() else e for e in entries))
        except ValueError as err:
            raise LTLSyntaxError(f"expected an atom name[index, ...] in quotes ({err})",
                                 self.text, tok.pos) from None


def parse(text: str) -> Formula:
    """Parse LTLf text (syntax in the module docstring); raises :class:`LTLSyntaxError`."""
    return _Parser(text).formula()


# --------------------------------------------------------------------------------------------------
# Transformations


def nnf(f: Formula) -> Formula:
    """Negation normal form: no Implies, Equiv, Xor, WeakUntil or StrongRelease, and Not only
    directly around an Atom: the operators the encoder knows.

    Uses the LTLf dualities ``!X a = WX !a``, ``!G a = F !a``, ``!(a U b) = !a R !b`` and their
    converses, De Morgan, ``!!a = a``, ``!true = false``, and the definitions
    ``a <-> b = (a & b) | (!a & !b)``, ``a W b = (a U b) | G a``, ``a M b = (a R b) & F a``.
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
        case Equiv(lhs, rhs) | Xor(lhs, rhs):  # xor is the negation of <->
            same = isinstance(f, Equiv) != neg
            return Or((And((_nnf(lhs, False), _nnf(rhs, not same))),
                       And((_nnf(lhs, True), _nnf(rhs, same)))))
        case WeakUntil(lhs, rhs) | StrongRelease(lhs, rhs):  # each the negation's dual of the other
            # the left argument is the one repeated: a right-nested chain a W b W c stays linear
            a, b = _nnf(lhs, neg), _nnf(rhs, neg)
            if isinstance(f, WeakUntil) != neg:
                return Or((Until(a, b), Always(a)))
            return And((Release(a, b), Eventually(a)))
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
        case _Unary(a):
            return type(f)(_map_atoms(a, fn))
        case _Binary(a, b):
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
    """The number of nodes of ``f`` (operators, atoms, constants), with ``<->``, ``xor``, ``W``
    and ``M`` counted as :func:`nnf` writes them for the encoder: three nodes, and each argument
    that it repeats (both of ``<->`` and ``xor``, the left one of ``W`` and ``M``) twice."""
    count, stack = 0, [(f, 1)]
    while stack:
        g, n = stack.pop()
        count += n
        if isinstance(g, And | Or):
            stack += [(a, n) for a in g.args]
        elif isinstance(g, Equiv | Xor):
            count += 2 * n
            stack += [(g.lhs, 2 * n), (g.rhs, 2 * n)]
        elif isinstance(g, WeakUntil | StrongRelease):
            count += 2 * n
            stack += [(g.lhs, 2 * n), (g.rhs, n)]
        elif isinstance(g, _Binary):
            stack += [(g.lhs, n), (g.rhs, n)]
        elif not isinstance(g, Atom | Const):
            stack.append((g.arg, n))
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
    (``G TRUE``, ``F TRUE``, ``WX TRUE``, ``a U TRUE``, ``a R TRUE``, ``a W TRUE``, ``TRUE W b``
    are TRUE; duals for FALSE)."""
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
        case WeakUntil(a, b) | StrongRelease(a, b):
            a, b = partial(a, known), partial(b, known)
            weak = isinstance(f, WeakUntil)
            if Const(weak) in (a, b):  # true W b = a W true = true, false M b = a M false = false
                return Const(weak)
            if not isinstance(b, Const):
                return type(f)(a, b)
            # a W false = G a, a M true = F a
            return a if isinstance(a, Const) else (Always if weak else Eventually)(a)
        case Equiv(a, b) | Xor(a, b):
            a, b = partial(a, known), partial(b, known)
            if isinstance(a, Const) and isinstance(b, Const):
                return Const((a == b) == isinstance(f, Equiv))
            return type(f)(a, b)
    raise TypeError(f"not a Formula: {f!r}")
