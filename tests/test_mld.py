"""Tests for model.mld: re-simulation by hand, the constraint checker, sound reachability."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualarm_mpc.model.mld import (
    Model,
    Rect,
    State,
    crowding,
    hand_reach,
    reachability,
    replay,
    standing,
    violations,
)
from dualarm_mpc.model.plan import Trajectory

PROPERTY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def model(
    n: int = 1,
    dt: float = 1.0,
    v_max: float = 0.2,
    u_max: float = 0.1,
    workspace=(-0.9, 0.9, 0.0, 0.9),
    goals=None,
    half: float = 0.05,
) -> Model:
    goals = goals or [(0.2, 0.4, 0.5, 0.7)] * n
    return Model(
        dt=dt,
        v_max=v_max,
        u_max=u_max,
        hand_gap=0.1,
        workspace=Rect.of(list(workspace)),
        goals=tuple(Rect.of(list(g)) for g in goals),
        grasp_half=np.full(n, half),
    )


def state(
    hands=((0.1, 0.0), (-0.1, 0.0)),
    objects=((0.1, 0.1),),
    hand_vel=None,
    object_vel=None,
    grasp=None,
) -> State:
    n = len(objects)
    return State(
        hand_pos=np.array(hands, float),
        hand_vel=np.zeros((2, 2)) if hand_vel is None else np.array(hand_vel, float),
        object_pos=np.array(objects, float),
        object_vel=np.zeros((n, 2)) if object_vel is None else np.array(object_vel, float),
        grasp=np.zeros((2, n), int) if grasp is None else np.array(grasp, int),
    )


def no_grasp(K: int, n: int = 1) -> np.ndarray:
    return np.zeros((K + 1, 2, n), int)


# --- replay ---------------------------------------------------------------------------------


def test_double_integrator_by_hand() -> None:
    m = model(dt=0.5)
    s = state(hand_vel=[[0.02, 0.0], [0.0, -0.04]])
    force = np.zeros((3, 2, 2))
    force[0, 0] = [0.1, 0.05]
    force[1, 0] = [-0.1, 0.0]
    force[2, 1] = [0.0, 0.08]
    t = replay(m, s, force, no_grasp(3))
    # arm 1: v = 0.02,0 → 0.07,0.025 → 0.02,0.025 → same; p += 0.5·v of the step before
    np.testing.assert_allclose(
        t.hand_vel[:, 0], [[0.02, 0], [0.07, 0.025], [0.02, 0.025], [0.02, 0.025]]
    )
    np.testing.assert_allclose(
        t.hand_pos[:, 0], [[0.1, 0], [0.11, 0], [0.145, 0.0125], [0.155, 0.025]]
    )
    # arm 2: v = 0,-0.04 until the last force: 0,0
    np.testing.assert_allclose(t.hand_vel[:, 1], [[0, -0.04], [0, -0.04], [0, -0.04], [0, 0]])
    np.testing.assert_allclose(
        t.hand_pos[:, 1], [[-0.1, 0], [-0.1, -0.02], [-0.1, -0.04], [-0.1, -0.06]]
    )
    np.testing.assert_array_equal(t.object_pos, np.repeat([[[0.1, 0.1]]], 4, axis=0))
    np.testing.assert_array_equal(t.object_vel, 0.0)
    assert t.steps == 3
    np.testing.assert_array_equal(t.force, force)


def test_held_object_moves_with_the_hand_then_slides_one_step_and_rests() -> None:
    m = model(workspace=(-2, 2, -2, 2))
    s = state(objects=[(0.13, 0.04)])  # within the 0.05 grasp box of hand 1 at (0.1, 0.0)
    K = 8
    force = np.zeros((K, 2, 2))
    force[0, 0] = [0.1, 0.1]
    force[1, 0] = [0.0, 0.1]
    force[3, 0] = [-0.1, 0.0]
    force[6, 0] = [-0.1, -0.2]  # after the release: the object no longer follows the hand
    grasp = no_grasp(K)
    grasp[1:5, 0, 0] = 1  # held at k = 1..4, released at k = 5
    t = replay(m, s, force, grasp)
    offset = t.object_pos[:, 0] - t.hand_pos[:, 0]
    # Grabbed at 1 (both still at their start); the offset is constant through step 5.
    np.testing.assert_allclose(offset[1:6], np.repeat([[0.03, 0.04]], 5, axis=0), atol=1e-12)
    np.testing.assert_allclose(t.object_vel[1:5, 0], t.hand_vel[1:5, 0])
    # Released at 5: slides with the velocity it had at 4 for one step, then rests.
    np.testing.assert_allclose(t.object_vel[5, 0], t.hand_vel[4, 0])
    assert np.abs(t.hand_vel[4, 0]).max() > 0.05  # a real throw
    np.testing.assert_allclose(t.object_pos[6, 0], t.object_pos[5, 0] + t.hand_vel[4, 0])
    np.testing.assert_array_equal(t.object_vel[6:, 0], 0.0)
    np.testing.assert_array_equal(t.object_pos[6:, 0], np.repeat(t.object_pos[6:7, 0], 3, 0))


def test_object_held_at_the_start_and_released_slides_with_its_measured_velocity() -> None:
    m = model(dt=0.5, workspace=(-2, 2, -2, 2))
    s = state(
        objects=[(0.1, 0.0)],
        hand_vel=[[0.1, 0.2], [0, 0]],
        object_vel=[[0.1, 0.2]],
        grasp=[[1], [0]],
    )
    grasp = no_grasp(3)
    grasp[0, 0, 0] = 1  # released at k = 1
    t = replay(m, s, np.zeros((3, 2, 2)), grasp)
    np.testing.assert_allclose(t.object_vel[:, 0], [[0.1, 0.2], [0.1, 0.2], [0, 0], [0, 0]])
    np.testing.assert_allclose(t.object_pos[:, 0], [[0.1, 0], [0.15, 0.1], [0.2, 0.2], [0.2, 0.2]])


def test_handover_keeps_the_object_moving_with_the_new_hand() -> None:
    m = model(workspace=(-2, 2, -2, 2))
    s = state(hands=[(0.1, 0.0), (0.0, 0.0)], objects=[(0.05, 0.0)], hand_vel=[[0, 0], [0, 0.1]])
    grasp = no_grasp(3)
    grasp[1, 0, 0] = 1
    grasp[2:, 1, 0] = 1
    t = replay(m, s, np.zeros((3, 2, 2)), grasp)
    np.testing.assert_allclose(t.object_vel[:, 0], [[0, 0], [0, 0], [0, 0.1], [0, 0.1]])


# --- violations -------------------------------------------------------------------------------


def _valid():
    m = model(n=2, workspace=(-0.9, 0.9, 0.0, 0.9))
    s = state(objects=[(0.12, 0.03), (-0.3, 0.3)])
    K = 4
    force = np.zeros((K, 2, 2))
    force[0, 0] = [0.0, 0.1]
    force[2, 0] = [0.0, -0.1]
    grasp = no_grasp(K, 2)
    grasp[1:3, 0, 0] = 1
    return m, s, force, grasp


def test_a_valid_trajectory_has_no_violations() -> None:
    m, s, force, grasp = _valid()
    assert violations(m, replay(m, s, force, grasp)) == []


@pytest.mark.parametrize(
    ("tamper", "expected"),
    [
        ("force", "|u|"),
        ("speed", "|v_hand|"),
        ("workspace", "workspace"),
        ("gap", "(16)"),
        ("both_hands", "(14)"),
        ("two_objects", "(15)"),
        ("far_grab", "(10)"),
    ],
)
def test_violations_catch_each_constraint(tamper: str, expected: str) -> None:
    m, s, force, grasp = _valid()
    if tamper == "force":
        force[1, 1] = [0.0, 0.11]
    elif tamper == "speed":
        force[0:3, 1] = [-0.1, 0.0]  # arm 2 speeds up to 0.3 > v_max, away from arm 1
    elif tamper == "workspace":
        force[0, 1] = [0.0, -0.1]  # arm 2 goes below y = 0
    elif tamper == "gap":
        s = state(hands=[(0.1, 0.0), (0.05, 0.0)], objects=[(0.12, 0.03), (-0.3, 0.3)])
    elif tamper == "both_hands":
        s = state(hands=[(0.1, 0.0), (-0.0, 0.0)], objects=[(0.05, 0.0), (-0.3, 0.3)])
        force[:] = 0
        grasp[1, :, 0] = 1
    elif tamper == "two_objects":
        s = state(objects=[(0.12, 0.03), (0.08, -0.02)])
        force[:] = 0
        grasp[1, 0, :] = 1
    elif tamper == "far_grab":
        grasp[3, 1, 1] = 1  # arm 2 at (-0.1, 0) grabs object 2 at (-0.3, 0.3)
    problems = violations(m, replay(m, s, force, grasp))
    assert len(problems) == 1 and expected in problems[0], problems


def test_violation_tolerance() -> None:
    m, s, force, grasp = _valid()
    force[1, 1] = [0.0, 0.1 + 1e-7]
    assert violations(m, replay(m, s, force, grasp)) == []


# --- objects that keep apart: (C1)-(C2) --------------------------------------------------------

SPACING = 0.06  # a 5 cm box and 1 cm of clearance


def path(points, held) -> Trajectory:
    """One object's positions (K+1, 2) and when hand 1 holds it (K+1,), velocities as the model
    has them (v(k) = p(k+1) − p(k), Δt = 1); the hands and forces do not matter here."""
    p = np.array(points, float)[:, None]
    grasp = np.zeros((len(p), 2, 1), int)
    grasp[:, 0, 0] = held
    v = np.vstack([np.diff(p, axis=0), np.zeros((1, 1, 2))])
    K = len(p) - 1
    return Trajectory(np.zeros((K + 1, 2, 2)), np.zeros((K + 1, 2, 2)), np.zeros((K, 2, 2)), p, v,
                      grasp)


def boxes(*points) -> tuple[np.ndarray, np.ndarray]:
    return np.array(points, float).reshape(-1, 2), np.array(points, float).reshape(-1, 2)


def test_a_carry_through_a_standing_object_crowds_it_and_a_detour_does_not() -> None:
    m = dataclasses.replace(model(), spacing=SPACING)
    held = [0, 1, 1, 1, 0]
    straight = path([(0.3, 0.1), (0.3, 0.1), (0.3, 0.3), (0.3, 0.5), (0.3, 0.5)], held)
    assert crowding(m, straight, *boxes((0.3, 0.35))) == [(0, 1, 1), (0, 1, 2)]
    # around it: aside below it first, then up along its left (x ≤ 0.3 − 0.06)
    detour = path([(0.3, 0.1), (0.3, 0.1), (0.24, 0.1), (0.24, 0.3), (0.24, 0.5), (0.24, 0.5)],
                  [0, 1, 1, 1, 1, 0])
    assert crowding(m, detour, *boxes((0.3, 0.35))) == []
    # both ends beyond a corner, the straight line between them through the square: crowded
    corner = path([(0.2, 0.35), (0.2, 0.35), (0.3, 0.45), (0.3, 0.45)], [0, 1, 1, 0])
    assert crowding(m, corner, *boxes((0.3, 0.35))) == [(0, 1, 1)]
    # the points of the paper: no spacing, nothing to keep
    assert crowding(model(), straight, *boxes((0.3, 0.35))) == []


def test_crowding_holds_while_held_or_sliding_and_not_at_rest() -> None:
    m = dataclasses.replace(model(), spacing=SPACING)
    other = boxes((0.3, 0.35))
    # released at step 2 (held at 1): the slide over [2, 3] ends beside the other: crowded
    slide = path([(0.3, 0.1), (0.3, 0.1), (0.3, 0.2), (0.3, 0.3), (0.3, 0.3)], [0, 1, 0, 0, 0])
    assert crowding(m, slide, *other) == [(0, 1, 2)]
    # at rest next to it (never held after the first step's fixed segment): nothing to keep
    still = path([(0.3, 0.3), (0.3, 0.3), (0.3, 0.3), (0.3, 0.3)], [0, 0, 0, 0])
    assert crowding(m, still, *other) == []


def test_a_pair_closer_already_may_not_come_closer() -> None:
    m = dataclasses.replace(model(), spacing=SPACING)
    other = boxes((0.3, 0.33))  # 3 cm from where the object is at k = 1
    away = path([(0.3, 0.3), (0.3, 0.3), (0.3, 0.2), (0.3, 0.1)], [0, 1, 1, 0])
    assert crowding(m, away, *other) == []
    closer = path([(0.3, 0.3), (0.3, 0.3), (0.3, 0.31), (0.3, 0.31)], [0, 1, 1, 0])
    assert crowding(m, closer, *other) == [(0, 1, 1), (0, 1, 2)]


def test_two_objects_of_a_step_keep_apart_while_either_moves() -> None:
    m = dataclasses.replace(model(n=2), spacing=SPACING)
    # object 1 carried along y at x = 0.3 past object 2, which rests at (0.33, 0.3)
    p = np.array([[(0.3, 0.1), (0.33, 0.3)], [(0.3, 0.1), (0.33, 0.3)], [(0.3, 0.3), (0.33, 0.3)],
                  [(0.3, 0.5), (0.33, 0.3)], [(0.3, 0.5), (0.33, 0.3)]])
    grasp = np.zeros((5, 2, 2), int)
    grasp[1:4, 0, 0] = 1
    v = np.vstack([np.diff(p, axis=0), np.zeros((1, 2, 2))])
    traj = Trajectory(np.zeros((5, 2, 2)), np.zeros((5, 2, 2)), np.zeros((4, 2, 2)), p, v, grasp)
    assert crowding(m, traj, np.zeros((0, 2)), np.zeros((0, 2))) == [(0, 1, 1), (0, 1, 2)]


def test_an_object_is_not_held_the_step_after_its_release_while_objects_keep_apart() -> None:
    """(C3): released at step 3, it slides over [3, 4]; held again at 4 it breaks (C3), at 5
    it does not; and one sliding now is not held at step 1. Points (no spacing): no (C3)."""
    m, s, force, grasp = _valid()
    force, grasp = np.vstack([force, np.zeros((1, 2, 2))]), np.vstack([grasp, grasp[-1:]])
    apart = dataclasses.replace(m, spacing=SPACING)
    grasp[4, 0, 0] = 1  # held at 1-2, released at 3, held again at 4
    traj = replay(apart, s, force, grasp)
    assert [p for p in violations(apart, traj) if "(C3)" in p] == [
        "(C3): object 1 held at step 4 while it slides"]
    assert not [p for p in violations(m, traj) if "(C3)" in p]
    grasp[4, 0, 0], grasp[5, 0, 0] = 0, 1
    assert not [p for p in violations(apart, replay(apart, s, force, grasp)) if "(C3)" in p]
    sliding = dataclasses.replace(s, object_vel=np.array([[0.1, 0.0], [0.0, 0.0]]))
    once = no_grasp(1, 2)
    once[1, 0, 0] = 1
    assert violations(apart, replay(apart, sliding, np.zeros((1, 2, 2)), once))[-1] == \
        "(C3): object 1 held at step 1 while it slides"


def test_a_sliding_object_outside_the_step_stands_for_its_whole_slide() -> None:
    s = state(objects=[(0.1, 0.1), (0.3, 0.3), (0.5, 0.5)], object_vel=[(0, 0), (0.2, 0), (0, 0)])
    lo, hi = standing(s, [0], dt=1.0)
    np.testing.assert_allclose(lo, [[0.3, 0.3], [0.5, 0.5]])
    np.testing.assert_allclose(hi, [[0.5, 0.3], [0.5, 0.5]])


# --- reachability -----------------------------------------------------------------------------


def test_hand_reach_by_hand() -> None:
    m = model(v_max=0.2, u_max=0.1)
    down, up = hand_reach(m, np.array([0.1, -0.2]), 4)
    # +x: v = 0.1, 0.2, 0.2, 0.2; -x: v = -0.1 → 0.0, 0.1, 0.2 (braking first)
    np.testing.assert_allclose(up[:, 0], [0, 0.1, 0.3, 0.5, 0.7])
    np.testing.assert_allclose(down[:, 0], [0, -0.1, -0.1, 0.0, 0.2])
    np.testing.assert_allclose(up[:, 1], [0, -0.2, -0.3, -0.3, -0.2])
    np.testing.assert_allclose(down[:, 1], [0, 0.2, 0.4, 0.6, 0.8])


def test_reachability_prunes_far_objects_and_goals() -> None:
    m = model(goals=[(0.2, 0.4, 0.7, 0.9)])
    s = state(objects=[(0.1, 0.45)])  # hand 1 at (0.1, 0) needs 0.4 m
    r = reachability(m, s, 10)
    # |v| ≤ 0.2, |u| ≤ 0.1 from rest: displacement 0, 0, 0.1, 0.3, 0.5 → grab box reached at 4
    assert r.first_grab[0, 0] == 4
    assert r.grab_possible()[:4, 0, 0].sum() == 0 and r.grab_possible()[4:, 0, 0].all()
    # from step 4 the object moves ≤ 0.2 per step: needs 0.25 → in the goal from step 6 on
    assert r.first_goal[0] == 6
    assert not r.goal_possible()[:6, 0].any() and r.goal_possible()[6:, 0].all()
    # never: a horizon too short for the grab
    short = reachability(m, s, 3)
    assert short.first_grab[0, 0] == 4 and short.first_goal[0] == 4


@st.composite
def rollouts(draw):
    """A random model, state and force/grasp sequence that obeys the model's constraints."""
    dt = draw(st.sampled_from([0.5, 1.0]))
    v_max = draw(st.sampled_from([0.1, 0.2, 0.5]))
    u_max = draw(st.sampled_from([0.05, 0.1, 0.5]))
    n = draw(st.integers(1, 3))
    K = draw(st.integers(1, 6))
    half = draw(st.sampled_from([0.05, 0.15, 0.3]))
    coord = st.floats(-1, 1, allow_nan=False)
    # Hands far apart in a large workspace, so eq. (16) and the hand range never bind.
    hands = np.array([[3.5, 0.0], [-3.5, 0.0]]) + np.array(
        draw(st.lists(st.tuples(coord, coord), min_size=2, max_size=2))
    )
    speed = st.floats(-v_max, v_max, allow_nan=False)
    hand_vel = np.array(draw(st.lists(st.tuples(speed, speed), min_size=2, max_size=2)))
    objects = np.array(
        [
            hands[draw(st.integers(0, 1))] + np.array(draw(st.tuples(coord, coord))) * 2 * half
            for _ in range(n)
        ]
    )
    object_vel = np.zeros((n, 2))
    grasp0 = np.zeros((2, n), int)
    if draw(st.booleans()):  # hand i holds object 0 at the start
        i = draw(st.integers(0, 1))
        grasp0[i, 0] = 1
        objects[0] = hands[i]
        object_vel[0] = hand_vel[i]
    # Goal boxes around where each object can get to (sometimes around its start).
    reach = v_max * dt * K
    size = st.floats(0.02, 0.3, allow_nan=False)
    goals = []
    for j in range(n):
        cx, cy = objects[j] + np.array(draw(st.tuples(coord, coord))) * reach
        w, h = draw(size), draw(size)
        goals.append((cx - w, cx + w, cy - h, cy + h))
    m = model(
        n=n, dt=dt, v_max=v_max, u_max=u_max, workspace=(-10, 10, -10, 10), goals=goals, half=half
    )
    s = state(hands=hands, objects=objects, hand_vel=hand_vel, object_vel=object_vel, grasp=grasp0)
    force = np.zeros((K, 2, 2))
    grasp = np.zeros((K + 1, 2, n), int)
    grasp[0] = grasp0
    unit = st.floats(-1, 1, allow_nan=False)
    for k in range(1, K + 1):
        # force k-1 within |u| ≤ u_max keeping |v| ≤ v_max
        v = replay(m, s, force[: k - 1], grasp[:k]).hand_vel[-1]
        lo = np.maximum(-u_max, (-v_max - v) / dt)
        hi = np.minimum(u_max, (v_max - v) / dt)
        w = np.array(draw(st.lists(st.tuples(unit, unit), min_size=2, max_size=2)))
        force[k - 1] = lo + (w + 1) / 2 * (hi - lo)
        # positions at k do not depend on grasp[k]: grab only what is inside the box
        now = replay(m, s, force[:k], np.concatenate([grasp[:k], grasp[k - 1 : k] * 0]))
        for i in draw(st.permutations([0, 1])):
            held = np.flatnonzero(grasp[k - 1, i])
            keep = len(held) > 0 and draw(st.booleans())  # carry on more often than not
            wish = int(held[0]) if keep else draw(st.integers(-1, n - 1))
            if wish < 0 or grasp[k, :, wish].any():
                continue
            d = np.abs(now.hand_pos[k, i] - now.object_pos[k, wish]).max()
            if d <= half:
                grasp[k, i, wish] = 1
    return m, s, force, grasp


