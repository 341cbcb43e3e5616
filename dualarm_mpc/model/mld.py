"""The mixed logical dynamical (MLD) model of two hands and N objects (paper §IV-A, docs/model.md).

Pure data and math: the model's parameters and derived bounds, the reachability times used for
pruning (§IV-C.2), and :func:`replay`, which replays forces and grasps through the model. The
MILP in ``program.py`` encodes the same model; :func:`replay` is the independent re-simulation
every plan is checked against.

Model (Δt = ``dt``; arm i = 0 is arm 1, the right arm; objects j):

* hands, eq. (1) as double integrators: ``p⁺ = p + Δt·v``, ``v⁺ = v + Δt·u``;
* objects, the picking model of eq. (8) as docs/model.md explains it (a rigid grasp and a
  one-step slide after release, so that objects can be thrown):

  - held by hand i at k (η_ij(k) = 1): ``v_obj(k) = v_hand_i(k)``;
  - released at k (held at k−1, by no hand at k): ``v_obj(k) = v_obj(k−1)``;
  - otherwise ``v_obj(k) = 0``; always ``p_obj(k+1) = p_obj(k) + Δt·v_obj(k)``.

  At k = 0 the object's velocity is the measured one (the previous step is not part of the horizon).
* η_ij = 1 → hand i inside the box H_ij around object j (eqs. 10–11), one-sided;
* (14) an object is held by at most one hand, (15) a hand holds at most one object,
  (16) ``x_arm2 + gap ≤ x_arm1``;
* with ``object_clearance`` (docs/formulation.md, "Objects that keep apart", (C1)–(C3)), an
  object held or sliding keeps its square clear of every other object's (:func:`crowding`),
  and none is held the step after its release (:func:`violations`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dualarm_mpc.model.plan import Trajectory
from dualarm_mpc.model.scenario import Scenario

N_HANDS = 2
# The vocabulary of goals and delivery, one tolerance per notion (docs/model.md, "What
# "delivered" means"): an object is *in_goal* when its centre lies in its goal box to
# POSITION_TOL, *at_rest* when its speed is at most a rest tolerance, *delivered* when both.
# The model's objects stop exactly (a one-step slide, then v = 0; docs/model.md, "The one-step
# slide"), so the model's rest tolerance is round-off; the plant's objects never stop exactly,
# so the robot's is a speed.
POSITION_TOL = 1e-6  # m: "inside a box" (solver round-off, not physics), model and robot alike
REST_TOL = 1e-6  # m/s: at rest in the model (planner, verifier, sequential transportation)
REST_SPEED = 0.01  # m/s: at rest on the robot (MPC planner, closed loop, summary, benches)
# m: a step's first move, from k = 1 (fixed by the state, which on the robot is measured), keeps
# the objects' spacing (C1) less this. Measured: a slide that ended 0.14 mm short of its plan's
# end point left two objects 59.9 mm apart where the plan had 60.1, and a §V-D replan, whose
# held object was committed to pass on that side, had no plan at any horizon.
FIRST_MOVE_TOL = 0.005


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle (x_1, x_2) × (y_1, y_2) in the paper's notation."""

    lo: np.ndarray  # [xmin, ymin]
    hi: np.ndarray  # [xmax, ymax]

    @staticmethod
    def of(bounds: list[float]) -> Rect:
        xmin, xmax, ymin, ymax = bounds
        return Rect(np.array([xmin, ymin], float), np.array([xmax, ymax], float))

    def contains(self, p: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether each point of ``p`` (…, 2) lies inside (to ``tol``)."""
        p = np.asarray(p)
        return np.all((p >= self.lo - tol) & (p <= self.hi + tol), axis=-1)

    def shrink(self, margin: float) -> Rect:
        """The box with ``margin`` taken off every side."""
        return Rect(self.lo + margin, self.hi - margin)

    def bounds(self) -> list[float]:
        return [float(self.lo[0]), float(self.hi[0]), float(self.lo[1]), float(self.hi[1])]


def in_goal(pos: np.ndarray, box: list[float] | Rect, tol: float = POSITION_TOL) -> np.ndarray:
    """Whether each position of ``pos`` (…, 2) lies in the goal ``box`` ([xmin, xmax, ymin,
    ymax] or a :class:`Rect`), to ``tol``."""
    return (box if isinstance(box, Rect) else Rect.of(box)).contains(pos, tol)


def at_rest(vel: np.ndarray, speed: float = REST_TOL) -> np.ndarray:
    """Whether each velocity of ``vel`` (…, 2 or 3) is at rest: its norm at most ``speed``
    (``REST_TOL`` in the model, ``REST_SPEED`` on the robot)."""
    return np.linalg.norm(np.asarray(vel, float), axis=-1) <= speed


def delivered(pos: np.ndarray, vel: np.ndarray, box: list[float] | Rect,
              speed: float = REST_TOL) -> np.ndarray:
    """At rest (to ``speed``) in its goal ``box``: what "delivered" means everywhere."""
    return in_goal(pos, box) & at_rest(vel, speed)


def delivered_objects(scenario: Scenario, pos: np.ndarray, vel: np.ndarray,
                      speed: float = REST_TOL, goals: dict[str, list[float]] | None = None
                      ) -> np.ndarray:
    """(N,) whether each object, at ``pos`` (N, 2) moving at ``vel`` (N, 2 or 3), is
    :func:`~dualarm_mpc.model.mld.delivered` in its goal (``goals``: the scenario's unless
    given)."""
    goals = scenario.task.goals if goals is None else goals
    return np.array([bool(delivered(pos[j], vel[j], goals[o.goal], speed))
                     for j, o in enumerate(scenario.task.objects)], dtype=bool)


@dataclass(frozen=True)
class State:
    """The MLD state at one step (and the grasps in force), planar: the model's, a plan's, and
    the robot's as measured (:meth:`from_vector`, the StateEstimator's ``measured_state``)."""

    hand_pos: np.ndarray  # (2, 2)
    hand_vel: np.ndarray  # (2, 2)
    object_pos: np.ndarray  # (N, 2)
    object_vel: np.ndarray  # (N, 2)
    grasp: np.ndarray  # (2, N) of 0/1

    @staticmethod
    def initial(scenario: Scenario) -> State:
        n = scenario.n_objects
        return State(
            hand_pos=np.array(scenario.robot.hand_start, float),
            hand_vel=np.zeros((N_HANDS, 2)),
            object_pos=np.array([o.position for o in scenario.task.objects], float),
            object_vel=np.zeros((n, 2)),
            grasp=np.zeros((N_HANDS, n), int),
        )

    @staticmethod
    def at(trajectory: Trajectory, k: int) -> State:
        """The state at step ``k`` of ``trajectory``."""
        t = trajectory
        return State(t.hand_pos[k], t.hand_vel[k], t.object_pos[k], t.object_vel[k], t.grasp[k])

    @staticmethod
    def last(trajectory: Trajectory) -> State:
        return State.at(trajectory, -1)

    def is_still(self) -> bool:
        """Nothing held, and every hand and object at rest."""
        return not self.grasp.any() and at_rest(self.hand_vel).all() and \
            at_rest(self.object_vel).all()

    @staticmethod
    def size(n_objects: int) -> int:
        """The length of :meth:`vector`: 8 + 6N."""
        return 4 * N_HANDS + 6 * n_objects

    def vector(self) -> np.ndarray:
        """The state as one vector: hand_pos (4: x0, y0, x1, y1), hand_vel (4), object_pos (2N:
        x_j, y_j), object_vel (2N), grasp (2N, row-major [i][j])."""
        return np.concatenate([self.hand_pos.ravel(), self.hand_vel.ravel(),
                               self.object_pos.ravel(), self.object_vel.ravel(),
                               np.asarray(self.grasp, float).ravel()])

    @staticmethod
    def from_vector(x: np.ndarray, n_objects: int, where: str = "state vector") -> State:
        """The state of :meth:`vector` ``x`` (copied; the grasps rounded to 0/1). A value that
        is not finite is a ``ValueError`` naming ``where`` and its field (a replan would take a
        NaN position for an object beyond reach)."""
        n = n_objects
        x = np.array(x, dtype=float)
        if x.shape != (State.size(n),):
            raise ValueError(f"{where}: expected {State.size(n)} values, got {x.shape}")
        h = 2 * N_HANDS
        state = State(hand_pos=x[:h].reshape(N_HANDS, 2), hand_vel=x[h:2 * h].reshape(N_HANDS, 2),
                      object_pos=x[2 * h:2 * h + 2 * n].reshape(n, 2),
                      object_vel=x[2 * h + 2 * n:2 * h + 4 * n].reshape(n, 2),
                      grasp=x[2 * h + 4 * n:].reshape(N_HANDS, n))
        for name, value in ((f.name, getattr(state, f.name)) for f in dataclasses.fields(state)):
            bad = np.argwhere(~np.isfinite(value))
            if bad.size:
                raise ValueError(f"{where}: {name}[{', '.join(map(str, bad[0]))}] is "
                                 f"{value[tuple(bad[0])]}, not a finite number")
        return dataclasses.replace(state, grasp=state.grasp.round().astype(int))

    def select(self, objects: list[int]) -> State:
        """The state restricted to the given objects (hands unchanged)."""
        return State(self.hand_pos, self.hand_vel, self.object_pos[objects],
                     self.object_vel[objects], self.grasp[:, objects])


@dataclass(frozen=True)
class Model:
    """Parameters of the MLD system for one set of objects, all from the scenario."""

    dt: float
    v_max: float  # |v| per component, hands (objects move with a hand or slide at its speed)
    u_max: float  # |u| per component
    hand_gap: float  # eq. (16)
    workspace: Rect  # hand range
    goals: tuple[Rect, ...]  # goal box of each object, eq. (12)
    grasp_half: np.ndarray  # (N,) half side of H_ij, eq. (11)
    # (C1): the least distance, per axis, between the centre of an object held or sliding and
    # any other's (the box size plus ``object_clearance``); None: objects are points (the paper)
    spacing: float | None = None

    @property
    def n_objects(self) -> int:
        return len(self.goals)

    @staticmethod
    def from_scenario(scenario: Scenario, objects: list[int] | None = None) -> Model:
        """The model of ``objects`` (scenario indices; all by default)."""
        objects = list(range(scenario.n_objects)) if objects is None else objects
        return Model(
            dt=scenario.robot.dt,
            v_max=scenario.robot.max_speed,
            u_max=scenario.robot.max_force,
            hand_gap=scenario.robot.hand_gap,
            workspace=Rect.of(scenario.robot.workspace),
            goals=tuple(target_box(scenario, j) for j in objects),
            grasp_half=np.array([scenario.task.objects[j].grasp_half_size for j in objects], float),
            spacing=(None if scenario.task.object_clearance is None
                     else scenario.table.object_size + scenario.task.object_clearance),
        )

    def object_region(self, start: np.ndarray) -> Rect:
        """Where objects can ever be: where they start, or within a hand's reach of the hand range
        plus one slide step (docs/model.md). Every object big-M derives from this box."""
        reach = self.grasp_half.max(initial=0.0) + self.v_max * self.dt
        lo = np.minimum(self.workspace.lo - reach, np.min(start, axis=0, initial=np.inf))
        hi = np.maximum(self.workspace.hi + reach, np.max(start, axis=0, initial=-np.inf))
        return Rect(lo, hi)


def target_box(scenario: Scenario, j: int) -> Rect:
    """Where the planner aims object j: its goal box less ``goal_margin``; with ``goal_slots``,
    only the j-th of side-by-side columns of the goal, one per object of that goal, so that
    objects thrown later do not run into those already delivered."""
    goal = scenario.task.objects[j].goal
    box = Rect.of(scenario.task.goals[goal])
    if scenario.task.goal_slots:
        sharing = [n for n, o in enumerate(scenario.task.objects) if o.goal == goal]
        width = (box.hi[0] - box.lo[0]) / len(sharing)
        x0 = box.lo[0] + width * sharing.index(j)
        box = Rect(np.array([x0, box.lo[1]]), np.array([x0 + width, box.hi[1]]))
    return box.shrink(scenario.task.goal_margin)


# --- reachability (pruning, §IV-C.2) ------------------------------------------------------------


def hand_reach(model: Model, v0: np.ndarray, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Per step k = 0..T, the largest displacement of a hand starting with velocity ``v0`` (2,),
    in the negative and in the positive direction of each axis: (T+1, 2) each.

    With |v| ≤ v_max and |u| ≤ u_max per component, v(t) ≤ min(v_max, v0 + t·Δt·u_max)."""
    t = np.arange(horizon)[:, None]
    up = np.minimum(model.v_max, v0 + t * model.dt * model.u_max) * model.dt
    down = np.minimum(model.v_max, -v0 + t * model.dt * model.u_max) * model.dt
    zero = np.zeros((1, 2))
    return np.vstack([zero, np.cumsum(down, 0)]), np.vstack([zero, np.cumsum(up, 0)])


