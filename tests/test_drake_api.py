"""The package as a Drake user meets it: ``import dualarm_mpc as dm`` and stock pydrake only.

A scene is loaded with ``dm.load_scenario``, the closed loop built with ``dm.MakeDiagram`` and
put in the user's own Diagram, the hands logged by a stock ``VectorLogSink`` on the Diagram's
named port, the run simulated in lockstep, and the plan's hand trajectory replayed through a stock
``TrajectorySource``. Judged on the plant: the hands follow the plan's trajectory (the plan in
force, read from the named port ``hand_trajectory`` every Δt), the object is carried into its goal
and rests there. Also: the planner as a context manager, and a planner nobody closed does not hold
the interpreter's exit.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import TrajectorySource, VectorLogSink

import dualarm_mpc as dm

# One object on the robot, §V-D's bounds (|v| ≤ 0.2 m/s, |u| ≤ 0.1 m/s²), Δt = 1 s: the right
# hand fetches it from (0.1, 0.1) and carries it into red.
RED = [0.225, 0.575, 0.65, 0.95]
SCENE = {
    "name": "drake_user",
    "workspace": [-0.9, 0.9, -0.3, 0.9],
    "max_speed": 0.2,
    "max_force": 0.1,
    "goals": {"red": RED},
    "objects": [{"name": "box", "position": [0.1, 0.1], "goal": "red"}],
    "rule": 1,
    "m_o": 1,
    "n_o": 1,
    "delivery": "rest",
    "goal_margin": 0.03,
}
DURATION = 8.0  # s: the plan of the first replan is six steps; then the hands hold
# m: the measured hands against the plan's hand trajectory in force. Measured: 0.55 mm at most
# (2 ms plant steps, PD tracking of the interpolator's reference, which is this curve here: the
# hand range and eq. (16) never clamp it on this scene).
HAND_TOLERANCE = 2e-3
# m: the measured object against the plan's object trajectory, a first-order hold (the plan's
# model), while the robot drags it along the hand's cubic, which leaves the chord by at most
# (4/27)·Δt·|Δv| = 14.8 mm at |u| ≤ 0.1 m/s². Measured: 14.7 mm at most.
OBJECT_TOLERANCE = 0.02
TRAJECTORIES = ("hand_trajectory", "object_trajectory", "grasp_schedule")  # the planner's ports


def scenario(**solver) -> dm.Scenario:
    return dm.load_scenario("table1_vc", {**SCENE, "solver": solver} if solver else SCENE)


class Run:
    """The closed loop in the user's Diagram, with stock loggers on the named ports; the plan's
    trajectories in force over each Δt, read from the named ports."""

    def __init__(self) -> None:
        sc = scenario()
        self.dt = sc.robot.dt
        with dm.MakeDiagram(sc) as dual:
            builder = DiagramBuilder()
            station = builder.AddSystem(dual.diagram)
            self.logs = {}
            for name in ("hand_positions", "object_positions", "grasp_state"):
                port = station.GetOutputPort(name)
                self.logs[name] = builder.AddSystem(VectorLogSink(port.size()))
                builder.Connect(port, self.logs[name].get_input_port())
            simulator = Simulator(builder.Build())
            context = simulator.get_mutable_context()
            # (start, end, {port: trajectory}, plan): in force over (start, end] (Drake runs
            # the replan at t at the start of the next AdvanceTo)
            self.in_force = []
            for k in range(1, round(DURATION / self.dt) + 1):
                simulator.AdvanceTo(k * self.dt)
                inner = station.GetMyContextFromRoot(context)
                self.in_force.append((
                    (k - 1) * self.dt, k * self.dt,
                    {name: station.GetOutputPort(name).Eval(inner) for name in TRAJECTORIES},
                    station.GetOutputPort("plan").Eval(inner)))
            self.data = {name: (log.FindLog(context).sample_times(), log.FindLog(context).data())
                         for name, log in self.logs.items()}

    def against_plan(self, name: str, trajectory: str) -> np.ndarray:
        """The largest difference, at each logged sample after t = 0, between the log ``name``
        and the plan in force's ``trajectory``."""
        times, values = self.data[name]
        return np.array([np.abs(drake[trajectory].value(t).ravel() - x).max()
                         for start, end, drake, _ in self.in_force
                         for t, x in zip(times, values.T, strict=True)
                         if start < t <= end + 1e-9])


@pytest.fixture(scope="module")
def run() -> Run:
    return Run()


def test_the_logged_hands_follow_the_plans_hand_trajectory(run: Run) -> None:
    times, hands = run.data["hand_positions"]
    assert hands.shape == (4, len(times)) and times[-1] == pytest.approx(DURATION)
    error = run.against_plan("hand_positions", "hand_trajectory")
    assert len(error) == len(times) - 1  # every sample after t = 0 judged once
    assert error.max() < HAND_TOLERANCE, f"{error.max() * 1e3:.2f} mm off the plan"
    # non-trivial: the right hand went up to the object and carried it 0.5 m; the left waited
    assert np.ptp(hands[1]) > 0.5 and np.ptp(hands[0]) > 0.1
    assert np.ptp(hands[2:], axis=1).max() < 0.01


