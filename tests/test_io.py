"""OBJ import/export, Rerun recording, manifest and atomic writers."""

import json

import numpy as np
import pandas as pd
import pytest

from cloth.collision.obstacles import Sphere
from cloth.core.mesh import Mesh, grid_mesh
from cloth.io.manifest import environment_manifest, write_json_atomic, write_parquet_atomic
from cloth.io.obj import ObjError, load_obj, save_obj
from cloth.io.recorder import NullRecorder, RerunRecorder

# trimesh writes 17 decimal places (fixed point): values read back to within 1e-17 absolute.
ROUNDTRIP = 1e-16

# A band of three cells closed into a prism: verts 3 and 7 are seam copies of nodes 0 and 3.
SEAM_OBJ = """\
v 1 0 0
v -0.5 0.866 0
v -0.5 -0.866 0
v 1 0 1
v -0.5 0.866 1
v -0.5 -0.866 1
vt 0 0
vt 1 0
vt 2 0
vt 3 0
vt 0 1
vt 1 1
vt 2 1
vt 3 1
f 1/1 2/2 5/6
f 1/1 5/6 4/5
f 2/2 3/3 6/7
f 2/2 6/7 5/6
f 3/3 1/4 4/8
f 3/3 4/8 6/7
"""


def test_obj_with_seam_gives_nodes_with_two_verts(tmp_path):
    path = tmp_path / "band.obj"
    path.write_text(SEAM_OBJ)
    m = load_obj(path, uv_scale=0.5)
    assert m.n_nodes == 6 and m.n_verts == 8 and m.n_faces == 6
    counts = np.bincount(m.vert_node)
    assert sorted(counts) == [1, 1, 1, 1, 2, 2]
    assert m.face_area.sum() == pytest.approx(3 * 0.5 * 0.5)  # uv_scale applied to a 3 x 1 strip
    assert m.n_nodes - m.n_edges + m.n_faces == 0  # a closed band (cylinder)


def test_obj_round_trip_keeps_nodes_verts_and_faces(tmp_path):
    path = tmp_path / "band.obj"
    path.write_text(SEAM_OBJ)
    m = load_obj(path)
    m.node_x += 0.1 * np.random.default_rng(0).standard_normal(m.node_x.shape)
    save_obj(tmp_path / "out.obj", m)
    r = load_obj(tmp_path / "out.obj")
    assert r.n_nodes == m.n_nodes and r.n_verts == m.n_verts
    assert np.abs(r.vert_x() - m.vert_x()).max() < ROUNDTRIP
    assert np.abs(r.vert_u - m.vert_u).max() < ROUNDTRIP
    assert np.array_equal(r.face_verts, m.face_verts)
    assert not list(tmp_path.glob(".*.tmp"))


# Bad garment OBJ files: (file name, content, what the one message must say). read_obj checks
# the lines before trimesh reads the file, so that every message names the file.
BAD_OBJ = [
    ("no_vt.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "no_vt.obj: has no texture coordinates"),
    ("bad_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 9/3\n", "bad_index.obj"),
    ("bad_vt.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nf 1/1 2/2 3/3\n",
     "bad_vt.obj: a face refers to vt 3, and the file has 2 vt lines"),
    ("bad_line.obj", "v 0 0 0\nv 1 zero 0\n", "bad_line.obj: line 2"),
    ("empty.obj", "v 0 0 0\n", "empty.obj: has no faces"),
]


def test_obj_errors_name_the_file_and_problem(tmp_path):
    with pytest.raises(ObjError, match="missing.obj: no such file"):
        load_obj(tmp_path / "missing.obj")
    for name, text, message in BAD_OBJ:
        (tmp_path / name).write_text(text)
        with pytest.raises(ObjError, match=message):
            load_obj(tmp_path / name)


def test_quads_in_two_material_groups_become_triangles_of_the_same_area(tmp_path):
    """Two 1 x 1 quads, one per usemtl group, sharing an edge: trimesh cuts each into two
    triangles and concatenates the groups; nodes on the shared edge are merged by position."""
    path = tmp_path / "quads.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n"
                    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 2 0\nvt 2 1\n"
                    "usemtl a\nf 1/1 2/2 3/3 4/4\nusemtl b\nf 2/2 5/5 6/6 3/3\n")
    m = load_obj(path)
    assert m.n_faces == 4 and m.n_nodes == 6
    assert m.face_area.sum() == pytest.approx(2.0) and (m.face_area > 0).all()
    assert np.array_equal(np.unique(m.face_verts), np.arange(m.n_verts))  # every vert in a face


