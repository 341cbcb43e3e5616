"""Meshcat for a run: the view a person sees (camera on the table, clutter hidden), the live
server, and the headless recording saved as one self-contained HTML file (docs/drake.md)."""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from pydrake.common import MemoryFile
from pydrake.geometry import (
    Box,
    InMemoryMesh,
    Mesh,
    Meshcat,
    MeshcatAnimation,
    MeshcatParams,
    Rgba,
)
from pydrake.math import RigidTransform

from dualarm_mpc.base import outputs
from dualarm_mpc.base.palette import goal_colour
from dualarm_mpc.sim.station import Station

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
OPEN_CONTROLS = "<script>viewer.gui.open(); viewer.gui.__folders.Scene.close();</script>\n</body>"


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


def show_the_work(meshcat: Meshcat, station: Station) -> None:
    """Point the camera at the table, and hide the clutter. Call it
    after the Simulator's initialization, which deletes and redraws the contact forces."""
    x0, x1, y0, y1 = station.table
    # The table only: the robot stands in front of it, and its arms reach in from below the view.
    table = [[x, y, 0.0] for x in (x0, x1) for y in (y0, y1)]
    meshcat.SetProperty(CAMERA, "fov", FOV_DEG)
    meshcat.SetCameraPose(*camera_pose(np.array(table)))
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


def save_recording(meshcat: Meshcat, path: str | Path | None) -> None:
    """Stop and publish the recording (a live browser can replay it), and write it to ``path``
    as standalone HTML with its controls open: it plays once from the start as the page loads."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    meshcat.Flush()  # a live browser has the replay before the server can go
    if path is None:
        return
    html = meshcat.StaticHtml()
    head, _, tail = html.rpartition("</body>")
    outputs.write(path, head + OPEN_CONTROLS + tail)


# The sign a live page shows once the run is over: a strip lying on the table's far margin (the
# 0.15 m the table extends past the goals), text on it, drawn after the recording so that the
# replay the page plays does not hide it and the HTML replay does not have it.
RUN_OVER = "/run_over"
REPLAYS = 1_000_000  # times a live page plays the recording once the run is over: for good
SIGN_SIZE = (1.1, 0.12)  # m: width, depth
SIGN_OBJ = """mtllib sign.mtl
v -0.5 -0.5 0
v 0.5 -0.5 0
v 0.5 0.5 0
v -0.5 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl sign
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
    width, depth = SIGN_SIZE
    fig = Figure(figsize=(8, 8 * depth / width), dpi=200)  # no pyplot: an image, no display
    fig.text(0.5, 0.5, f"The run is over at t = {t:.1f} s: replaying it", ha="center",
             va="center", fontsize=22, fontweight="bold", color=(0.15, 0.15, 0.15))
    image = io.BytesIO()
    fig.savefig(image, format="png", facecolor=(1.0, 1.0, 0.85))
    files = {"sign.mtl": MemoryFile("newmtl sign\nKa 1 1 1\nKd 1 1 1\nmap_Kd sign.png\n",
                                    ".mtl", "sign.mtl"),
             "sign.png": MemoryFile(image.getvalue(), ".png", "sign.png")}
    sign = InMemoryMesh(mesh_file=MemoryFile(SIGN_OBJ, ".obj", "sign.obj"),
                        supporting_files=files)
    meshcat.SetObject(RUN_OVER, Mesh(sign, np.array([width, depth, 1.0])))
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
