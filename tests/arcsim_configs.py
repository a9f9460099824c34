"""ARCSim configs for the reader's tests (tests/test_arcsim_reader.py, tests/test_arcsim_motions.py):
small meshes and a .mot file written into an ARCSim-like directory (`arcsim_dir`, each test
module's `root` fixture), a small valid config (`base`) and the loaders that write and read one."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cloth.io.arcsim import ArcsimConfigError, load_arcsim_config

# Hand-computed values are closed forms evaluated in float64; a few roundings apart.
EXACT = 1e-12
# Finite-difference step (s) and tolerance for velocities checked against poses: central
# differences of a cubic are exact up to h^2 |x'''| / 6 ~ 1e-8 and round-off ~ 1e-16 / h.
FD_STEP = 1e-5
FD_TOL = 1e-6

# A unit square as a quad (material coordinates twice the positions), fanned from corner 0.
SQUARE_OBJ = """\
# a comment
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 2 0
vt 2 2
vt 0 2
vn 0 0 1
f 1/1/1 2/2/1 3/3/1 4/4/1
"""

# Two triangles without vt: material coordinates are the positions' x and y.
FLAT_OBJ = """\
v 0 0 5
v 2 0 5
v 2 1 5
v 0 1 5
f 1 2 3
f 1 3 4
"""

TETRA_OBJ = """\
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
"""

# Two parts, three frames. Part 1's third orientation is written with the opposite sign of the
# continuous one ((0, 0, 0, 1): 180 degrees about z), which ARCSim's clean-up flips back.
C45 = math.cos(math.pi / 4)
MOT = f"""\
NumFrames: 3
body[0] position
0 0 0
1 0 0
2 0 0

body[0] orientation
1 0 0 0
1 0 0 0
1 0 0 0

body[1] position
0 0 1
0 0 1
0 0 1

body[1] orientation
1 0 0 0
{C45!r} 0 0 {C45!r}
0 0 0 -1
"""


def rot(axis, angle_deg):
    """Rotation matrix about a coordinate axis ('x', 'y' or 'z')."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def arcsim_dir(tmp_path):
    """`tmp_path` made an ARCSim-like directory: conf/, meshes/ (square, flat, tetra, a .mot),
    materials/ (each test module's `root` fixture)."""
    (tmp_path / "conf").mkdir()
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    (meshes / "square.obj").write_text(SQUARE_OBJ)
    (meshes / "flat.obj").write_text(FLAT_OBJ)
    (meshes / "tetra.obj").write_text(TETRA_OBJ)
    (meshes / "walk.mot").write_text(MOT)
    (tmp_path / "materials").mkdir()
    (tmp_path / "materials" / "cotton.json").write_text("{}")  # its contents are not this reader's
    return tmp_path


def base(**changes) -> dict:
    """A small valid config, with top-level keys replaced (a value None removes the key)."""
    conf = {"frame_time": 0.04, "frame_steps": 4, "end_time": 2,
            "cloths": [{"mesh": "meshes/square.obj", "materials": [{"data": "materials/cotton.json"}]}]}
    conf.update(changes)
    return {k: v for k, v in conf.items() if v is not None}


def write(root: Path, conf, name: str = "scene.json") -> Path:
    path = root / "conf" / name
    path.write_text(conf if isinstance(conf, str) else json.dumps(conf, indent=1))
    return path


def load(root: Path, conf, name: str = "scene.json"):
    return load_arcsim_config(write(root, conf, name))


def error_of(root: Path, conf) -> ArcsimConfigError:
    """The error loading `conf` raises; checks that its message names the key and the file."""
    path = write(root, conf)
    with pytest.raises(ArcsimConfigError) as info:
        load_arcsim_config(path)
    err = info.value
    assert str(path) in str(err) and err.path == path
    if err.key is not None:
        assert err.key in str(err)
    return err
