"""OBJ files: cloth meshes (garments) and OBJ sequences (moving obstacles), read by one parser.

:func:`read_obj` reads the `v`, `vt`, `f` and `usemtl` lines of a file in the file's own
numbering; the two readers build on it:

* :func:`load_obj`, a cloth mesh with texture coordinates, read by trimesh's OBJ import after
  :func:`read_obj` has checked its lines (so that every error names the file). Positions become
  nodes and texture coordinates become material coordinates (metres, after a scale), so a garment
  pattern laid out in UV space imports with its rest shape. There is a vert per distinct
  (position, texture coordinate) pair; verts at exactly equal positions are merged into one node,
  which is how seams (one node, two verts) are recovered. Limitation: two distinct OBJ vertices at
  exactly the same position also become one node.
* :func:`read_obj_mesh` and :func:`load_obj_sequence`, positions and triangles only, polygons split
  into fans, in the file's vertex numbering, so that the frames of a sequence compare index by index.

Writing (:func:`save_obj`, :func:`write_obj_sequence`) goes through trimesh's OBJ export and plain
text; every file is written atomically.
"""

from __future__ import annotations

import glob
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj
from trimesh.visual import TextureVisuals

from cloth.collision.meshobstacle import MeshObstacleError
from cloth.core.mesh import Mesh, MeshError
from cloth.io.manifest import write_text_atomic


class ObjError(MeshError):
    """An OBJ file that cannot become a cloth mesh; the message names the file."""


class ObjSequenceError(ObjError, MeshObstacleError):
    """An OBJ file or sequence that cannot become a triangle-mesh obstacle: an ObjError (the message
    names the file) and the MeshObstacleError the obstacle's builders catch."""


# ---- the parser --------------------------------------------------------------------------------

@dataclass
class ObjFile:
    """The mesh content of an OBJ file, in the file's own numbering (what :func:`read_obj` returns).

    positions:      (V, 3) float64, the ``v`` lines in order (numbers after the third ignored).
    texcoords:      (T, 2) float64, the ``vt`` lines in order (u, v); empty unless read with texcoords.
    faces:          one tuple of corners per ``f`` line, in order; a corner is (v, vt, vn) as written:
                    1-based, or negative (relative to the end of the lines read so far); vt and vn
                    are None where absent, and always None unless read with texcoords.
    face_positions: (F,) int64, the number of ``v`` lines before each ``f`` line.
    face_material:  the ``usemtl`` name in force at each ``f`` line (None before the first).
    """
    positions: np.ndarray
    texcoords: np.ndarray
    faces: list[tuple[tuple[int, int | None, int | None], ...]]
    face_positions: np.ndarray
    face_material: list[str | None]


def _corner(token: str, texcoords: bool) -> tuple[int, int | None, int | None]:
    """(v, vt, vn) of a face token ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``."""
    parts = token.split("/")
    if not texcoords:
        return int(parts[0]), None, None
    vt = int(parts[1]) if len(parts) > 1 and parts[1] else None
    vn = int(parts[2]) if len(parts) > 2 and parts[2] else None
    return int(parts[0]), vt, vn


