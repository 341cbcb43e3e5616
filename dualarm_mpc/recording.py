"""Headless Meshcat recording of a run, saved as one self-contained HTML file (design §4)."""

from __future__ import annotations

from pathlib import Path

from pydrake.geometry import Box, Meshcat, MeshcatParams, Rgba
from pydrake.math import RigidTransform

from dualarm_mpc.station import goal_colour


def start_meshcat() -> Meshcat:
    """A Meshcat server with no browser attached, on any free port."""
    return Meshcat(MeshcatParams(port=0))


def start_recording(meshcat: Meshcat) -> None:
    meshcat.StartRecording(frames_per_second=32.0, set_visualizations_while_recording=False)


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


def save_recording(meshcat: Meshcat, path: str | Path) -> int:
    """Stop, publish and write the recording as standalone HTML; returns its size in bytes."""
    meshcat.StopRecording()
    meshcat.PublishRecording()
    html = meshcat.StaticHtml()
    Path(path).write_text(html)
    return len(html.encode())


def is_self_contained(html: str) -> bool:
    """No external script or stylesheet: every <script> and <link> is inline."""
    lowered = html.lower()
    return not any(tag in lowered for tag in ('<script src="http', "<script src='http",
                                               '<link rel="stylesheet" href="http'))

