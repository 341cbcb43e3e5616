"""Resources: where the installed package keeps its robot model, and the PackageMap that finds it.

The model files live in the top-level ``models/`` directory, installed as the package
``dualarm_mpc.models`` (see pyproject.toml); ``package://dualarm_mpc/<file>`` URLs resolve there.
Nothing is downloaded: the robot is our own (docs/drake.md).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pydrake.multibody.parsing import PackageMap

PACKAGE = "dualarm_mpc"
ROBOT_URL = f"package://{PACKAGE}/dual_scara.sdf"


def models_dir() -> Path:
    """The directory holding ``package.xml`` and ``dual_scara.sdf`` in the installed package."""
    path = Path(str(resources.files("dualarm_mpc.models")))
    if not (path / "package.xml").is_file():
        raise FileNotFoundError(f"dualarm_mpc models: no package.xml in {path}")
    return path


def package_map() -> PackageMap:
    """A PackageMap with only ``dualarm_mpc`` → :func:`models_dir`."""
    package_map = PackageMap.MakeEmpty()
    package_map.Add(PACKAGE, str(models_dir()))
    return package_map
