"""Vectorized linear rows: many constraints ``lb ≤ Σ c·x ≤ ub`` added to a program at once.

Constraint families (dynamics, picking model, LTL, ...) are written as whole arrays of rows,
``rows.add([(coef, var_index), ...], lb, ub)`` with numpy broadcasting, and emitted as one sparse
``LinearConstraint`` per family, so building the program costs little next to solving it.
Variables are referred to by their index in the program's decision-variable vector.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram


class Rows:
    """An accumulator of sparse linear rows over a program's decision variables."""

    def __init__(self) -> None:
        # Triplets and bounds, in blocks (numpy) and in scalar rows (lists); rows are numbered
        # in the order they were added.
        self._rows: list[np.ndarray] = []
        self._cols: list[np.ndarray] = []
        self._vals: list[np.ndarray] = []
        self._bounds: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._scalar: tuple[list, list, list, list, list, list] = ([], [], [], [], [], [])
        self.count = 0

    def add(self, terms: list[tuple], lb=-np.inf, ub=np.inf) -> None:
        """Add rows ``lb ≤ Σ_t coef_t · x[index_t] ≤ ub``; all arguments broadcast to one shape,
        one row per element. A term's index of -1 means "no variable" (the term is dropped)."""
        shape = np.broadcast_shapes(*(np.shape(c) for c, _ in terms),
                                    *(np.shape(i) for _, i in terms), np.shape(lb), np.shape(ub))
        m = int(np.prod(shape, dtype=int))
        if m == 0:
            return
        row = self.count + np.arange(m)
        for coef, index in terms:
            c = np.broadcast_to(coef, shape).ravel().astype(float)
            i = np.broadcast_to(index, shape).ravel().astype(int)
            keep = (i >= 0) & (c != 0)
            self._rows.append(row[keep])
            self._cols.append(i[keep])
            self._vals.append(c[keep])
        self._bounds.append((row, np.broadcast_to(np.asarray(lb, float), shape).ravel(),
                             np.broadcast_to(np.asarray(ub, float), shape).ravel()))
        self.count += m

    def add_row(self, pairs: list[tuple[float, int]], lb: float = -np.inf,
                ub: float = np.inf) -> None:
        """Add one row ``lb ≤ Σ c·x[i] ≤ ub`` from ``(c, i)`` pairs (cheap; for scalar logic)."""
        rows, cols, vals, brow, lbs, ubs = self._scalar
        for c, i in pairs:
            rows.append(self.count)
            cols.append(i)
            vals.append(c)
        brow.append(self.count)
        lbs.append(lb)
        ubs.append(ub)
        self.count += 1

    def emit(self, prog: MathematicalProgram, description: str) -> None:
        """Add the accumulated rows to ``prog`` as one sparse linear constraint."""
        if self.count == 0:
            return
        rows, cols, vals, lb, ub = self._triplets()
        used, local = np.unique(cols, return_inverse=True)
        A = sp.csc_matrix((vals, (rows, local)), shape=(self.count, len(used)))
        A.sum_duplicates()
        binding = prog.AddLinearConstraint(A, lb, ub, prog.decision_variables()[used])
        binding.evaluator().set_description(description)

    def matrix(self, n_columns: int) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        """The accumulated rows as (A, lb, ub) over ``n_columns`` variables, for a standard
        form built without a program."""
        rows, cols, vals, lb, ub = self._triplets()
        A = sp.csr_matrix((vals, (rows, cols)), shape=(self.count, n_columns))
        A.sum_duplicates()
        return A, lb, ub

    def _triplets(self):
        srows, scols, svals, brow, lbs, ubs = self._scalar
        rows = np.concatenate(self._rows + [np.asarray(srows, int)])
        cols = np.concatenate(self._cols + [np.asarray(scols, int)])
        vals = np.concatenate(self._vals + [np.asarray(svals, float)])
        lb = np.empty(self.count)
        ub = np.empty(self.count)
        for r, lo, hi in self._bounds + [(np.asarray(brow, int), np.asarray(lbs, float),
                                          np.asarray(ubs, float))]:
            lb[r] = lo
            ub[r] = hi
        return rows, cols, vals, lb, ub


def new_variables(prog: MathematicalProgram, shape: tuple[int, ...], name: str,
                  binary: bool = False) -> np.ndarray:
    """New variables of ``shape``; returns their indices in ``prog.decision_variables()``."""
    n = int(np.prod(shape, dtype=int))
    start = prog.num_vars()
    if n:
        if binary:
            prog.NewBinaryVariables(n, name)
        else:
            prog.NewContinuousVariables(n, name)
    return (start + np.arange(n)).reshape(shape)


def bound(prog: MathematicalProgram, index: np.ndarray, lb, ub) -> None:
    """Bounding box ``lb ≤ x[index] ≤ ub`` (broadcast) in one constraint."""
    index = np.asarray(index)
    if index.size == 0:
        return
    lb = np.broadcast_to(np.asarray(lb, float), index.shape).ravel()
    ub = np.broadcast_to(np.asarray(ub, float), index.shape).ravel()
    prog.AddBoundingBoxConstraint(lb, ub, prog.decision_variables()[index.ravel()])
