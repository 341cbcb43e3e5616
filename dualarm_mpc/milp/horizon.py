"""The MILP of one horizon of one sequential step, and its solution.

:class:`HorizonProgram` holds the model of one horizon — the MLD system (``program.py``: eqs. 1,
7–11, 14–16), pruning (§IV-C.2) and cost (17) — built once; a specification (``spec.py``,
encoded by ``encoding.py``) is added per solve. :func:`solve_step` solves the whole step as one
MILP (the monolithic reference); ``search.py`` solves the many narrowed programs of its
skeleton search through the same class.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from dualarm_mpc.logic.ltl import Atom
from dualarm_mpc.milp import program
from dualarm_mpc.milp.backends import solve_standard_form
from dualarm_mpc.milp.encoding import Encoder, EncodingError, Literal
from dualarm_mpc.milp.solver import (
    SolveOptions,
    SolveResult,
    StandardForm,
    Start,
    Status,
    standard_form,
)
from dualarm_mpc.model.mld import Model, Rect, State, in_goal, reachability, replay, standing
from dualarm_mpc.model.plan import Trajectory
from dualarm_mpc.model.route import Order
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import Specification, StepProblem


@dataclass(frozen=True)
class StepResult:
    """The outcome of one solve of one horizon."""

    status: Status
    horizon: int
    trajectory: Trajectory | None  # the step's objects only, as in ``spec.objects``
    cost: float
    solve_time_s: float  # wall time of the solver
    build_time_s: float
    gap: float
    binaries: int
    solution: np.ndarray | None  # raw solver values, for a MIP start
    variables: program.HorizonVariables | None = None
    message: str = ""
    bound: float = 0.0  # the solver's proven lower bound on the cost
    # Of a step's plan (sequential.plan_step): the witness's cost and horizon, where there was
    # one; the horizons below this one, from predictT, that the second prover (solver.prover)
    # proved to have no plan, the search having left them undecided; those neither decided
    # nor given a plan in time; and (horizon, cost) of a shorter horizon's plan that the step
    # passed over, the witness being cheaper (sequential.below_witness).
    witness_cost: float | None = None
    witness_horizon: int | None = None
    proofs: tuple[int, ...] = ()
    undecided: tuple[int, ...] = ()
    passed_over: tuple[int, float] | None = None
    # The pairs of objects whose (C1)–(C2) rows the solve needed (HorizonProgram._solve_apart)
    apart: frozenset[tuple[int, int]] = frozenset()
    # Of the skeleton search: its work (subprograms.SearchStats.record); of a step's plan, the
    # sum over the step's horizons (sequential.plan_step)
    search_stats: dict | None = None

    @property
    def minimal(self) -> bool:
        """Of a step's plan: every horizon below this one, from predictT, was proven to have no
        plan (none passed over, none left undecided)."""
        return self.passed_over is None and not self.undecided

    @classmethod
    def solved(cls, result: SolveResult, horizon: int, build_time_s: float, binaries: int,
               variables: program.HorizonVariables, trajectory: Trajectory | None = None,
               cost: float = np.inf, apart: frozenset[tuple[int, int]] = frozenset()
               ) -> StepResult:
        """A solve of ``horizon``: with its re-simulated ``trajectory`` and its ``cost`` when
        the solver found a solution; ``apart``, the pairs whose (C1)–(C2) rows it needed."""
        return cls(result.status, horizon, trajectory, cost, result.wall_time_s, build_time_s,
                   result.gap, binaries, None if trajectory is None else result.x, variables,
                   result.message, bound=result.bound, apart=apart)

    @classmethod
    def replayed(cls, status: Status, horizon: int, trajectory: Trajectory, cost: float,
                 gap: float = 0.0, apart: frozenset[tuple[int, int]] = frozenset()
                 ) -> StepResult:
        """A plan made by re-simulating forces and grasps, not by a solve (no solver values);
        ``apart``, the pairs whose (C1)–(C2) rows the solves it comes from needed."""
        return cls(status, horizon, trajectory, cost, 0.0, 0.0, gap, 0, None, apart=apart)

    @classmethod
    def no_plan(cls, status: Status, horizon: int, bound: float = 0.0,
                solve_time_s: float = 0.0, binaries: int = 0, message: str = "") -> StepResult:
        """No plan at ``horizon``: ``status`` says why, ``bound`` what is proven."""
        return cls(status, horizon, None, np.inf, solve_time_s, 0.0, np.inf, binaries, None,
                   message=message, bound=bound)


def solve_options(scenario: Scenario, time_limit_s: float | None = None) -> SolveOptions:
    """The options of one solve from the scenario's ``solver:`` settings (``time_limit_s`` in
    place of theirs if given)."""
    s = scenario.solver
    return SolveOptions(time_limit_s=s.time_limit_s if time_limit_s is None else time_limit_s,
                        mip_rel_gap=s.mip_rel_gap, threads=s.threads, backend=s.backend)


def _resolver(spec: Specification, x: program.HorizonVariables, state: State, scenario: Scenario):
    """Atoms of the formulas → program variables (objects outside the step are constants)."""
    local = {j + 1: n for n, j in enumerate(spec.objects)}
    goals = [Rect.of(scenario.task.goals[o.goal]) for o in scenario.task.objects]

    def resolve(atom: Atom, k: int) -> Literal:
        idx = atom.index
        if atom.name == "eta" and len(idx) == 2 and idx[0] in (1, 2):
            i, j = idx
            if j in local:
                return Literal(int(x.eta[k, i - 1, local[j]]))
            if 1 <= j <= len(goals):
                return Literal(-1, constant=False)  # an object outside the step is not grabbed
        if atom.name == "theta" and len(idx) == 1:
            (j,) = idx
            if j in local:
                return Literal(int(x.theta[k, local[j]]), geometric=True)
            if 1 <= j <= len(goals):
                return Literal(-1, geometric=True,
                               constant=bool(in_goal(state.object_pos[j - 1], goals[j - 1])))
        raise EncodingError(
            f"unknown atom {atom}: the atoms are eta[i,j] (hand i = 1 right, 2 left, grabs "
            f"object j) and theta[j] (object j in its goal), j = 1..{len(goals)}"
        )

    return resolve


class HorizonProgram:
    """The MILP of one horizon over one step's objects, before its specification.

    The model (eqs. 1, 7–11, 14–16), pruning and cost (17) are built once as a
    MathematicalProgram and read into a standard form; :meth:`solve` adds a specification (only
    its LTL rows are encoded anew, over the same variables) and the skeleton search's
    restrictions as bounds and rows. The monolithic solve and every program of the skeleton
    search (``search.py``) go through it."""

    def __init__(self, scenario: Scenario, state: State, objects: list[int], horizon: int,
                 pruning: bool | None = None, hands_anywhere: bool = False,
                 apart: bool = True) -> None:
        self.scenario, self.state, self.horizon = scenario, state, horizon
        self.objects = list(objects)
        self.model = Model.from_scenario(scenario, self.objects)
        self.local_state = state.select(self.objects)
        # hands_anywhere: the hands start anywhere in their range, with state's velocities (for
        # feasibility: solve's trajectory still replays from state's positions)
        reach = reachability(self.model, self.local_state, horizon, hands_anywhere)
        self.prog = MathematicalProgram()
        x = self.x = program.new_horizon_variables(self.prog, horizon, len(self.objects))
        pruning = scenario.task.pruning if pruning is None else pruning
        program.add_bounds(self.prog, x, self.model, self.local_state, reach, pruning)
        program.add_dynamics(self.prog, x, self.model)
        program.add_picking(self.prog, x, self.model, self.local_state, reach)
        program.add_system_constraints(self.prog, x, self.model)
        program.add_goal_atoms(self.prog, x, self.model, reach)
        # apart: the objects keep their spacing, (C1)-(C2), if the scenario gives them one
        self.apart = None
        if apart and self.model.spacing is not None:
            self.apart = program.clearance(x, self.model, self.local_state, reach,
                                           *standing(state, self.objects, self.model.dt))
            program.add_settling(self.prog, x, self.local_state)
        self._hand_cost = program.add_cost(self.prog, x, scenario.task.state_weight)
        self._forms: dict[Specification, StandardForm] = {}

    @functools.cached_property
    def form(self) -> StandardForm:
        """The model in standard form (read once; every backend solves standard forms)."""
        return standard_form(self.prog)

    def encode(self, prog: MathematicalProgram, spec: Specification) -> None:
        """Add ``spec`` (φ_task and the rules) to ``prog``, whose first variables are ours."""
        self._encoder(prog, spec).emit("LTL specification")

    def _encoder(self, prog: MathematicalProgram, spec: Specification) -> Encoder:
        """``spec`` encoded over ``prog``'s variables (not yet added to it)."""
        enc = Encoder(prog, self.horizon, _resolver(spec, self.x, self.state, self.scenario))
        if spec.task_form == "counting":
            enc.require_at_least(spec.m_o, spec.events)
        else:
            enc.require(spec.task())
        for _, rule in spec.rules:
            enc.require(rule)
        return enc

    def program(self, spec: Specification) -> MathematicalProgram:
        """The whole MILP of ``spec`` as one MathematicalProgram."""
        prog = self.prog.Clone()
        self.encode(prog, spec)
        return prog

    def _specified(self, spec: Specification) -> StandardForm:
        """The model with ``spec``'s rows, encoded once per specification: the search solves
        the same one many times (a probe, then its exact solve; one per hand assignment)."""
        if spec not in self._forms:
            ltl = self._encoder(self.prog, spec).standard_form()
            self._forms[spec] = self.form.extended(ltl)
        return self._forms[spec]

    def standard_form(self, spec: Specification, allowed: np.ndarray | None = None,
                      hands: tuple[int, ...] = (0, 1), grasp: np.ndarray | None = None,
                      floor: np.ndarray | None = None, orders: tuple[Order, ...] = (),
                      relaxed: bool = False, apart: set[tuple[int, int]] | None = None
                      ) -> StandardForm:
        """The MILP of ``spec`` in standard form, narrowed for the skeleton search:

        * ``allowed`` (2, n_step): η_ij(k ≥ 1) = 0 where false (which hand may hold what);
        * ``hands``: only these hands' force is costed (alone, the other hand moves for free,
          out of the way of eq. 16: a relaxation);
        * ``grasp`` (T+1, 2, n_step): every η fixed;
        * ``floor`` (2,): proven lower bounds on each costed hand's Σ_k ‖u_i(k)‖₁ as rows,
          which lift the LP bound (otherwise near zero);
        * ``orders`` (``route.Order``, one per hand at most): each hand grabs the objects of
          its order in that order — η_ij(k) ≤ Σ_{k' < k} η_ij'(k') for j' the one before j —
          and none before its route allows (η_ij(k) = 0, θ_j(k) = 0 there), nor first
          grabbed after its latest step (``Order.latest``: Σ_{k ≤ latest} η_ij(k) ≥ 1);
        * ``relaxed``: a relaxation of the programs in which the step's objects it never moves
          may move: (C1)–(C2) hold only between objects it may move and the standing ones;
        * ``apart``: the pairs whose (C1)–(C2) rows it has, of those it keeps apart (all by
          default: the whole program; :meth:`solve` adds them as its solutions need them)."""
        f = self._narrowed(spec, allowed, hands, grasp, floor, orders)
        pairs = self._kept_apart(f, relaxed)
        return self._with_apart(f, pairs if apart is None else pairs & apart)

    def _narrowed(self, spec: Specification, allowed: np.ndarray | None = None,
                  hands: tuple[int, ...] = (0, 1), grasp: np.ndarray | None = None,
                  floor: np.ndarray | None = None, orders: tuple[Order, ...] = ()
                  ) -> StandardForm:
        """:meth:`standard_form` without (C1)–(C2)."""
        f = self._specified(spec)
        f = dataclasses.replace(f, c=f.c.copy(), col_lb=f.col_lb.copy(), col_ub=f.col_ub.copy())
        f.c[: len(self._hand_cost[0])] = sum(self._hand_cost[i] for i in hands)
        eta = self.x.eta
        if allowed is not None:
            keep = np.broadcast_to(np.asarray(allowed, bool)[None], eta[1:].shape)
            f.col_ub[eta[1:][~keep]] = 0.0
        if grasp is not None:
            f.col_lb[eta] = f.col_ub[eta] = np.asarray(grasp, float)
        if floor is not None:
            for i in hands:
                if floor[i] > 0:
                    f = f.with_row(self.x.force_abs[:, i].ravel(), lb=float(floor[i]))
        for order in orders:
            f = self._ordered(f, order)
        return f

    def _kept_apart(self, f: StandardForm, relaxed: bool) -> set[tuple[int, int]]:
        """The pairs (j, o) the narrowed program ``f`` keeps apart, (C1)–(C2): all, or in a
        relaxation those of an object it may move and one it may move or a standing one (an
        object of the step it holds still may move in the programs it bounds)."""
        if self.apart is None:
            return set()
        pairs = self.apart.pairs()
        if not relaxed:
            return pairs
        n = len(self.objects)
        moves = (self.state.grasp[:, self.objects].any(axis=0)
                 | (f.col_ub[self.x.eta[1:]] > 0).any(axis=(0, 1)))
        return {(j, o) for j, o in pairs if moves[j] and (o >= n or moves[o])}

    def _with_apart(self, f: StandardForm, pairs: set[tuple[int, int]]) -> StandardForm:
        """``f`` with the (C1)–(C2) rows of ``pairs`` and their side binaries."""
        if not pairs:
            return f
        A, lb, ub, sides = self.apart.rows(self.x, pairs, len(f.c))
        n = A.shape[1]
        col_lb, col_ub = np.full(n, -np.inf), np.full(n, np.inf)
        col_lb[len(f.c):], col_ub[len(f.c):] = 0.0, sides
        integer = np.arange(n) >= len(f.c)
        return f.extended(StandardForm(np.zeros(n), 0.0, A, lb, ub, col_lb, col_ub, integer))

    def _ordered(self, f: StandardForm, order: Order) -> StandardForm:
        eta = self.x.eta[:, order.hand]
        rows, cols, vals, lb, ub, m = [], [], [], [], [], 0
        for n, grab, goal, latest in zip(order.objects, order.grab, order.goal,
                                         order.latest(self.horizon), strict=True):
            f.col_ub[eta[:grab, n]] = 0.0
            f.col_ub[self.x.theta[:goal, n]] = 0.0
            # row m: Σ_{grab ≤ k ≤ latest} η(k) ≥ 1, grabbed in time for the rest of the route
            span = eta[max(grab, 1):latest + 1, n]
            rows += [m] * len(span)
            cols += list(span)
            vals += [1.0] * len(span)
            lb.append(1.0)
            ub.append(np.inf)
            m += 1
        first_grab = dict(zip(order.objects, order.grab, strict=True))
        for before, after in itertools.pairwise(order.objects):
            # row m: η_after(k) − Σ_{k'<k} η_before(k') ≤ 0; before its grab step η_after is 0
            for k in range(max(first_grab[after], 1), self.horizon + 1):
                rows += [m] * k
                cols += [eta[k, after], *eta[1:k, before]]
                vals += [1.0] + [-1.0] * (k - 1)
                lb.append(-np.inf)
                ub.append(0.0)
                m += 1
        a = sp.csr_matrix((vals, (rows, cols)), shape=(m, len(f.c)))
        return f.with_rows(a, np.array(lb), np.array(ub))

    def solve(self, spec: Specification, options: SolveOptions,
              start: Callable[[program.HorizonVariables], Start] | None = None,
              relaxed: bool = False, apart: frozenset[tuple[int, int]] = frozenset(),
              **narrow) -> StepResult:
        """Solve ``spec`` (narrowed as in :meth:`standard_form`, with the (C1)–(C2) rows its
        solutions need, from those of the pairs ``apart`` on: :meth:`!_solve_apart`); the
        trajectory is re-simulated from the solver's forces and grasps through the model (so
        it is exactly the model's, not the solver's rounding). The cost is that of the costed
        hands."""
        x = self.x
        t0 = time.perf_counter()
        f = self._narrowed(spec, **narrow)
        build = time.perf_counter() - t0
        pairs = self._kept_apart(f, relaxed)
        result, needed = self._solve_apart(f, pairs, pairs & apart, options,
                                           start(x) if start else None)
        binaries = int(x.binaries.size)
        if not result.status.has_solution:
            return StepResult.solved(result, self.horizon, build, binaries, x, apart=needed)
        result = dataclasses.replace(result, x=result.x[: len(f.c)])  # f's columns: a MIP start
        force = result.x[x.force]
        traj = replay(self.model, self.local_state, force, np.round(result.x[x.eta]).astype(int))
        cost = float(np.abs(force[:, list(narrow.get("hands", (0, 1)))]).sum())
        return StepResult.solved(result, self.horizon, build, binaries, x, traj, cost, needed)

    def _solve_apart(self, f: StandardForm, pairs: set[tuple[int, int]],
                     active: set[tuple[int, int]], options: SolveOptions, start: Start | None
                     ) -> tuple[SolveResult, frozenset[tuple[int, int]]]:
        """``f`` with the (C1)–(C2) rows of ``pairs`` it needs, and those pairs: solved with
        the rows of ``active`` first, then with those of every pair its solution breaks too,
        until none does (each round a relaxation of the next: an infeasible round or its bound
        holds for the whole). The rows of pairs a plan keeps apart anyway stay out of the
        program, which would otherwise carry four binaries per pair, object and step
        (docs/formulation.md, "Objects that keep apart"). Within ``options``' time limit over
        all rounds; the wall time is their sum."""
        wall, deadline = 0.0, time.perf_counter() + options.time_limit_s
        if active and isinstance(start, np.ndarray):  # the columns of f: a partial start
            start = (np.arange(len(start)), start)
        while True:
            result = solve_standard_form(self._with_apart(f, active), options, start)
            wall += result.wall_time_s
            broken = (self.apart.broken(self.x, result.x, pairs - active)
                      if pairs and result.status.has_solution else set())
            if not broken:
                return dataclasses.replace(result, wall_time_s=wall), frozenset(active)
            active = active | broken
            start = None  # it breaks the rows added
            left = deadline - time.perf_counter()
            stop = options.interrupt is not None and options.interrupt.is_set()
            if left <= 0 or stop:  # no time for the next round: undecided
                return dataclasses.replace(result, status=Status.TIME_LIMIT, x=None,
                                           objective=np.inf, gap=np.inf,
                                           wall_time_s=wall), frozenset(active)


def build_program(problem: StepProblem, horizon: int, pruning: bool | None = None):
    """The MILP of one horizon as one MathematicalProgram: model, specification, cost.
    ``problem.state`` covers all objects. Returns the program, its variables, model and local
    state."""
    h = HorizonProgram(problem.scenario, problem.state, list(problem.spec.objects), horizon,
                       pruning)
    return h.program(problem.spec), h.x, h.model, h.local_state


def solve_step(problem: StepProblem, horizon: int, options: SolveOptions | None = None,
               start: Callable[[program.HorizonVariables], Start] | None = None,
               pruning: bool | None = None) -> StepResult:
    """Build and solve the monolithic MILP of one horizon (:meth:`HorizonProgram.solve`).
    ``start(x)`` may give a MIP start for the horizon's variables ``x``."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
    options = options or solve_options(scenario)
    t0 = time.perf_counter()
    h = HorizonProgram(scenario, state, list(spec.objects), horizon, pruning)
    build = time.perf_counter() - t0
    res = h.solve(spec, options, start)
    return dataclasses.replace(res, build_time_s=res.build_time_s + build)
