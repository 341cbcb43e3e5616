"""Meshcat for a run: the view a person sees (camera on the table and the robot, clutter hidden),
what the replay says besides the scene (:class:`Notes`: labels, the plan in force, releases and
slides, and a head-up display of the run), the live server, and the headless recording saved as
one self-contained HTML file (docs/drake.md).

Why one module of this length: the notes are drawn into the recording (each shown by its
animation), the head-up display goes into the page :func:`save_recording` writes, the camera
frames the arms' names the notes lay out, and the labels and the live page's sign are one kind of
text quad; apart, each part would reach into the others' paths, frames and constants."""

from __future__ import annotations

import dataclasses
import io
import json
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from pydrake.common import MemoryFile
from pydrake.geometry import (
    Box,
    Cylinder,
    InMemoryMesh,
    Mesh,
    Meshcat,
    MeshcatAnimation,
    MeshcatParams,
    Rgba,
)
from pydrake.math import RigidTransform

from dualarm_mpc.base import outputs
from dualarm_mpc.base.palette import ARM_COLOURS, goal_colour
from dualarm_mpc.model.mld import REST_SPEED, State, target_box
from dualarm_mpc.model.plan import TimedTrajectory
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.sim.station import Station
from dualarm_mpc.systems.trajectories import hand_trajectory

# The view is framed for a 1280×800 window (a wider one only adds margin at the sides), through a
# narrower lens than Meshcat's default 75° (vertical): less distorted, the near arms not huge.
CAMERA = "/Cameras/default/rotated/<object>"
FOV_DEG = 30.0
ASPECT = 1280 / 800
ELEVATION_DEG = 60.0  # below the horizontal: steep enough that the columns hide no goal
FILL = 0.92  # of the view, in its tighter direction, the framed points span (the rest: margin)
# Drawn by Meshcat itself or by Drake's contact visualizer (with ``record_contacts`` only): they
# clutter the view of the work. Hidden, not deleted: each has its checkbox in the Scene panel.
HIDDEN = ("/Grid", "/Axes")
CONTACT_FORCES = "/drake/contact_forces"
# Meshcat collapses its controls at load; a replay is driven from them (play, pause, time): open
# them, with the long Scene tree folded so that Animations is at the top.
OPEN_CONTROLS = "<script>viewer.gui.open(); viewer.gui.__folders.Scene.close();</script>\n"
# The robot's columns (models/dual_scara.sdf): their radius, and the height of the arms' top.
COLUMN_RADIUS = 0.05
ROBOT_TOP = 0.36
ARM_NAMES = ("arm 1 (right)", "arm 2 (left)")  # as plan.png names them (figures/plan.py)
ARM_SIGN_SIZE = (0.45, 0.09)  # m: an arm's name on the floor beside its column
LIFT = 0.004  # m: what is drawn on the table lies this high, over the goals (a moved one: 3 mm)


def start_meshcat(live: bool = False) -> Meshcat:
    """A Meshcat server: ``live``, on Drake's usual port (7000, or the next free one) for a
    browser to watch; otherwise on any free port, with no browser attached."""
    return Meshcat() if live else Meshcat(MeshcatParams(port=0))


def start_recording(meshcat: Meshcat, live: bool = False) -> None:
    """Record from now on; ``live``: the browser attached follows the run as it goes."""
    meshcat.StartRecording(frames_per_second=32.0, set_visualizations_while_recording=live)