def test_the_object_is_carried_as_planned_into_its_goal_and_rests(run: Run) -> None:
    times, objects = run.data["object_positions"]
    error = run.against_plan("object_positions", "object_trajectory")
    assert error.max() < OBJECT_TOLERANCE, f"{error.max() * 1e3:.1f} mm off the plan"
    x, y = objects[:, -1]
    assert RED[0] <= x <= RED[1] and RED[2] <= y <= RED[3]
    last = objects[:, times >= DURATION - 0.5]
    assert np.ptp(last, axis=1).max() < 1e-4  # at rest over the last 0.5 s
    # held by the right hand (η_11, the first of 2N = 2 rows) for seconds, let go at the end
    _, grasp = run.data["grasp_state"]
    assert set(np.unique(grasp)) == {0.0, 1.0} and not grasp[1].any()
    assert np.ptp(times[grasp[0] > 0]) > 2.0 and grasp[0, -1] == 0.0
    # as the plan's grasp schedule says, but for a sample at a grasp or release: the gripper
    # acts on the command at its next plant step (2 ms). Measured: one sample.
    assert np.count_nonzero(run.against_plan("grasp_state", "grasp_schedule")) <= 2


def test_the_ports_trajectories_are_the_plan_in_force_as_drake_trajectories(run: Run) -> None:
    for _, _, ports, plan in run.in_force:
        drake = dm.plan_trajectories(plan)
        assert isinstance(drake, dm.PlanTrajectories)
        ours = {"hand_trajectory": drake.hand, "object_trajectory": drake.objects,
                "grasp_schedule": drake.grasp}
        for t in np.linspace(plan.t0 - 1, drake.grasp.end_time() + 1, 23):
            for name, port in ports.items():
                np.testing.assert_array_equal(port.value(t), ours[name].value(t))


def test_the_plans_hand_trajectory_replays_through_a_stock_trajectory_source(run: Run) -> None:
    _, _, ports, plan = max(run.in_force, key=lambda f: len(f[3].trajectory.hand_pos))
    hand = ports["hand_trajectory"]
    knots = plan.trajectory.hand_pos
    assert len(knots) > 3 and plan.t0 == 0.0  # the carry, planned at t = 0
    builder = DiagramBuilder()
    source = builder.AddSystem(TrajectorySource(hand, output_derivative_order=1))
    log = builder.AddSystem(VectorLogSink(8))
    builder.Connect(source.get_output_port(), log.get_input_port())
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(hand.end_time() + 1.0)
    times, values = (log.FindLog(simulator.get_context()).sample_times(),
                     log.FindLog(simulator.get_context()).data())
    assert times[-1] == pytest.approx(hand.end_time() + 1.0)
    for t, x in zip(times, values.T, strict=True):
        np.testing.assert_allclose(x[:4], hand.value(t).ravel(), atol=1e-12)
    velocity, context = hand.derivative(1), source.CreateDefaultContext()
    for k, p in enumerate(knots):  # the planned positions at the plan's steps
        context.SetTime(plan.t0 + k * plan.dt)
        x = source.get_output_port().Eval(context)
        np.testing.assert_allclose(x[:4], p.ravel(), atol=1e-12)
        np.testing.assert_allclose(x[4:], velocity.value(context.get_time()).ravel(), atol=1e-12)
    # beyond the plan: the last planned position, at rest
    np.testing.assert_allclose(values[:, -1], [*knots[-1].ravel(), 0, 0, 0, 0], atol=1e-12)
    # and where the robot's hands were, as they followed it (the plan was in force until 6 s)
    robot_times, robot = run.data["hand_positions"]
    for t in np.arange(0.25, 6.0, 0.5):
        context.SetTime(t)
        sample = np.argmin(np.abs(robot_times - t))
        np.testing.assert_allclose(source.get_output_port().Eval(context)[:4], robot[:, sample],
                                   atol=HAND_TOLERANCE)


def test_the_diagram_exports_its_ports_by_name() -> None:
    sc = scenario()
    with dm.MakeDiagram(sc) as dual:
        ports = {dual.diagram.get_output_port(i).get_name(): dual.diagram.get_output_port(i)
                 for i in range(dual.diagram.num_output_ports())}
    n = sc.n_objects
    sizes = {"measured_state": dm.State.size(n), "hand_positions": 4, "hand_velocities": 4,
             "object_positions": 2 * n, "object_velocities": 2 * n, "grasp_state": 2 * n,
             "robot_state": 12}
    assert {name: ports[name].size() for name in sizes} == sizes
    assert set(ports) == {*sizes, "plan", "replan", "hand_trajectory", "object_trajectory",
                          "grasp_schedule"}


