"""OBJ meshes as ARCSim reads them (its ``io.cpp`` ``load_obj``), for cloths and obstacles.

ARCSim's mesh has **nodes** (world space) and **verts** (material space), as this project's:

* a ``v`` line is a node, numbered in file order (handles name nodes by these numbers), at its
  world position;
* a ``vt`` line is a vert, numbered in file order, at its material coordinates (u, v; a third
  number is ignored);
* a face corner ``v/vt`` (or ``v/vt/vn``) ties vert vt to node v. A corner without vt (``v`` or
  ``v//vn``) uses the first vert already tied to node v, or else a new vert at the first two
  coordinates (x, y) of the node's file position (so a flat mesh drawn in the xy plane needs no
  ``vt``). New verts are numbered after the ``vt`` verts, in order of first use (ARCSim numbers
  them where the face line stands; this differs only for a file with ``vt`` lines after faces
  without vt, and no config refers to verts by number);
* a polygon of n corners becomes n - 2 triangles fanned from one corner: ARCSim's
  ``triangulate`` takes the corner whose fan has the largest smallest angle (angles of the file
  positions), the first such corner on a tie (here: within :data:`ROOT_TIE_RAD`). A triangle is
  kept as written; a polygon whose every fan has a zero angle (degenerate) is an error, where
  ARCSim would crash.

Checked here, where ARCSim would crash or read garbage: indices are positive (OBJ's relative,
negative indices are not ARCSim's), a face names only nodes defined above it and existing
verts, a corner names a node once per face, a vert is tied to one node only, and every vert
belongs to a face. Lines whose keyword ARCSim does not read (``vn``, ``g``, ``usemtl``, ``vv``, ...)
are ignored, as ARCSim ignores them; ARCSim's own extension lines (:data:`ARCSIM_OBJ_EXTENSIONS`:
labels, velocities, edges, plastic state) carry state this reader does not support and are an
error naming the line.

The ``v``/``vt``/``f`` lines are parsed by :func:`cloth.io.obj.read_obj`. The garment reader
(:func:`cloth.io.obj.load_obj`, trimesh's OBJ import) does not fit: it numbers vertices as trimesh
does and merges nodes by position, while ARCSim's handles name nodes by their ``v`` line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cloth.io.obj import ObjError, read_obj

# ARCSim's OBJ extension keywords (0.2.1 and 0.3.1) -> what they carry. Each is rejected.
ARCSIM_OBJ_EXTENSIONS = {
    "vl": "a vert label", "ms": "3-D material coordinates (0.3.1)",
    "ny": "a node's plastic embedding", "nv": "a node's initial velocity", "nl": "a node label",
    "e": "an explicit edge", "ea": "an edge's rest angle", "ed": "an edge's damage", "el": "an edge label",
    "ep": "an edge's preserve flag (0.3.1)",
    "tl": "a face label (material index)", "fl": "a face label (material index)",
    "ts": "a face's plastic strain", "fs": "a face's plastic strain", "td": "a face's damage",
    "fd": "a face's damage", "tm": "a face flag (0.3.1)", "tp": "a face's plastic bending (0.3.1)",
}

# Two fans whose smallest angles differ by less than this are a tie (the earlier corner wins):
# ARCSim breaks exact ties so, and rounding differs between its arithmetic and numpy's.
ROOT_TIE_RAD = 1e-12


@dataclass(frozen=True, eq=False)
class ArcsimObj:
    """An OBJ mesh as ARCSim builds it (module docstring), in the file's coordinates."""

    path: Path
    node_x: np.ndarray  # (n_nodes, 3) float64: ``v`` positions in file order (file units)
    vert_u: np.ndarray  # (n_verts, 2) float64: material coordinates (file units), ``vt`` verts first
    vert_node: np.ndarray  # (n_verts,) int64: the node each vert is tied to
    face_verts: np.ndarray  # (n_faces, 3) int64: triangles as vert indices, polygons fanned

    @property
    def face_nodes(self) -> np.ndarray:
        """(n_faces, 3) int64: triangles as node indices."""
        return self.vert_node[self.face_verts]