def read_obj(path, error: type[Exception] = ObjError, texcoords: bool = False,
             encoding_errors: str = "strict") -> ObjFile:
    """Parse an OBJ file's ``v``, ``f`` and (with `texcoords`) ``vt`` and ``usemtl`` lines; every
    other line is ignored. A line that cannot be read raises `error` naming the file and the line;
    so does a missing file. `encoding_errors`: how bytes that are not UTF-8 are decoded (``open``'s
    ``errors``). Indices are not checked here (see the readers)."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such file")
    verts, uvs, faces, face_positions, face_material = [], [], [], [], []
    material = None
    line_no = 0
    try:
        with open(path, errors=encoding_errors) as fh:
            for line in fh:
                line_no += 1
                if line.startswith("v "):
                    parts = line.split()
                    if len(parts) < 4:
                        raise ValueError("a vertex needs three coordinates")
                    verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
                elif line.startswith("f "):
                    corners = tuple(_corner(tok, texcoords) for tok in line.split()[1:])
                    if len(corners) < 3:
                        raise ValueError("a face needs at least three vertices")
                    faces.append(corners)
                    face_positions.append(len(verts))
                    face_material.append(material)
                elif texcoords and line.startswith("vt "):
                    parts = line.split()
                    if len(parts) < 3:
                        raise ValueError("a texture coordinate needs two numbers")
                    uvs.append((float(parts[1]), float(parts[2])))
                elif texcoords and line.startswith("usemtl "):
                    material = line[6:].strip()
    except (ValueError, UnicodeDecodeError) as exc:
        raise error(f"{path}: line {line_no}: cannot be read as OBJ ({exc})") from None
    return ObjFile(positions=np.asarray(verts, dtype=np.float64).reshape(-1, 3),
                   texcoords=np.asarray(uvs, dtype=np.float64).reshape(-1, 2), faces=faces,
                   face_positions=np.asarray(face_positions, dtype=np.int64), face_material=face_material)


def _fan(n: int) -> list[tuple[int, int, int]]:
    """The triangles of a polygon of n corners as a fan from corner 0, as corner numbers."""
    return [(0, j, j + 1) for j in range(1, n - 1)]


# ---- cloth meshes ------------------------------------------------------------------------------

def _check_garment_lines(obj: ObjFile, path) -> None:
    """ObjError naming the file for what trimesh would load without complaint or stop on with a
    message that does not name it: no faces, a face without texture coordinates, a corner that
    refers to a ``v`` or ``vt`` line that is not there."""
    if not obj.faces:
        raise ObjError(f"{path}: has no faces")
    corners = [c for face in obj.faces for c in face]
    if any(c[1] is None for c in corners):
        raise ObjError(f"{path}: has no texture coordinates (vt); material coordinates come from them")
    for k, (what, count) in enumerate((("v", len(obj.positions)), ("vt", len(obj.texcoords)))):
        bad = next((c[k] for c in corners if not (1 <= c[k] <= count or -count <= c[k] <= -1)), None)
        if bad is not None:
            raise ObjError(f"{path}: a face refers to {what} {bad}, and the file has {count} {what} lines")


def garment_arrays(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertex positions (n, 3), texture coordinates (n, 2), triangles (F, 3)) of a garment OBJ,
    as trimesh's OBJ import gives them (``trimesh.load_mesh(path, process=False)``: a vertex per
    distinct position and texture coordinate of the faces, polygons cut into triangles, groups of
    ``usemtl`` concatenated). The file is parsed by :func:`read_obj` first, so that a line that is
    not OBJ, a missing vertex or missing texture coordinates give an ObjError naming the file and
    the line or index, before trimesh reads it."""
    _check_garment_lines(read_obj(path, texcoords=True, encoding_errors="replace"), path)
    try:
        tm = trimesh.load_mesh(path, file_type="obj", process=False)
    except Exception as exc:  # noqa: BLE001 - whatever trimesh raises, the message names the file
        raise ObjError(f"{path}: cannot be read as OBJ ({type(exc).__name__}: {exc})") from None
    uv = getattr(tm.visual, "uv", None)
    if uv is None or len(uv) != len(tm.vertices):
        raise ObjError(f"{path}: has no texture coordinates (vt); material coordinates come from them")
    return (np.asarray(tm.vertices, dtype=np.float64), np.asarray(uv, dtype=np.float64),
            np.asarray(tm.faces, dtype=np.int64))


