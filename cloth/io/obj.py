"""OBJ import and export through trimesh.

Positions become nodes and texture coordinates become material coordinates (metres, after a
scale), so a garment pattern laid out in UV space imports with its rest shape. trimesh gives a
vertex per distinct (position, texture coordinate) pair; verts at exactly equal positions are
merged into one node, which is how seams (one node, two verts) are recovered. Limitation: two
distinct OBJ vertices at exactly the same position also become one node.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from trimesh.exchange.obj import export_obj
from trimesh.visual import TextureVisuals

from ..mesh import Mesh, MeshError
from .manifest import write_text_atomic


class ObjError(MeshError):
    """An OBJ file that cannot become a cloth mesh; the message names the file."""


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
    try:
        tm = trimesh.load(path, file_type="obj", force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on malformed input
        raise ObjError(f"{path}: cannot be read as OBJ ({type(exc).__name__}: {exc})") from None
    if len(tm.faces) == 0:
        raise ObjError(f"{path}: has no faces")
    uv = getattr(tm.visual, "uv", None)
    if uv is None or len(uv) != len(tm.vertices):
        raise ObjError(f"{path}: has no texture coordinates (vt); material coordinates come from them")
    verts_x = np.asarray(tm.vertices, dtype=np.float64) * position_scale
    vert_u = np.asarray(uv, dtype=np.float64) * uv_scale
    faces = np.asarray(tm.faces, dtype=np.int64)
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
    write_text_atomic(path, text)