@dataclass(frozen=True)
class Reach:
    """Sound per-step boxes for hands and objects, and the earliest steps η and θ can be 1."""

    hand_lo: np.ndarray  # (T+1, 2, 2)
    hand_hi: np.ndarray
    object_lo: np.ndarray  # (T+1, N, 2)
    object_hi: np.ndarray
    first_grab: np.ndarray  # (2, N): earliest k with η_ij(k) = 1 possible (T+1 = never)
    first_goal: np.ndarray  # (N,): earliest k with θ_j(k) = 1 possible

    def grab_possible(self) -> np.ndarray:
        """(T+1, 2, N) mask of the η that pruning keeps."""
        k = np.arange(len(self.hand_lo))[:, None, None]
        return k >= self.first_grab[None]

    def goal_possible(self) -> np.ndarray:
        """(T+1, N) mask of the θ that pruning keeps."""
        return np.arange(len(self.hand_lo))[:, None] >= self.first_goal[None]


def reachability(model: Model, state: State, horizon: int,
                 hands_anywhere: bool = False) -> Reach:
    """Reachable boxes from straight-line motion at bounded speed and force (§IV-C.2).

    An object moves only once a hand holds it (or by its measured velocity in the first step), so
    before its earliest possible grab it stays put; afterwards it moves at most v_max·Δt per step.
    Hand i can hold object j at k only if its reachable box, widened by H_ij, meets the object's.
    ``hands_anywhere``: the hands may start anywhere in their range (``state``'s hand positions
    ignored), so every hand box is the whole range."""
    T = horizon
    n = model.n_objects
    ws = model.workspace
    hand_lo = np.empty((T + 1, N_HANDS, 2))
    hand_hi = np.empty((T + 1, N_HANDS, 2))
    for i in range(N_HANDS):
        down, up = hand_reach(model, state.hand_vel[i], T)
        hand_lo[:, i] = np.maximum(state.hand_pos[i] - down, ws.lo)
        hand_hi[:, i] = np.minimum(state.hand_pos[i] + up, ws.hi)
    if hands_anywhere:
        hand_lo[:], hand_hi[:] = ws.lo, ws.hi
    half = model.grasp_half
    p0 = state.object_pos
    # Step 0's velocity is measured; it carries the object into step 1.
    p1 = p0 + model.dt * state.object_vel
    held = state.grasp.any(axis=0)
    first_grab = np.full((N_HANDS, n), T + 1)
    for i in range(N_HANDS):
        for j in range(n):
            if state.grasp[i, j]:
                first_grab[i, j] = 0
                continue
            # The object is static at p1 from k = 1 until some hand grabs it.
            for k in range(1, T + 1):
                if meet(hand_lo[k, i], hand_hi[k, i], p1[j] - half[j], p1[j] + half[j]):
                    first_grab[i, j] = k
                    break
    start = np.where(held, 0, first_grab.min(axis=0))  # (N,) earliest step an object can move
    k = np.arange(T + 1)[:, None]
    moves = np.clip(k - np.maximum(start, 1)[None], 0, None) * model.v_max * model.dt  # (T+1, N)
    region = model.object_region(p0)
    obj_lo = np.where(k[..., None] == 0, p0[None], p1[None] - moves[..., None])
    obj_hi = np.where(k[..., None] == 0, p0[None], p1[None] + moves[..., None])
    # A sliding object (measured velocity) may be carried past the region in step 0.
    obj_lo = np.maximum(obj_lo, np.minimum(region.lo, np.minimum(p0, p1)))
    obj_hi = np.minimum(obj_hi, np.maximum(region.hi, np.maximum(p0, p1)))
    # With the object's motion bounded, a second pass catches grabs of an object moved by the other
    # hand (rule 2 allows put-down and pick-up by the other arm).
    for i in range(N_HANDS):
        for j in range(n):
            if first_grab[i, j] == 0:
                continue
            for kk in range(1, T + 1):
                if meet(hand_lo[kk, i], hand_hi[kk, i], obj_lo[kk, j] - half[j],
                         obj_hi[kk, j] + half[j]):
                    first_grab[i, j] = min(first_grab[i, j], kk)
                    break
    first_goal = np.full(n, T + 1)
    for j in range(n):
        g = model.goals[j]
        for kk in range(T + 1):
            if meet(obj_lo[kk, j], obj_hi[kk, j], g.lo, g.hi):
                first_goal[j] = kk
                break
    return Reach(hand_lo, hand_hi, obj_lo, obj_hi, first_grab, first_goal)


