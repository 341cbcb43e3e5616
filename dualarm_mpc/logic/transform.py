"""Transformations of LTLf formulas: negation normal form (the encoder's input), atoms, size,
placeholders and their substitution, partial evaluation."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from dualarm_mpc.logic.ltl import (
    FALSE,
    TRUE,
    Always,
    And,
    Atom,
    Binary,
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
    Unary,
    Until,
    WeakNext,
    WeakUntil,
    Xor,
)

__all__ = ["atoms", "nnf", "partial", "placeholders", "rename_atoms", "size", "substitute"]


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
        case Unary(a):
            return type(f)(_map_atoms(a, fn))
        case Binary(a, b):
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
        elif isinstance(g, Binary):
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
