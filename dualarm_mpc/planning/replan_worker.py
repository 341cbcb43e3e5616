"""Real-time replans (``solver.realtime``): the worker thread a replan's search runs on, and the
wall time a replan may hold the simulation for (its budget). Past the budget the robot follows
the plan in force; a search the robot waits for at rest is carried over to the next periods
(:attr:`ReplanWorker.search`), any other is stopped. The next sequential step, planned ahead
while the current one runs, has a thread of its own, so that it never delays a replan of the
current step. Lockstep replans have no worker: they run in the caller to their end.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass
from typing import Any

from dualarm_mpc.milp.solver import Interrupt
from dualarm_mpc.model.scenario import Scenario

# The share of a control period a replan may hold the simulation for. The plant's own
# simulation of §V-D takes about half of real time, so 0.4 Δt keeps the loop at least real time.
BUDGET_SHARE = 0.4


@dataclass(frozen=True)
class Search:
    """A search carried over to the next periods: its job (given back when it ends), its running
    future, and the interrupt that stops its solves."""

    job: Any
    future: Future
    interrupt: Interrupt


class ReplanWorker:
    """One worker thread (made once) and the budget: ``solver.replan_budget_s``, else
    ``BUDGET_SHARE`` of Δt."""

    def __init__(self, scenario: Scenario) -> None:
        budget = scenario.solver.replan_budget_s
        self.budget_s = BUDGET_SHARE * scenario.robot.dt if budget is None else budget
        self._full_speed_budget_s = self.budget_s
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="mpc-search")
        self._ahead = ThreadPoolExecutor(1, thread_name_prefix="mpc-ahead")
        #: Real time: the search carried over to the next periods, if any.
        self.search: Search | None = None

    def pace(self, rate: float) -> None:
        """The simulation runs at ``rate`` × real time: the budget, the same share of a
        control period, is ``1 / rate`` times the wall time."""
        self.budget_s = self._full_speed_budget_s / rate

    def start(self, solve: Callable[[Any], Any], job: Any) -> Future:
        """``solve(job)`` on the worker."""
        return self._pool.submit(solve, job)

    def start_ahead(self, solve: Callable[[Any], Any], job: Any) -> Future:
        """``solve(job)`` on the plan-ahead thread."""
        return self._ahead.submit(solve, job)

    def within_budget(self, future: Future, budget_s: float | None = None) -> bool:
        """Wait for ``future`` at most the budget (or ``budget_s``): whether it ended."""
        try:
            future.result(timeout=self.budget_s if budget_s is None else budget_s)
        except FutureTimeout:
            return False
        return True

    def carry(self, job: Any, future: Future, interrupt: Interrupt) -> None:
        """Carry the search of ``job`` over to the next periods."""
        self.search = Search(job, future, interrupt)

    def take(self) -> Search:
        """The search carried over, which has ended: no longer carried."""
        search, self.search = self.search, None
        return search

    def abandon(self) -> None:
        """Stop the search carried over, if any."""
        if self.search is not None:
            self.search.interrupt.set()
            self.search = None

    def close(self) -> None:
        """Stop the search carried over, if any, and the worker (the run is over)."""
        self.abandon()
        for pool in (self._pool, self._ahead):
            pool.shutdown(wait=False, cancel_futures=True)