def _waiting_search(searching: threading.Event, stopped: threading.Event):
    """One horizon's solve that never ends by itself: it waits for its interrupt (at most a
    minute, so that a failing test still ends)."""
    def solve(problem, T, options, start=None):
        searching.set()
        for _ in range(6000):
            if options.interrupt.is_set():
                stopped.set()
                break
            time.sleep(0.01)
        raise RuntimeError("the search was stopped")
    return solve


def test_the_planner_as_a_context_manager_stops_its_search() -> None:
    # the first plan, made before the clock starts, waits one solve's time limit at most
    sc = scenario(realtime=True, replan_budget_s=0.05, time_limit_s=0.5)
    searching, stopped = threading.Event(), threading.Event()
    with dm.MpcPlanner(sc, solve=_waiting_search(searching, stopped)) as planner:
        context = planner.CreateDefaultContext()
        state = dm.State(hand_pos=np.array(sc.robot.hand_start), hand_vel=np.zeros((2, 2)),
                         object_pos=np.array([[0.1, 0.1]]), object_vel=np.zeros((1, 2)),
                         grasp=np.zeros((2, 1), int))
        planner.GetInputPort("measured_state").FixValue(context, state.vector())
        planner.GetInputPort("goals").FixValue(context, AbstractValue.Make(SCENE["goals"]))
        simulator = Simulator(planner, context)
        simulator.AdvanceTo(0.5)  # the first replan waited its limit, the search goes on
        assert planner.GetOutputPort("replan").Eval(context).status == "searching"
        assert searching.is_set() and not stopped.is_set()
    assert stopped.wait(60)


UNCLOSED = """
import threading, time
import dualarm_mpc as dm
from pydrake.systems.analysis import Simulator

def solve(problem, T, options, start=None):
    while not options.interrupt.is_set():  # the search never ends unless it is stopped
        time.sleep(0.01)
    raise RuntimeError("stopped")

sc = dm.load_scenario("table1_vc", {scene!r})
dual = dm.MakeDiagram(sc, solve=solve)
simulator = Simulator(dual.diagram)
simulator.AdvanceTo(0.5)
print(dual.diagram.GetOutputPort("replan").Eval(simulator.get_context()).status, flush=True)
"""


def test_a_planner_nobody_closed_does_not_hold_the_exit() -> None:
    """In real time, a search the robot waits for at rest runs on after its replan; the script
    ends without closing the planner, and the interpreter still exits."""
    scene = {**SCENE, "solver": {"realtime": True, "replan_budget_s": 0.05, "time_limit_s": 0.5}}
    script = textwrap.dedent(UNCLOSED).format(scene=scene)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["searching"]


@pytest.mark.parametrize("limit", [-1, float("nan"), 0])
def test_the_planner_refuses_a_time_limit_the_command_line_refuses(limit) -> None:
    with pytest.raises(ValueError, match=f"^time_limit_s: must be a positive number of seconds, "
                                         f"got {limit}$"):
        dm.MpcPlanner(scenario(), time_limit_s=limit)


def _first_replan(measured: np.ndarray, goals) -> None:
    """The planner's first update (t = 0) with ``measured`` and ``goals`` at its ports."""
    sc = scenario()
    with dm.MpcPlanner(sc) as planner:
        context = planner.CreateDefaultContext()
        planner.get_measured_state_input_port().FixValue(context, measured)
        planner.get_goals_input_port().FixValue(context, AbstractValue.Make(goals))
        Simulator(planner, context).AdvanceTo(0.0)


def _measured(**changes) -> np.ndarray:
    sc = scenario()
    state = dm.State(hand_pos=np.array(sc.robot.hand_start, float), hand_vel=np.zeros((2, 2)),
                     object_pos=np.array([[0.1, 0.1]]), object_vel=np.zeros((1, 2)),
                     grasp=np.zeros((2, 1), int))
    for name, value in changes.items():
        getattr(state, name)[np.unravel_index(0, getattr(state, name).shape)] = value
    return state.vector()


@pytest.mark.parametrize(("measured", "goals", "message"), [
    (_measured(object_pos=np.nan), {},
     r"measured_state: object_pos\[0, 0\] is nan, not a finite number"),
    (_measured(hand_vel=np.inf), {},
     r"measured_state: hand_vel\[0, 0\] is inf, not a finite number"),
    (_measured(), {"red": None},
     r"goals: goals.red is missing \(the objects' goals: red\)"),
    (_measured(), {"red": [RED[1], RED[0], RED[2], RED[3]]}, r"goals: goals.red: empty box"),
])
def test_a_bad_value_at_a_port_raises_there_naming_the_field(measured, goals, message) -> None:
    """Not a replan's "error" or "infeasible": the caller's value is wrong, and says where.
    ``goals``: changes to the scenario's (None: left out)."""
    goals = {name: box for name, box in {**scenario().task.goals, **goals}.items()
             if box is not None}
    with pytest.raises(ValueError, match=message):
        _first_replan(measured, goals)