def meet(lo1, hi1, lo2, hi2) -> bool:
    """Whether the boxes [lo1, hi1] and [lo2, hi2] meet (touching counts)."""
    return bool(np.all(lo1 <= hi2 + 1e-12) and np.all(lo2 <= hi1 + 1e-12))


# --- re-simulation --------------------------------------------------------------------------------


def replay(model: Model, state: State, force: np.ndarray, grasp: np.ndarray) -> Trajectory:
    """Replay ``force`` (K, 2, 2) and ``grasp`` (K+1, 2, N) through the model from ``state``.

    ``grasp[0]`` must equal ``state.grasp``. This is the reference semantics of the picking model;
    it shares no code with the MILP encoding."""
    K = len(force)
    n = model.n_objects
    dt = model.dt
    hp = np.empty((K + 1, N_HANDS, 2))
    hv = np.empty((K + 1, N_HANDS, 2))
    op = np.empty((K + 1, n, 2))
    ov = np.empty((K + 1, n, 2))
    hp[0], hv[0], op[0], ov[0] = state.hand_pos, state.hand_vel, state.object_pos, state.object_vel
    for k in range(K + 1):
        if k > 0:
            hp[k] = hp[k - 1] + dt * hv[k - 1]
            hv[k] = hv[k - 1] + dt * force[k - 1]
            op[k] = op[k - 1] + dt * ov[k - 1]
            for j in range(n):
                holder = np.flatnonzero(grasp[k, :, j])
                if len(holder):
                    ov[k, j] = hv[k, holder[0]]
                elif grasp[k - 1, :, j].any():
                    ov[k, j] = ov[k - 1, j]  # released: slides one step
                else:
                    ov[k, j] = 0.0
    return Trajectory(hp, hv, np.asarray(force, float), op, ov, np.asarray(grasp, int))