def load_obj(path, uv_scale: float = 1.0, position_scale: float = 1.0) -> Mesh:
    """Read a cloth mesh from an OBJ file with texture coordinates.

    Node positions are the OBJ positions times `position_scale`; material coordinates are the
    texture coordinates times `uv_scale` (metres). If every face is clockwise in UV space the
    faces are flipped consistently; a mix of orientations is reported as an inverted triangle.
    """
    path = Path(path)
    if not path.is_file():
        raise ObjError(f"{path}: no such file")
    if not (uv_scale > 0 and position_scale > 0):
        raise ObjError(f"{path}: uv_scale and position_scale must be > 0")
    x, uv, faces = garment_arrays(path)
    verts_x = x * position_scale
    vert_u = uv * uv_scale
    # one node per distinct position, numbered in order of first appearance
    _, first, inverse = np.unique(verts_x, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    vert_node = rank[inverse.reshape(-1)]
    node_x = verts_x[first[order]]
    u = vert_u[faces]
    signed = ((u[:, 1, 0] - u[:, 0, 0]) * (u[:, 2, 1] - u[:, 0, 1])
              - (u[:, 1, 1] - u[:, 0, 1]) * (u[:, 2, 0] - u[:, 0, 0]))
    if np.all(signed < 0):
        faces = faces[:, [0, 2, 1]]
    n = node_x.shape[0]
    try:
        return Mesh(node_x=node_x, node_v=np.zeros((n, 3)), node_pinned=np.zeros(n, dtype=bool),
                    vert_u=vert_u, vert_node=vert_node, face_verts=faces)
    except MeshError as exc:
        raise ObjError(f"{path}: {exc}") from None


def save_obj(path, mesh: Mesh) -> None:
    """Write the mesh as OBJ (atomically): one OBJ vertex per vert, vt = material coordinates.

    A seam node is written once per vert, at the same position, so load_obj merges it back.
    """
    tm = trimesh.Trimesh(vertices=mesh.vert_x(), faces=mesh.face_verts,
                         visual=TextureVisuals(uv=mesh.vert_u), process=False)
    text = export_obj(tm, include_normals=False, include_color=False, include_texture=True,
                      write_texture=False, digits=17, header=None)
    if isinstance(text, tuple):
        text = text[0]
    # no material library is written, so drop the references to one
    text = "\n".join(line for line in text.splitlines() if not line.startswith(("mtllib", "usemtl"))) + "\n"
    write_text_atomic(path, text, durable=False)  # a run's OBJ frames: no fsync each


# ---- OBJ sequences (moving obstacles): positions and triangles only, the file's numbering ----

def read_obj_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """(positions (V, 3), triangles (F, 3)) of an OBJ file: `v` and `f` lines only (texture and
    normal indices ignored, polygons split into fans, negative indices relative). The vertex
    numbering is the file's, so that frames of a sequence compare index by index."""
    obj = read_obj(path, error=ObjSequenceError)
    tris = [tuple(p[k][0] if p[k][0] > 0 else n + 1 + p[k][0] for k in t)
            for p, n in zip(obj.faces, obj.face_positions) for t in _fan(len(p))]
    if not tris:
        raise ObjSequenceError(f"{path}: has no faces")
    x = obj.positions
    f = np.asarray(tris, dtype=np.int64) - 1
    if f.min() < 0 or f.max() >= x.shape[0]:
        raise ObjSequenceError(f"{path}: a face refers to vertex "
                               f"{int(f.max() + 1 if f.max() >= x.shape[0] else f.min() + 1)} of {x.shape[0]}")
    return x, f


def _natural_key(path: str):
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", str(path))]


def obj_sequence_paths(source) -> list[Path]:
    """The files of an OBJ sequence: a glob pattern (e.g. 'walk/frame_*.obj'; sorted by name,
    numbers by value), a directory (its *.obj files), one file, or an explicit list of paths."""
    if isinstance(source, (list, tuple)):
        if not source:
            raise ObjSequenceError("obstacle OBJ sequence: the list of files is empty")
        paths = [Path(p).expanduser() for p in source]
    else:
        s = str(Path(str(source)).expanduser())
        if Path(s).is_dir():
            paths = [Path(p) for p in sorted(glob.glob(str(Path(s) / "*.obj")), key=_natural_key)]
        elif glob.has_magic(s):
            paths = [Path(p) for p in sorted(glob.glob(s), key=_natural_key)]
        else:
            paths = [Path(s)]
        if not paths:
            raise ObjSequenceError(f"obstacle OBJ sequence {str(source)!r}: no file matches")
    for p in paths:
        if not p.is_file():
            raise ObjSequenceError(f"obstacle OBJ sequence: {p}: no such file")
    return paths


def load_obj_sequence(source, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, list[Path]]:
    """Read an OBJ sequence of one topology: (vertices (K, V, 3) in metres = file units x scale,
    faces (F, 3), paths). A file whose vertex count or faces differ from the first's is named."""
    if not (np.isfinite(scale) and scale > 0):
        raise ObjSequenceError(f"obstacle OBJ scale must be > 0, got {scale}")
    paths = obj_sequence_paths(source)
    x0, faces = read_obj_mesh(paths[0])
    frames = [x0]
    for p in paths[1:]:
        x, f = read_obj_mesh(p)
        if x.shape[0] != x0.shape[0]:
            raise ObjSequenceError(f"{p}: has {x.shape[0]} vertices, {paths[0]} has {x0.shape[0]}: "
                                   "an OBJ sequence needs one topology")
        if f.shape != faces.shape or not np.array_equal(f, faces):
            raise ObjSequenceError(f"{p}: its faces differ from those of {paths[0]}: an OBJ sequence needs one "
                                   "topology")
        frames.append(x)
    return np.stack(frames) * float(scale), faces, paths


def write_obj_sequence(directory, vertices_per_frame, faces, stem: str = "frame") -> list[Path]:
    """Write keyframes (K, V, 3) as OBJ files directory/<stem>_0000.obj ... (atomically each)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    faces = np.asarray(faces, dtype=np.int64)
    face_text = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)
    paths = []
    for k, x in enumerate(np.asarray(vertices_per_frame, dtype=np.float64)):
        text = "".join(f"v {a:.17g} {b:.17g} {c:.17g}\n" for a, b, c in x) + face_text
        path = directory / f"{stem}_{k:04d}.obj"
        write_text_atomic(path, text, durable=False)
        paths.append(path)
    return paths