def _angles(x0: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Angle at x0 (..., radians) between x1 - x0 and x2 - x0, a zero edge counting as
    perpendicular (ARCSim normalises a zero vector to zero)."""
    def unit(d):
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        return np.divide(d, n, out=np.zeros_like(d), where=n > 0)
    return np.arccos(np.clip(np.sum(unit(x1 - x0) * unit(x2 - x0), axis=-1), -1.0, 1.0))


def fan_min_angles(x: np.ndarray) -> np.ndarray:
    """(m, n) the smallest angle of the fan from each corner, of m polygons of n corners at
    positions x (m, n, 3)."""
    m, n = x.shape[:2]
    smallest = np.empty((m, n))
    j = np.arange(2, n)
    for i in range(n):
        a = np.broadcast_to(x[:, i:i + 1], (m, n - 2, 3))
        b, c = x[:, (i + j - 1) % n], x[:, (i + j) % n]
        smallest[:, i] = np.minimum.reduce([_angles(a, b, c), _angles(b, c, a), _angles(c, a, b)]).min(axis=1)
    return smallest


def fan_roots(x: np.ndarray) -> np.ndarray:
    """(m,) int64: the corner ARCSim fans each of m polygons (corner positions x (m, n, 3)) from:
    the largest smallest angle, the earlier corner within ROOT_TIE_RAD; -1 if every fan of the
    polygon has a zero angle."""
    smallest = fan_min_angles(x)
    best_angle = np.zeros(x.shape[0])
    root = np.full(x.shape[0], -1, dtype=np.int64)
    for i in range(x.shape[1]):
        better = smallest[:, i] > best_angle + np.where(root >= 0, ROOT_TIE_RAD, 0.0)
        best_angle[better], root[better] = smallest[better, i], i
    return root


def _check_lines(path: Path) -> None:
    """ObjError for an ARCSim extension line, or a v/vt/f line ARCSim reads but read_obj would not
    (indented, or a tab after the keyword)."""
    with open(path, errors="replace") as fh:
        for line_no, line in enumerate(fh, start=1):
            if line.startswith("#"):
                continue
            tokens = line.split()
            if not tokens:
                continue
            keyword = tokens[0]
            if keyword in ARCSIM_OBJ_EXTENSIONS:
                raise ObjError(f"{path}: line {line_no}: ARCSim's OBJ extension {keyword!r} "
                               f"({ARCSIM_OBJ_EXTENSIONS[keyword]}) is not supported")
            if keyword in ("v", "vt", "f") and not line.startswith(keyword + " "):
                raise ObjError(f"{path}: line {line_no}: an OBJ {keyword!r} line must start the line and be "
                               "followed by a space")


def read_arcsim_obj(path) -> ArcsimObj:
    """Read an OBJ file as ARCSim does (module docstring); ObjError naming the file (and the
    line or face) for what ARCSim could not read."""
    path = Path(path)
    if not path.is_file():
        raise ObjError(f"{path}: no such file")
    _check_lines(path)
    obj = read_obj(path, texcoords=True, encoding_errors="replace")
    node_x = obj.positions
    for what, values in (("v", node_x), ("vt", obj.texcoords)):
        bad = np.flatnonzero(~np.isfinite(np.asarray(values, dtype=np.float64)).all(axis=1)) if len(values) else []
        if len(bad):
            raise ObjError(f"{path}: {what} line {int(bad[0]) + 1} (of the {what} lines) has a coordinate that is not "
                           f"a finite number: {np.asarray(values)[bad[0]].tolist()}")
    if not obj.faces:
        raise ObjError(f"{path}: has no faces")
    n_vt = obj.texcoords.shape[0]
    vert_u = list(obj.texcoords)
    vert_node = [-1] * n_vt
    node_verts: list[list[int]] = [[] for _ in range(node_x.shape[0])]
    polygons: list[list[int]] = []  # per face line, its corners' verts
    for f, (corners, n_defined) in enumerate(zip(obj.faces, obj.face_positions)):
        nodes, verts = [], []
        for v, vt, _ in corners:
            if not 1 <= v <= n_defined:
                raise ObjError(f"{path}: face {f + 1} names node {v}, but {n_defined} 'v' lines stand above it "
                               "(indices start at 1; ARCSim reads no negative ones)")
            node = v - 1
            if vt is not None:
                if not 1 <= vt <= n_vt:
                    raise ObjError(f"{path}: face {f + 1} names vt {vt} of {n_vt}")
                vert = vt - 1
            elif node_verts[node]:
                vert = node_verts[node][0]
            else:
                vert = len(vert_u)
                vert_u.append(node_x[node, :2].copy())
                vert_node.append(-1)
            nodes.append(node)
            verts.append(vert)
        if len(set(nodes)) != len(nodes):
            raise ObjError(f"{path}: face {f + 1} names a node twice: {[n + 1 for n in nodes]}")
        for node, vert in zip(nodes, verts):
            if vert_node[vert] not in (-1, node):
                raise ObjError(f"{path}: face {f + 1}: vt {vert + 1} is tied to node {vert_node[vert] + 1} and "
                               f"node {node + 1}; ARCSim ties a vert to one node")
            vert_node[vert] = node
            if vert not in node_verts[node]:
                node_verts[node].append(vert)
        polygons.append(verts)
    vert_node = np.array(vert_node, dtype=np.int64)
    root = np.zeros(len(polygons), dtype=np.int64)
    for n in {len(p) for p in polygons}:
        which = np.array([f for f, p in enumerate(polygons) if len(p) == n])
        root[which] = fan_roots(node_x[vert_node[np.array([polygons[f] for f in which])]])
    if np.any(root < 0):
        raise ObjError(f"{path}: face {int(np.argmax(root < 0)) + 1} is degenerate (a zero angle in every fan "
                       "of it)")
    triangles = [(p[r], p[(r + j - 1) % len(p)], p[(r + j) % len(p)])
                 for p, r in zip(polygons, root.tolist()) for j in range(2, len(p))]
    face_verts = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    unused = [i + 1 for i in np.flatnonzero(vert_node < 0)]
    if unused:
        raise ObjError(f"{path}: vt line(s) {unused[:5]}{' ...' if len(unused) > 5 else ''} belong to no face")
    return ArcsimObj(path=path, node_x=node_x, vert_u=np.array(vert_u, dtype=np.float64).reshape(-1, 2),
                     vert_node=vert_node, face_verts=face_verts)
