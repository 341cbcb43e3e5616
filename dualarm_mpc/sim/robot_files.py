"""Robot files: a URDF or SDF model as its package ships it, made readable by Drake.

* ``package://`` URLs resolve through Drake's ``PackageMap``: our own models, the package around
  the model file (its ``package.xml``), ``ROS_PACKAGE_PATH``, and robot-description packages
  installed by pip (``example-robot-data`` and the other ``cmeel`` packages install under
  ``site-packages/cmeel.prefix/share/NAME``), found without the user setting a path.
* A model that welds its base to a ``world`` link (Universal Robots', xArm's) loses that weld,
  and :mod:`dualarm_mpc.sim.robot` welds its base where the scenario puts it, the weld's offset
  kept: loaded twice, it would otherwise weld both arms to one place.
* STL and COLLADA meshes become OBJ (:mod:`dualarm_mpc.sim.meshes`).

The re-written model is a file in the cache folder, which Drake's own parser reads
(docs/robots.md).
"""

from __future__ import annotations

import hashlib
import logging
import os
import site
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.parsing import PackageMap

from dualarm_mpc.base.outputs import write
from dualarm_mpc.model.scenario import ScenarioError
from dualarm_mpc.sim.meshes import MeshError, cache_dir, drake_mesh
from dualarm_mpc.sim.resources import package_map

_log = logging.getLogger(__name__)


class RobotError(ScenarioError):
    """A robot model that cannot carry the hands: missing, unreadable, or lacking a frame."""


def installed_packages() -> PackageMap:
    """Robot-description packages pip installed (``cmeel.prefix/share/NAME`` with a
    ``package.xml``), under their folder's name and their ``package.xml``'s, plus
    ``ROS_PACKAGE_PATH`` and our own models."""
    packages = package_map()
    roots = [*site.getsitepackages(), site.getusersitepackages()]
    for root in roots:
        share = Path(root) / "cmeel.prefix" / "share"
        for folder in sorted(share.glob("*/package.xml")):
            for name in {folder.parent.name, _package_name(folder)} - {None}:
                if not packages.Contains(name):
                    packages.Add(name, str(folder.parent))
    if os.environ.get("ROS_PACKAGE_PATH"):
        packages.PopulateFromRosPackagePath()
    return packages


def _package_name(package_xml: Path) -> str | None:
    try:
        return ET.parse(package_xml).findtext("name")
    except (ET.ParseError, OSError):
        return None


def model_path(url: str, packages: PackageMap) -> Path:
    """The file of ``robot_model``: a path (made absolute by the scenario loader) or a
    ``package://NAME/...`` URL. Adds the package around a plain file to ``packages``."""
    if url.startswith("package://"):
        name, _, rest = url[len("package://"):].partition("/")
        if not packages.Contains(name):
            raise RobotError(f"robot_model: no package {name!r} (known: "
                             f"{', '.join(sorted(packages.GetPackageNames()))})")
        path = Path(packages.GetPath(name)) / rest
    else:
        path = Path(url.removeprefix("file://"))
        for parent in path.parents:  # the package the file belongs to, for its package:// URLs
            if (parent / "package.xml").is_file():
                name = _package_name(parent / "package.xml")
                if name and not packages.Contains(name):
                    packages.Add(name, str(parent))
                break
    if not path.is_file():
        raise RobotError(f"robot_model: no file {path}")
    if path.suffix.lower() not in (".urdf", ".sdf", ".xml"):
        raise RobotError(f"robot_model: {path.name} is neither URDF nor SDF")
    return path


@dataclass(frozen=True)
class PreparedModel:
    """A model file re-written for Drake, and the weld to ``world`` it had."""

    path: Path
    root: str | None  # the link welded to world in the file, if any
    weld: RigidTransform  # that weld's pose of the link in the world


def prepare_model(source: Path, packages: PackageMap) -> PreparedModel:
    """``source`` with its meshes made readable by Drake and its weld to ``world`` taken out,
    written to the cache folder (once per content)."""
    try:
        tree = ET.parse(source)
    except (ET.ParseError, OSError) as err:
        raise RobotError(f"robot_model: {source} is not readable XML ({err})") from err
    root = tree.getroot()
    converted = 0
    for element, attribute in _mesh_references(root):
        uri = element.get(attribute) if attribute else (element.text or "").strip()
        path = _mesh_file(uri, source, packages)
        try:
            target, fresh = drake_mesh(path)
        except MeshError as err:
            raise RobotError(f"robot_model: {err}") from err
        converted += fresh
        if target != path or not uri.startswith("package://"):
            if attribute:
                element.set(attribute, str(target))
            else:
                element.text = str(target)
    if converted:
        _log.warning("converted %d meshes of %s to OBJ in %s", converted, source.name,
                     cache_dir() / "meshes")
    for parent in root.iter():  # ROS's soft limits, which Drake ignores with a warning each
        for tag in parent.findall("safety_controller"):
            parent.remove(tag)
    link, weld = _unweld(root)
    text = ET.tostring(root, encoding="unicode")
    key = hashlib.sha256(f"{source.resolve()}|{text}".encode()).hexdigest()[:16]
    target = cache_dir() / "models" / key / source.name
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        write(target, text)
    return PreparedModel(target, link, weld)


def _mesh_references(root: ET.Element):
    """(element, attribute) of every mesh file: URDF's ``<mesh filename>``, SDF's
    ``<mesh><uri>`` (attribute None: the text)."""
    for mesh in root.iter("mesh"):
        if mesh.get("filename"):
            yield mesh, "filename"
        uri = mesh.find("uri")
        if uri is not None and (uri.text or "").strip():
            yield uri, None


def _mesh_file(uri: str, model: Path, packages: PackageMap) -> Path:
    for scheme in ("package://", "model://"):
        if uri.startswith(scheme):
            name, _, rest = uri[len(scheme):].partition("/")
            if not packages.Contains(name):
                raise RobotError(f"robot_model: mesh {uri} is in package {name!r}, which is "
                                 "not installed")
            return Path(packages.GetPath(name)) / rest
    path = Path(uri.removeprefix("file://"))
    return path if path.is_absolute() else model.parent / path


def _unweld(root: ET.Element) -> tuple[str | None, RigidTransform]:
    """Removes the fixed joint from ``world`` (and URDF's ``world`` link); returns the link it
    welded and that link's pose in the world."""
    for parent in root.iter():
        for joint in list(parent.findall("joint")):
            if joint.get("type") != "fixed":
                continue
            urdf = joint.find("parent") is not None and joint.find("parent").get("link")
            source = urdf or (joint.findtext("parent") or "").strip()
            if source != "world":
                continue
            child = joint.find("child")
            link = child.get("link") if urdf else (child.text or "").strip()
            origin = joint.find("origin")
            weld = RigidTransform()
            if urdf and origin is not None:
                xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()]
                rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()]
                weld = RigidTransform(RollPitchYaw(rpy), xyz)
            parent.remove(joint)
            for world in [w for w in parent.findall("link") if w.get("name") == "world"]:
                parent.remove(world)
            return link, weld
    return None, RigidTransform()
