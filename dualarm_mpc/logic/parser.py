"""The text syntax of LTLf formulas: tokenizer and parser, and the syntax error that names its
column. The grammar and its precedence are in :mod:`dualarm_mpc.logic.ltl`'s docstring; the
printer there writes what this reads (``parse(str(f)) == f``)."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from dualarm_mpc.logic.ltl import (
    CONSTANTS,
    FALSE,
    KEYWORDS,
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
    needs_quotes,
)

__all__ = ["MAX_DEPTH", "LTLSyntaxError", "parse"]


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
            if word.lower() in (*CONSTANTS, "last"):
                kind = word.lower()
            elif word in KEYWORDS:
                kind = _CANONICAL.get(word, word)
            elif needs_quotes(word):  # Spot's GFa, flloat's WXGa: the operator, then the rest
                word = kind = "WX" if word.startswith("WX") else word[0]
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

    def implies(self, equiv: bool = False) -> Formula:
        """``equiv``: the right side of a ``<->``, where another would make a chain, which
        flloat and ltlf2dfa read as "all equal" and we would read as nested: refused."""
        lhs = self.disjunction()
        op = self.accept("->", "<->")
        if op is None:
            return lhs
        if equiv and op.kind == "<->":
            raise LTLSyntaxError("a chain of <-> (flloat and ltlf2dfa read a <-> b <-> c as "
                                 "'all three equal'): write (a <-> b) <-> c or a <-> (b <-> c)",
                                 self.text, op.pos)
        return _BINARY_OPS[op.kind](lhs, self.deeper(op, lambda: self.implies(op.kind == "<->")))

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
            if m < n:  # Spot swaps the bounds; a reversed range is more likely a slip
                raise LTLSyntaxError(f"empty range {op.kind}[{n}:{m}] (Spot reads it as "
                                     f"{op.kind}[{m}:{n}]: write that if it is meant)",
                                     self.text, tok.pos)
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
        if self.accept(*CONSTANTS):
            return Const(CONSTANTS[tok.kind])
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