def camera_pose(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and target (world, z up) that show every one of ``points`` (n × 3) from
    in front (−y) and above, as large as the view allows.

    With the camera's right r, up u and forward f, a point p is inside the view's left and right
    planes iff −t ≤ r·(p − C) / f·(p − C) ≤ t (t: tangent of half the field of view across).
    Writing C = x·r + y·u + z·f, that is x − (−t)·z ≤ A and −x + t·z ≤ B for every p, with
    A = min (r + t·f)·p and B = min (t·f − r)·p: the camera can come in as far as
    z = (A + B) / 2t, centred at x = (A − B) / 2. The same holds for y with u and the tangent of
    half the field of view upwards; the nearer bound on z of the two is the one that holds."""
    el = np.radians(ELEVATION_DEG)
    f = np.array([0.0, np.cos(el), -np.sin(el)])
    r = np.array([1.0, 0.0, 0.0])
    u = np.cross(r, f)
    tan_up = FILL * np.tan(np.radians(FOV_DEG) / 2)
    position, depth = np.zeros(3), np.inf
    for axis, t in ((r, tan_up * ASPECT), (u, tan_up)):
        a = (points @ (axis + t * f)).min()
        b = (points @ (t * f - axis)).min()
        position += (a - b) / 2 * axis
        depth = min(depth, (a + b) / (2 * t))
    position += depth * f
    target = position - position[2] / f[2] * f  # where the view's centre meets the table
    return position, target


def arm_sign_centres(station: Station) -> np.ndarray:
    """Where each arm's name lies (2 × 3, world): on the floor beside its column, outwards."""
    width, _ = ARM_SIGN_SIZE
    bases = np.asarray(station.arm_bases, float)
    side = np.sign(bases[:, 0] - bases[:, 0].mean())  # the right arm's to the right
    x = bases[:, 0] + side * (COLUMN_RADIUS + 0.03 + width / 2)
    return np.stack([x, bases[:, 1], np.full(len(bases), LIFT)], axis=1)


def framed_points(station: Station) -> np.ndarray:
    """What the camera shows whole: the table top, the robot's columns up to its arms' height,
    and the arms' names beside the columns."""
    x0, x1, y0, y1 = station.table
    points = [[x, y, 0.0] for x in (x0, x1) for y in (y0, y1)]
    r = COLUMN_RADIUS
    points += [[bx + dx, by + dy, z] for bx, by in station.arm_bases for dx in (-r, r)
               for dy in (-r, r) for z in (0.0, ROBOT_TOP)]
    width, depth = ARM_SIGN_SIZE
    points += [[cx + dx, cy + dy, cz] for cx, cy, cz in arm_sign_centres(station)
               for dx in (-width / 2, width / 2) for dy in (-depth / 2, depth / 2)]
    return np.array(points)


def show_the_work(meshcat: Meshcat, station: Station) -> None:
    """Point the camera at the table and the robot (:func:`framed_points`), and hide the
    clutter. Call it after the Simulator's initialization, which deletes and redraws the contact
    forces."""
    meshcat.SetProperty(CAMERA, "fov", FOV_DEG)
    meshcat.SetCameraPose(*camera_pose(framed_points(station)))
    for path in HIDDEN:
        meshcat.SetProperty(path, "visible", False)
    if meshcat.HasPath(CONTACT_FORCES):  # setting a property would add the path to the scene
        meshcat.SetProperty(CONTACT_FORCES, "visible", False)


def show_goal(meshcat: Meshcat, name: str, box: list[float], t: float) -> None:
    """Draw goal ``name`` at ``box`` from time ``t`` of the recording on (a moved goal)."""
    x0, x1, y0, y1 = box
    path = f"/goals/{name}_{t:.2f}"
    meshcat.SetObject(path, Box(x1 - x0, y1 - y0, 0.002), Rgba(*goal_colour(name), 0.8))
    meshcat.SetTransform(path, RigidTransform([(x0 + x1) / 2, (y0 + y1) / 2, 0.002]))
    animation = meshcat.get_mutable_recording()
    frame = animation.frame(t)
    animation.SetProperty(0, path, "visible", False)
    animation.SetProperty(frame, path, "visible", True)


# What the replay says besides the scene (:class:`Notes`).
NOTES = "/notes"  # everything drawn on the table and the floor; the object numbers ride the boxes
SAMPLE_S = 1 / 32  # s of simulated time between two looks at the run: a frame of the recording
THROWN_SPEED = 0.05  # m/s: an object released faster is thrown (a placed one is at rest)
TRAIL_PIECE_S = 0.25  # s: a slide's trail grows by pieces this long
FAINT = 0.5  # opacity of the plan in force drawn on the table
PATH_SAMPLES = 8  # points per Δt of a hand's planned path (the curve its interpolator follows)
WHITE = (1.0, 1.0, 1.0)


def _rgba(colour, alpha: float = 1.0) -> Rgba:
    """An ``Rgba`` of an RGB tuple or a ``#rrggbb`` string."""
    if isinstance(colour, str):
        colour = [int(colour[k:k + 2], 16) / 255 for k in (1, 3, 5)]
    return Rgba(*colour, alpha)


def _outline(box: list[float] | np.ndarray) -> np.ndarray:
    """The closed outline of [x0, x1, y0, y1] on the table (3 × 5)."""
    x0, x1, y0, y1 = box
    return np.array([[x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], [LIFT] * 5])


def _on_table(xy: np.ndarray) -> np.ndarray:
    """Planar points (n × 2) as a line on the table (3 × n)."""
    xy = np.asarray(xy, float)
    return np.vstack([xy.T, np.full(len(xy), LIFT)])


class Notes:
    """What the replay says besides the scene, drawn into it as the run goes (live too).

    :meth:`start` (once the recording started) writes each object's number on its box and each
    arm's name beside its column. Called after every simulator step (``simulate``'s observer),
    every ``SAMPLE_S`` of simulated time it draws each plan the planner puts in force, faint,
    until the next one: the hands' planned paths in the arms' colours, the moving objects' paths
    and their goal slots (``mld.target_box``) in their goals'; it marks each release point with a
    disc in the arm's colour, and draws the slide of a thrown object (released faster than
    ``THROWN_SPEED``) as a trail that grows with it. Shown from when each happens on: the
    recording animates their visibility. :meth:`overlay` is the replay's head-up display."""

    def __init__(self, meshcat: Meshcat, scenario: Scenario, dual) -> None:
        self.meshcat, self.scenario, self.dual = meshcat, scenario, dual
        self.releases: list[list] = []  # [t, arm, object index, speed in m/s]
        self._next: float | None = None  # when to look next; None: not started
        self._last = 0.0  # the last look's time
        self._plan: TimedTrajectory | None = None
        self._plan_path: str | None = None
        self._plan_since = 0.0
        self._held = [-1, -1]
        self._slides: dict[int, list] = {}  # object → [since, points of the piece not drawn]
        self._count = 0  # paths drawn so far (each drawing's path is new)
        self._later: set[str] = set()  # paths shown after t = 0 and not hidden again since

    def start(self) -> None:
        """Label the objects and the arms; from now on, draw the plans and the releases."""
        st, meshcat = self.dual.station, self.meshcat
        size = st.object_size
        for j, (instance, body) in enumerate(zip(st.object_instances, st.objects, strict=True)):
            frame = f"/drake/illustration/{st.plant.GetModelInstanceName(instance)}/{body.name()}"
            goal = goal_colour(self.scenario.task.objects[j].goal)
            meshcat.SetObject(f"{frame}/number", _text_mesh(
                str(j + 1), (0.9 * size, 0.9 * size), WHITE, goal, fontsize=52, width_in=1.28,
                dpi=100))
            meshcat.SetTransform(f"{frame}/number", RigidTransform([0, 0, size / 2 + 5e-4]))
        for i, centre in enumerate(arm_sign_centres(st)):
            path = f"{NOTES}/arm{i + 1}"
            meshcat.SetObject(path, _text_mesh(ARM_NAMES[i], ARM_SIGN_SIZE, WHITE,
                                               ARM_COLOURS[i], fontsize=40, width_in=6.4,
                                               dpi=100))
            meshcat.SetTransform(path, RigidTransform(centre))
        self._next = 0.0

    def __call__(self, dual, context) -> None:
        t = context.get_time()
        if self._next is None or t < self._next - 1e-9:
            return
        self._next = t + SAMPLE_S
        planner = dual.planner
        own = planner.GetMyContextFromRoot(context)
        plan = planner.mpc_state(own).plan
        if plan is not self._plan:
            goals = dual.goals.goals(dual.goals.GetMyContextFromRoot(context))
            self._show_plan(plan, max(min(plan.t0, t), self._last), goals)
        measured = planner.get_measured_state_input_port().Eval(own)
        self._look(t, State.from_vector(measured, self.scenario.n_objects))
        self._last = t

    def _new_path(self, kind: str) -> str:
        self._count += 1
        return f"{NOTES}/{kind}/{self._count}"

    def _visible(self, path: str, since: float, until: float | None = None) -> None:
        """``path`` shows in the replay from ``since`` (until ``until``); live, it shows now."""
        animation = self.meshcat.get_mutable_recording()
        if animation.frame(since) > 0:
            animation.SetProperty(0, path, "visible", False)
            self._later.add(path)
        animation.SetProperty(animation.frame(since), path, "visible", True)
        if until is not None:
            animation.SetProperty(animation.frame(until), path, "visible", False)
            self.meshcat.SetProperty(path, "visible", False)
            self._later.discard(path)

    def _show_plan(self, plan: TimedTrajectory, since: float, goals: dict) -> None:
        if self._plan_path is not None:
            self._visible(self._plan_path, self._plan_since, since)
        self._plan, self._plan_path, self._plan_since = plan, None, since
        traj = plan.trajectory
        steps = len(traj.hand_pos) - 1
        if steps < 1:  # holding still: nothing planned to draw
            return
        path = self._plan_path = self._new_path("plan")
        times = plan.t0 + plan.dt * np.linspace(0, steps, PATH_SAMPLES * steps + 1)
        hands = hand_trajectory(plan).vector_values(times)  # rows x, y of arm 1, then arm 2
        for i in range(2):
            self.meshcat.SetLine(f"{path}/hand{i + 1}", _on_table(hands[2 * i:2 * i + 2].T), 2.0,
                                 _rgba(ARM_COLOURS[i], FAINT))
        sc = dataclasses.replace(self.scenario,
                                 task=dataclasses.replace(self.scenario.task, goals=goals))
        moved = np.linalg.norm(traj.object_pos[-1] - traj.object_pos[0], axis=1) > 1e-3
        for j in np.flatnonzero(moved):
            colour = goal_colour(self.scenario.task.objects[j].goal)
            self.meshcat.SetLine(f"{path}/object{j + 1}", _on_table(traj.object_pos[:, j]), 2.0,
                                 _rgba(colour, FAINT))
            self.meshcat.SetLine(f"{path}/slot{j + 1}", _outline(target_box(sc, j).bounds()),
                                 2.0, _rgba(colour, FAINT))
        self._visible(path, since)

    def _look(self, t: float, s: State) -> None:
        """Grasps taken and let go, release points, and the slides of thrown objects."""
        for i in range(2):
            held = np.flatnonzero(s.grasp[i] > 0.5)
            j = int(held[0]) if len(held) else -1
            if j == self._held[i]:
                continue
            was, self._held[i] = self._held[i], j
            if was >= 0:
                self._released(t, i, was, s)
        for j in list(self._slides):
            since, points = self._slides[j]
            points.append(s.object_pos[j].copy())
            over = np.linalg.norm(s.object_vel[j]) < REST_SPEED or s.grasp[:, j].max() > 0.5
            if over or t - since >= TRAIL_PIECE_S - 1e-9:
                colour = goal_colour(self.scenario.task.objects[j].goal)
                path = self._new_path("slide")
                self.meshcat.SetLine(path, _on_table(np.array(points)), 4.0, _rgba(colour))
                self._visible(path, t)
                self._slides[j] = [t, points[-1:]]
            if over:
                del self._slides[j]

    def _released(self, t: float, arm: int, j: int, s: State) -> None:
        speed = float(np.linalg.norm(s.object_vel[j]))
        self.releases.append([round(t, 3), arm, j, round(speed, 3)])
        path = self._new_path("release")
        self.meshcat.SetObject(path, Cylinder(0.018, 0.002), _rgba(ARM_COLOURS[arm], 0.9))
        self.meshcat.SetTransform(path, RigidTransform([*s.object_pos[j], LIFT]))
        self._visible(path, t)
        if speed > THROWN_SPEED:
            self._slides[j] = [t, [s.object_pos[j].copy()]]

    def overlay(self, summary) -> str:
        """The replay's head-up display: HTML for :func:`save_recording`. Top left, keyed by the
        animation's time: the simulated time, the sequential step and its objects, the last
        replan's status and cost (a kept plan's, with when it was made), delivered k/N, what
        each arm holds and where it goes, and each throw and each environment event (an object
        knocked, a goal moved) for 3 s after it; below, a legend of what is drawn. From the
        run's ``summary`` (``closed_loop.Summary``: a step is a run of replans for the same
        objects) and what :class:`Notes` saw. The page's ``?t=`` (simulated seconds) opens the
        replay paused at that time, and seeking by script (``viewer.animator.seek``) shows the
        time sought in the time field.

        Called as the run ends, it also hides in the scene what the run drew after t = 0: the
        page shows each only when the animation does, not all at once while the animation
        loads (a live page goes on to replay the recording, which shows them again)."""
        for path in sorted(self._later):
            self.meshcat.SetProperty(path, "visible", False)
        self._later.clear()
        names = [o["name"] for o in summary.objects]
        rows, step, current, plan = [], 0, None, (None, None)
        for r in summary.replans:
            objects = [names.index(name) + 1 for name in r["objects"]]
            if objects and objects != current:
                step, current = step + 1, objects
            if r["adopted"]:
                plan = (r["cost"], r["t"])
            rows.append([r["t"], step, r["status"], r["cost"], *plan, objects])
        events = sorted([e["time"], _event_text(e, names)] for e in summary.events)
        # [t, arm, object or -1 (free)] at each change, a hold ended before one begun at once
        holds = sorted([t, h["arm"] - 1, j] for h in summary.holds
                       for t, j in ((h["from"], names.index(h["object"])), (h["to"], -1))
                       if j >= 0 or t < summary.sim_time_s)
        data = {"n": len(names), "goals": [o["goal"] for o in summary.objects], "replans": rows,
                "delivered": sorted(d for d in summary.delivered_time_s if d is not None),
                "holds": holds, "releases": self.releases, "thrown": THROWN_SPEED,
                "arms": list(ARM_NAMES), "events": events}
        return HUD.replace("__RUN__", json.dumps(data).replace("</", "<\\/"))


def _event_text(event: dict, names: list[str]) -> str:
    """An environment event of the summary, as the HUD says it."""
    if event["kind"] == "move_object":
        x, y = event["position"]
        return f"object {names.index(event['target']) + 1} knocked to ({x:.2f}, {y:.2f})"
    x0, x1, y0, y1 = event["box"]
    return f"goal {event['target']} moved to x {x0:.2f}\u2013{x1:.2f}, y {y0:.2f}\u2013{y1:.2f}"


HUD_STYLE = ("position:fixed;left:10px;top:10px;z-index:10;pointer-events:none;"
             "white-space:pre;background:rgba(255,255,255,0.85);color:#222;border-radius:6px;"
             "padding:6px 10px;font-family:system-ui,sans-serif")
HUD = f"""<div style="{HUD_STYLE}"><div id="hud" style="font-size:14px;font-weight:600;\
line-height:1.4"></div><div id="hud-legend" style="font-size:11px;line-height:1.35;color:#444;\
margin-top:4px">faint lines: the plan in force (hands: the arms' colours; objects: their goals')
outlines: its goal slots \u00b7 discs: release points \u00b7 bold lines: a thrown box's slide\
</div></div>
<script>
(() => {{
  const run = __RUN__;
  const animator = viewer.animator;
  const hud = document.getElementById("hud");
  const EPS = 1e-6;
  const upTo = (rows, t) => rows.filter(r => r[0] <= t + EPS);
  const last = (rows, t) => upTo(rows, t).pop();
  const fixed = (x, n) => Number(x).toFixed(n);
  function text(t) {{
    const lines = [`t = ${{fixed(t, 1)}} s`];
    const r = last(run.replans, t);
    if (r === undefined) {{
      lines.push("step -: no replan yet");
    }} else {{
      const [at, step, status, cost, planCost, planAt, objects] = r;
      lines.push(objects.length ? `step ${{step}}: objects ${{objects.join(", ")}}`
                                : `step ${{step}}: nothing left to plan`);
      let said = `replan at ${{fixed(at, 1)}} s: ${{status}}`;
      if (cost !== null) said += `, cost ${{fixed(cost, 3)}}`;
      else if (planCost !== null && status !== "done")
        said += `, plan's cost ${{fixed(planCost, 3)}} (made at ${{fixed(planAt, 1)}} s)`;
      lines.push(said);
    }}
    const k = run.delivered.filter(d => d <= t + EPS).length;
    lines.push(`delivered ${{k}}/${{run.n}}`);
    run.arms.forEach((arm, i) => {{
      const hold = last(run.holds.filter(h => h[1] === i), t);
      const j = hold === undefined ? -1 : hold[2];
      lines.push(j < 0 ? `${{arm}}: free` : `${{arm}}: holds ${{j + 1}} \u2192 ${{run.goals[j]}}`);
    }});
    for (const [at, arm, j, speed] of upTo(run.releases, t)) {{  // the throws of the last 3 s
      if (speed > run.thrown && t - at < 3)
        lines.push(`${{fixed(at, 1)}} s: ${{run.arms[arm]}} threw ${{j + 1}} ` +
                   `at ${{fixed(speed, 2)}} m/s`);
    }}
    for (const [at, what] of upTo(run.events, t)) {{  // the disturbances of the last 3 s
      if (t - at < 3) lines.push(`${{fixed(at, 1)}} s: ${{what}}`);
    }}
    return lines.join("\\n");
  }}
  let shown = null;
  function show() {{
    // The time field's: when the replay ends, Meshcat resets its actions' times to 0 and leaves
    // the scene and the field at the end.
    const said = text(animator.time);
    if (said !== shown) hud.textContent = shown = said;
  }}
  function update() {{
    show();
    requestAnimationFrame(update);
  }}
  update();
  const seek = animator.seek.bind(animator);
  animator.seek = t => {{  // the time field and the HUD show the time sought at once
    seek(t);
    animator.display_progress(Math.max(0, Math.min(animator.duration, t)));
    show();
  }};
  // A paused scene is drawn again only when it changes, and the labels' textures load after
  // their meshes (each Meshcat mesh file has a loader of its own, which says nothing when done):
  // draw it again twice a second for the first 20 s, or a label opened paused stays black.
  let redraws = 40;
  const redraw = setInterval(() => {{
    viewer.set_dirty();
    if (--redraws === 0) clearInterval(redraw);
  }}, 500);
  const at = parseFloat(new URLSearchParams(location.search).get("t"));
  if (Number.isFinite(at)) {{  // ?t=5.5: paused at 5.5 s of simulated time
    const go = () => {{ animator.pause(); animator.seek(at); }};
    if (animator.duration > 0) {{
      go();
    }} else {{
      const load = animator.load.bind(animator);
      animator.load = (...args) => {{ load(...args); animator.load = load; go(); }};
    }}
  }}
}})();
</script>
"""


def save_recording(meshcat: Meshcat, path: str | Path | None, overlay: str = "") -> None:
    """Stop and publish the recording (a live browser can replay it), and write it to ``path``
    as standalone HTML with its controls open and ``overlay`` (HTML, e.g.
    :meth:`Notes.overlay`) at the end of the page: it plays once from the start as the page
    loads."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    meshcat.Flush()  # a live browser has the replay before the server can go
    if path is None:
        return
    html = meshcat.StaticHtml()
    head, _, tail = html.rpartition("</body>")
    outputs.write(path, head + OPEN_CONTROLS + overlay + "</body>" + tail)


def _text_mesh(text: str, size: tuple[float, float], colour, background, fontsize: float,
               width_in: float = 8.0, dpi: int = 200) -> Mesh:
    """A flat ``size`` (m: width along x, depth along y) quad at z = 0 facing up, ``text``
    written on it across x (matplotlib draws it, ``width_in`` inches wide at ``dpi``), read from
    −y: a textured mesh Meshcat shows live and in the replay."""
    width, depth = size
    fig = Figure(figsize=(width_in, width_in * depth / width), dpi=dpi)  # no pyplot: no display
    fig.text(0.5, 0.5, text, ha="center", va="center", fontsize=fontsize, fontweight="bold",
             color=colour)
    image = io.BytesIO()
    fig.savefig(image, format="png", facecolor=background)
    files = {"label.mtl": MemoryFile("newmtl label\nKa 1 1 1\nKd 1 1 1\nmap_Kd label.png\n",
                                     ".mtl", "label.mtl"),
             "label.png": MemoryFile(image.getvalue(), ".png", "label.png")}
    quad = InMemoryMesh(mesh_file=MemoryFile(QUAD_OBJ, ".obj", "label.obj"),
                        supporting_files=files)
    return Mesh(quad, np.array([width, depth, 1.0]))


# The sign a live page shows once the run is over: a strip lying on the table's far margin (the
# 0.15 m the table extends past the goals), text on it, drawn after the recording so that the
# replay the page plays does not hide it and the HTML replay does not have it.
RUN_OVER = "/run_over"
REPLAYS = 1_000_000  # times a live page plays the recording once the run is over: for good
SIGN_SIZE = (1.1, 0.12)  # m: width, depth
QUAD_OBJ = """mtllib label.mtl
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl label
f 1/1/1 2/2/1 3/3/1
f 1/1/1 3/3/1 4/4/1
"""


def end_live(meshcat: Meshcat, station: Station, t: float) -> None:
    """A live page, the run over: it replays the recording over and over (published again,
    after :func:`save_recording` wrote the HTML replay, which plays once) and says so, on a
    sign on the table: "The run is over at t = … s: replaying it"."""
    recording = meshcat.get_mutable_recording()
    recording.set_loop_mode(MeshcatAnimation.LoopMode.kLoopRepeat)
    recording.set_repetitions(REPLAYS)
    meshcat.PublishRecording()
    sign = _text_mesh(f"The run is over at t = {t:.1f} s: replaying it", SIGN_SIZE,
                      (0.15, 0.15, 0.15), (1.0, 1.0, 0.85), fontsize=22)
    meshcat.SetObject(RUN_OVER, sign)
    x0, x1, _, y1 = station.table
    meshcat.SetTransform(RUN_OVER, RigidTransform([(x0 + x1) / 2, y1 - 0.075, 0.003]))
    meshcat.Flush()


def serve_while_watched(meshcat: Meshcat, poll_s: float = 0.5) -> None:
    """Keep the server up while a page is open on it: the page goes on playing the recording,
    and its "No connection to server" banner would show the moment the server went. Returns
    when the last page closes, at once if none is open."""
    while meshcat.GetNumActiveConnections() > 0:
        time.sleep(poll_s)


def is_self_contained(html: str) -> bool:
    """No external script or stylesheet: every <script> and <link> is inline."""
    lowered = html.lower()
    return not any(tag in lowered for tag in ('<script src="http', "<script src='http",
                                               '<link rel="stylesheet" href="http'))


def both(*observers):
    """One ``simulate`` observer (``observe(dual, context)``) calling each of ``observers`` not
    None in turn; None if none is."""
    calls = [f for f in observers if f is not None]
    if len(calls) < 2:
        return calls[0] if calls else None
    return lambda dual, context: [f(dual, context) for f in calls]