def test_clockwise_uv_layout_is_flipped(tmp_path):
    path = tmp_path / "cw.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 3/3 2/2\n")
    m = load_obj(path)
    assert m.face_area[0] == pytest.approx(0.5)


def test_rerun_recording_holds_every_frame(tmp_path):
    from rerun.chunk import RrdReader

    m = grid_mesh(1.0, 1.0, 3, 3)
    path = tmp_path / "rec.rrd"
    with RerunRecorder(path) as rec:
        for f in range(4):
            colors = np.random.default_rng(f).random((m.n_faces, 3)) if f % 2 else None
            rec.log_frame(f, 0.1 * f, m, face_colors=colors, obstacles=[Sphere((0, 0, 0), 0.2)])
    rows = {}
    for chunk in RrdReader(path).stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/world/cloth"] == 4
    assert rows["/world/obstacles/sphere"] == 1  # a static obstacle is logged once


def test_null_recorder_accepts_everything():
    with NullRecorder() as rec:
        rec.log_static("x", np.zeros((3, 3)), [[0, 1, 2]])
        rec.log_frame(0, 0.0, grid_mesh(1, 1, 1, 1))


def test_manifest_and_atomic_writers(tmp_path):
    man = environment_manifest(7)
    for key in ("seed", "python", "packages", "git_commit", "git_dirty", "cpu_model", "cpu_count", "numba_threads"):
        assert key in man
    assert man["seed"] == 7 and man["packages"]["numpy"] != "not installed"
    write_json_atomic(tmp_path / "m.json", man)
    assert json.loads((tmp_path / "m.json").read_text())["seed"] == 7
    write_parquet_atomic(tmp_path / "f.parquet", pd.DataFrame({"a": [1, 2]}))
    assert list(pd.read_parquet(tmp_path / "f.parquet")["a"]) == [1, 2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.parquet", "m.json"]


# The solver's libraries and what runs and records a run: each named in every manifest.json.
MANIFEST_PACKAGES = ("numpy", "scipy", "numba", "pypardiso", "mkl", "ray", "joblib", "rerun-sdk", "hydra-core",
                     "omegaconf", "pyyaml", "pandas", "pyarrow")


def test_manifest_records_the_solver_s_libraries_installed_or_not(monkeypatch):
    from importlib import metadata

    from cloth.io import manifest

    packages = environment_manifest(0)["packages"]
    assert set(MANIFEST_PACKAGES) <= set(packages)
    for name in MANIFEST_PACKAGES:
        assert packages[name] == manifest._version(name)  # a version, or "not installed"
    # the solve's libraries travel with a checkpoint, whose resume compares them
    assert {"pypardiso", "mkl", "numpy", "scipy", "numba"} <= set(manifest.code_version()["packages"])
    # a package that is not there is said so, and the manifest is still written
    real = metadata.version

    def without_ray(name):
        if name == "ray":
            raise metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(manifest.metadata, "version", without_ray)
    packages = environment_manifest(0)["packages"]
    assert packages["ray"] == manifest.NOT_INSTALLED == "not installed"
    assert packages["numpy"] == real("numpy")


def test_mesh_copy_is_independent():
    m = grid_mesh(1, 1, 2, 2)
    c = m.copy()
    c.node_x += 1
    assert isinstance(c, Mesh) and not np.allclose(c.node_x, m.node_x)