def violations(model: Model, traj: Trajectory, tol: float = 1e-5) -> list[str]:
    """Every way ``traj`` breaks the model's constraints (bounds, eqs. 10–11, 14–16; with the
    objects' spacing, (C3): no object held the step after its release)."""
    out = []
    g = traj.grasp
    if np.abs(traj.force).max(initial=0) > model.u_max + tol:
        out.append(f"|u| exceeds u_max = {model.u_max}")
    if np.abs(traj.hand_vel).max(initial=0) > model.v_max + tol:
        out.append(f"|v_hand| exceeds v_max = {model.v_max}")
    if not model.workspace.contains(traj.hand_pos, tol).all():
        out.append("a hand leaves the workspace")
    gap = traj.hand_pos[:, 0, 0] - traj.hand_pos[:, 1, 0]
    if (gap < model.hand_gap - tol).any():
        k = int(np.argmax(gap < model.hand_gap - tol))
        out.append(f"eq. (16) broken at step {k}: x_arm1 - x_arm2 = {gap[k]:.4f}")
    if (g.sum(axis=1) > 1).any():
        out.append("eq. (14): an object held by both hands")
    if (g.sum(axis=2) > 1).any():
        out.append("eq. (15): a hand holds two objects")
    for k, i, j in zip(*np.nonzero(g[1:]), strict=True):
        d = np.abs(traj.hand_pos[k + 1, i] - traj.object_pos[k + 1, j]).max()
        if d > model.grasp_half[j] + tol:
            out.append(f"eq. (10): hand {i + 1} grabs object {j + 1} at step {k + 1} "
                       f"from {d:.3f} m")
    if model.spacing is not None:  # (C3): no object held the step after its release
        held = g.any(axis=1)
        slid = np.vstack([~held[0] & (np.abs(traj.object_vel[0]).max(axis=-1) > 0),
                          held[:-1] & ~held[1:]])  # (K+1, N): sliding over [k, k+1]
        for k, j in zip(*np.nonzero(slid[:-1] & held[1:]), strict=True):
            out.append(f"(C3): object {j + 1} held at step {k + 1} while it slides")
    return out


