"""Meshes: a robot package's STL and COLLADA files, converted once to OBJ, which Drake reads.

Robot packages ship STL or COLLADA (``.dae``) meshes; Drake 1.51 reads OBJ, VTK and glTF only (its
parser refuses an STL collision mesh outright). :func:`drake_mesh` converts such a file with
``trimesh`` (the ``robots`` extra; ``pycollada`` reads COLLADA) into a cache folder, keyed by the
source's path, size and modification time, so a second run converts nothing. COLLADA's colours
come along as the OBJ's materials. A file that cannot be read is a :class:`MeshError` naming it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from dualarm_mpc.base.outputs import write

# What Drake reads as it is; every other extension is converted.
DRAKE_MESHES = (".obj", ".vtk", ".gltf", ".glb")


class MeshError(ValueError):
    """A mesh file that cannot be converted for Drake."""


def cache_dir() -> Path:
    """``$DUALARM_MPC_CACHE``, else ``$XDG_CACHE_HOME/dualarm_mpc``, else ``~/.cache/dualarm_mpc``:
    where converted meshes and re-written robot files are kept."""
    root = os.environ.get("DUALARM_MPC_CACHE")
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dualarm_mpc"


def drake_mesh(source: Path) -> tuple[Path, bool]:
    """A mesh file Drake reads for ``source``: itself if it already is one, else its OBJ in
    :func:`cache_dir` (``True`` when converted by this call)."""
    if source.suffix.lower() in DRAKE_MESHES:
        return source, False
    try:
        stat = source.stat()
    except OSError as err:
        raise MeshError(f"mesh {source}: cannot read it: {err.strerror}") from err
    key = hashlib.sha256(f"{source.resolve()}|{stat.st_size}|{stat.st_mtime_ns}".encode())
    folder = cache_dir() / "meshes" / key.hexdigest()[:16]
    target = folder / f"{source.stem}.obj"
    if target.is_file():
        return target, False
    try:
        import trimesh
    except ImportError as err:
        raise MeshError(f"mesh {source}: {source.suffix} needs converting for Drake, which needs "
                        "trimesh: pip install 'dualarm_mpc[robots]'") from err
    try:
        mesh = trimesh.load(source, force="scene")
        if not mesh.geometry:
            raise ValueError("no geometry in it")
        text, materials = trimesh.exchange.obj.export_obj(
            mesh, include_color=True, include_texture=True, return_texture=True,
            mtl_name=f"{source.stem}.mtl")
    except Exception as err:  # trimesh's loaders raise anything from KeyError to XML errors
        raise MeshError(f"mesh {source}: cannot be converted to OBJ ({err})") from err
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in materials.items():  # the material file first: the OBJ names it
        write(folder / name, data)
    write(target, text)
    return target, True
