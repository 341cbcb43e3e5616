"""A figure written to a file: in the format its suffix names, whole or not at all."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from dualarm_mpc.base import outputs


def write_figure(fig: Figure, path: str | Path) -> None:
    """Write ``fig`` in the format the suffix of ``path`` names (PNG, PDF, SVG, ...) at 100 dpi,
    whole or not at all (``outputs.write``), and close it."""
    image = io.BytesIO()
    fig.savefig(image, format=Path(path).suffix.lstrip(".").lower(), dpi=100)
    plt.close(fig)
    outputs.write(path, image.getvalue())