# --- objects that keep apart (docs/formulation.md, (C1)–(C2)) -----------------------------------


def standing(state: State, objects: list[int], dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The objects outside ``objects`` as obstacles of a step: for each, the box (lo, hi), each
    (M, 2), spanned by where it is and where its slide under way ends (Δt·v on): the model keeps
    it there for the step (``sequential.embed_step``), the robot lets it slide there."""
    rest = [j for j in range(len(state.object_pos)) if j not in set(objects)]
    here = state.object_pos[rest]
    there = here + dt * state.object_vel[rest]
    return np.minimum(here, there), np.maximum(here, there)


def crowding(model: Model, traj: Trajectory, standing_lo: np.ndarray, standing_hi: np.ndarray,
             tol: float = 1e-6) -> list[tuple[int, int, int]]:
    """Every way ``traj`` (one step, its N objects) breaks (C1)–(C2), as (j, o, k): over step k
    (k ≥ 1) object j of the step, held or sliding (held at k or at k − 1), comes within
    ``spacing`` of object o of the step, or of standing box o − N (``standing_lo/hi``, as
    :func:`standing` gives them), o ≥ N. It keeps clear when its centre's straight path from k
    to k + 1 and the other's lie on one side of a line at ``spacing`` from each other: along
    some axis the two stay that far apart, at both ends. A pair closer already where the step's
    first move can begin (k = 1, fixed by the state) keeps that distance instead: it may not
    shrink; none if it is inside the other's box there. The first move (k = 1) keeps the
    spacing less ``FIRST_MOVE_TOL``. Empty without a ``spacing``; written apart from the rows
    of ``program.py``."""
    if model.spacing is None or traj.steps < 2:
        return []
    held = traj.grasp.any(axis=1)  # (K+1, N)
    moving = held[1:-1] | held[:-2]  # (K-1, N): over [k, k+1], k = 1..K-1
    p = traj.object_pos
    n = p.shape[1]
    boxes = [(p[:, o], p[:, o]) for o in range(n)]  # another object of the step: a point
    boxes += [(np.broadcast_to(lo, p[:, 0].shape), np.broadcast_to(hi, p[:, 0].shape))
              for lo, hi in zip(standing_lo, standing_hi, strict=True)]

    def gaps(k: int, j: int, o: int) -> np.ndarray:
        """How far object j's centre lies beyond box o at step k, along +x, −x, +y, −y."""
        a, (lo, hi) = p[k, j], (boxes[o][0][k], boxes[o][1][k])
        return np.array([a[0] - hi[0], lo[0] - a[0], a[1] - hi[1], lo[1] - a[1]])

    out = []
    for j in range(n):
        for o in range(j + 1, len(boxes)):
            spacing = min(model.spacing, gaps(1, j, o).max())
            if spacing <= 0:  # j starts inside it (a standing box spans a slide): no side
                continue
            steps = moving[:, j] | (moving[:, o] if o < n else False)
            for k in np.flatnonzero(steps) + 1:
                keep = spacing - (FIRST_MOVE_TOL if k == 1 else 0.0)
                if keep > 0 and not np.any((gaps(k, j, o) >= keep - tol)
                                           & (gaps(k + 1, j, o) >= keep - tol)):
                    out.append((j, o, int(k)))
    return out
