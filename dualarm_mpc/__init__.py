"""dualarm_mpc: LTL-specified table-top rearrangement with two arms, planned as MILPs and run
receding-horizon in Drake (Katayama et al., "Fast LTL-Based Flexible Planning for Dual-Arm
Manipulation").

The public API is this module's names; every other module path is the package's inside and
may change. ::

    import dualarm_mpc as dm

    scenario = dm.load_scenario("table1_vc", {"rule": 2}, on_robot=True)
    report = dm.check(scenario)          # do the task and the rules admit a plan?
    plan = dm.plan(scenario)             # sequential transportation, verified
    summary = dm.simulate(scenario)      # the closed loop on the robot in Drake

Names load on first use, so ``import dualarm_mpc`` stays light (pydrake loads with the first
name that needs it).
"""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING

try:
    __version__ = version("dualarm_mpc")
except PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"

# public name → the module that defines it
_EXPORTS = {
    "Scenario": "dualarm_mpc.model.scenario",
    "ScenarioError": "dualarm_mpc.model.scenario",
    "LTLSyntaxError": "dualarm_mpc.logic.parser",
    "parse": "dualarm_mpc.logic.parser",
    "Plan": "dualarm_mpc.model.plan",
    "delivered_objects": "dualarm_mpc.model.mld",
    "State": "dualarm_mpc.model.mld",
    "PlanningError": "dualarm_mpc.planning.sequential",
    "Interrupt": "dualarm_mpc.milp.solver",
    "MpcPlanner": "dualarm_mpc.systems.mpc_planner",
    "MakeDiagram": "dualarm_mpc.sim.diagram",
    "plan_trajectories": "dualarm_mpc.systems.trajectories",
    "PlanTrajectories": "dualarm_mpc.systems.trajectories",
    "Summary": "dualarm_mpc.sim.closed_loop",
    "plot_plan": "dualarm_mpc.figures.plan",
    "plan_figure": "dualarm_mpc.figures.plan",
    "plot_timeline": "dualarm_mpc.figures.timeline",
    "timeline_figure": "dualarm_mpc.figures.timeline",
    "RunLog": "dualarm_mpc.sim.closed_loop",
    "knock": "dualarm_mpc.sim.disturbances",
    "move_goal": "dualarm_mpc.sim.disturbances",
    "load_scenario": "dualarm_mpc.model.scenario",
    "on_robot_overrides": "dualarm_mpc.model.scenario",
    "check": "dualarm_mpc.planning.consistency",
    "plan": "dualarm_mpc.planning.task",
    "ConflictError": "dualarm_mpc.planning.task",
    "VerificationError": "dualarm_mpc.planning.task",
    "whole_task": "dualarm_mpc.planning.task",
    "simulate": "dualarm_mpc.sim.closed_loop",
}

__all__ = [
    "__version__",
    "ConflictError",
    "Interrupt",
    "LTLSyntaxError",
    "MakeDiagram",
    "MpcPlanner",
    "Plan",
    "PlanTrajectories",
    "PlanningError",
    "RunLog",
    "Scenario",
    "ScenarioError",
    "State",
    "Summary",
    "VerificationError",
    "check",
    "delivered_objects",
    "knock",
    "move_goal",
    "load_scenario",
    "on_robot_overrides",
    "parse",
    "plan",
    "plan_figure",
    "plan_trajectories",
    "plot_plan",
    "plot_timeline",
    "simulate",
    "timeline_figure",
    "whole_task",
]  # = _EXPORTS (tests/test_api.py)

if TYPE_CHECKING:  # what a type checker and an IDE see; at run time __getattr__ loads them
    from dualarm_mpc.figures.plan import plan_figure, plot_plan
    from dualarm_mpc.figures.timeline import plot_timeline, timeline_figure
    from dualarm_mpc.logic.parser import LTLSyntaxError, parse
    from dualarm_mpc.milp.solver import Interrupt
    from dualarm_mpc.model.mld import State, delivered_objects
    from dualarm_mpc.model.plan import Plan
    from dualarm_mpc.model.scenario import (
        Scenario,
        ScenarioError,
        load_scenario,
        on_robot_overrides,
    )
    from dualarm_mpc.planning.consistency import check
    from dualarm_mpc.planning.sequential import PlanningError
    from dualarm_mpc.planning.task import ConflictError, VerificationError, plan, whole_task
    from dualarm_mpc.sim.closed_loop import RunLog, Summary, simulate
    from dualarm_mpc.sim.diagram import MakeDiagram
    from dualarm_mpc.sim.disturbances import knock, move_goal
    from dualarm_mpc.systems.mpc_planner import MpcPlanner
    from dualarm_mpc.systems.trajectories import PlanTrajectories, plan_trajectories


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'dualarm_mpc' has no attribute {name!r}")
    value = getattr(import_module(_EXPORTS[name]), name)
    globals()[name] = value  # loaded once
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
