"""Triangle meshes from files: STL (binary or ASCII) and Wavefront OBJ (its ``v`` and ``f`` lines; polygons fanned
into triangles). A file that is neither, or holds no triangle, is an :class:`~cdpr.errors.InputError` naming it."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from cdpr.errors import InputError
from cdpr.mechanics.rotation import Array


def load_mesh(path: str | Path) -> Array:
    """The triangles (n, 3, 3) of an STL or OBJ file, in the file's units."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the mesh ({exc.strerror or exc})") from None
    suffix = p.suffix.lower()
    if suffix == ".stl":
        triangles = _stl(data, str(path))
    elif suffix == ".obj":
        triangles = _obj(data, str(path))
    else:
        raise InputError(f"{path}: a mesh must be an .stl or .obj file")
    if len(triangles) == 0:
        raise InputError(f"{path}: the mesh has no triangle")
    if not np.all(np.isfinite(triangles)):
        raise InputError(f"{path}: the mesh has a vertex that is not a finite number")
    return triangles


def _stl(data: bytes, where: str) -> Array:
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        if len(data) == 84 + 50 * count:  # binary: a header, a count, 50 bytes per facet
            raw = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=count, offset=84)
            return raw["v"].astype(float)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(f"{where}: neither a binary STL (its size does not match its facet count) nor ASCII") from None
    vertices = []
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if words[:1] == ["vertex"]:
            try:
                if len(words) < 4:
                    raise ValueError
                vertices.append([float(w) for w in words[1:4]])
            except ValueError:
                raise InputError(f"{where}: line {number}: a vertex needs 3 numbers") from None
    if len(vertices) % 3:
        raise InputError(f"{where}: {len(vertices)} vertices: not whole triangles")
    return np.array(vertices, dtype=float).reshape(-1, 3, 3)


def _obj(data: bytes, where: str) -> Array:
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    for number, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), start=1):
        words = line.split("#", 1)[0].split()
        try:
            if words[:1] == ["v"]:
                if len(words) < 4:
                    raise ValueError
                vertices.append([float(w) for w in words[1:4]])
            elif words[:1] == ["f"]:
                idx = [int(w.split("/")[0]) for w in words[1:]]
                faces.append([i - 1 if i > 0 else len(vertices) + i for i in idx])
        except ValueError:
            raise InputError(f"{where}: line {number}: {line.strip()!r} is not a vertex or a face") from None
    triangles = []
    for number, f in enumerate(faces):
        if len(f) < 3 or min(f) < 0 or max(f) >= len(vertices):
            raise InputError(f"{where}: face {number}: needs 3 or more vertex indices, each naming one of its "
                             f"{len(vertices)} vertices")
        triangles += [[vertices[f[0]], vertices[f[k]], vertices[f[k + 1]]] for k in range(1, len(f) - 1)]
    return np.array(triangles, dtype=float).reshape(-1, 3, 3)