@PROPERTY
@given(rollouts())
def test_reachability_is_sound(rollout) -> None:
    m, s, force, grasp = rollout
    traj = replay(m, s, force, grasp)
    assert violations(m, traj) == []  # the generator obeys the model
    K = traj.steps
    r = reachability(m, s, K)
    tol = 1e-9
    assert (traj.hand_pos >= r.hand_lo - tol).all() and (traj.hand_pos <= r.hand_hi + tol).all()
    assert (traj.object_pos >= r.object_lo - tol).all()
    assert (traj.object_pos <= r.object_hi + tol).all()
    k = np.arange(K + 1)
    grabbed = traj.grasp.astype(bool)  # (K+1, 2, N)
    assert not (grabbed & (k[:, None, None] < r.first_grab[None])).any(), (
        f"grab before first_grab {r.first_grab}: {np.argwhere(grabbed)}"
    )
    assert (~grabbed | r.grab_possible()).all()
    inside = np.stack(
        [m.goals[j].contains(traj.object_pos[:, j]) for j in range(m.n_objects)], axis=1
    )  # (K+1, N)
    assert not (inside & (k[:, None] < r.first_goal[None])).any(), r.first_goal
    assert (~inside | r.goal_possible()).all()


def test_object_region_contains_start_and_hand_range() -> None:
    m = model(workspace=(-0.9, 0.9, 0.0, 0.9), half=0.05, v_max=0.2)
    region = m.object_region(np.array([[0.0, -0.5]]))
    np.testing.assert_allclose(region.lo, [-1.15, -0.5])
    np.testing.assert_allclose(region.hi, [1.15, 1.15])
