"""The ten dancers (multiple_dancers) and crowds of any size: the stage layout (crowd_columns,
crowd_placement) and one Scene per character."""

from __future__ import annotations

import math

import numpy as np

from cloth.core.material import Material
from cloth.core.scene import Scene, SceneError
from cloth.scenes.common import _check_size
from cloth.scenes.dancers import solo_dancer

PAPER_COLUMNS = 5
PAPER_CROWD = 10
CROWD_ASPECT = 2.5


def crowd_columns(dancers: int, columns: int | None = None) -> int:
    """Dancers per row of a crowd of `dancers`: `columns` when given; else (auto) the paper's 5 up
    to 10 dancers (one row, or the paper's 5 x 2), and beyond ceil(sqrt(2.5 dancers)), the least c
    with c^2 >= 2.5 dancers (exact integer arithmetic): 16 per row for 100 dancers (7 rows), 50
    for 1000 (20 rows)."""
    if columns is not None:
        return int(columns)
    n = int(dancers)
    if n <= PAPER_CROWD:
        return PAPER_COLUMNS
    c = math.isqrt(5 * n // 2)
    while 2 * c * c < 5 * n:  # c^2 >= 2.5 n
        c += 1
    return c


def crowd_placement(dancers: int, spacing: float, columns: int | None, phase_step: float, heading_step: float,
                    phase_wrap: float = 1.0):
    """(positions (dancers, 3) m, phases (dancers,) s, headings (dancers,) rad) of a crowd on a
    stage: rows of `columns` dancers (None: :func:`crowd_columns`) `spacing` metres apart,
    centred on the origin, rows behind each other (+y; row 0, the front row, nearest -y) and a
    last row that may be short. Dancer i's phase, the delay of its motion's start, is
    (i * `phase_step`) mod `phase_wrap` seconds (in [0, phase_wrap): every dancer dances for
    most of the run), its heading i * `heading_step` radians."""
    n = int(dancers)
    columns = crowd_columns(n, columns)
    i = np.arange(n)
    col, row = i % columns, i // columns
    n_rows = (n + columns - 1) // columns
    x = (col - (min(n, columns) - 1) / 2) * spacing
    y = (row - (n_rows - 1) / 2) * spacing
    return np.column_stack([x, y, np.zeros(len(i))]), np.mod(i * phase_step, phase_wrap), i * heading_step


def multiple_dancers(material: Material, *, character: int = 0, dancers: int = PAPER_CROWD, spacing: float = 3.0,
                     columns: int | None = None, phase_step: float = 0.37, phase_wrap: float = 1.0,
                     heading_step: float = 0.6, **dancer) -> Scene:
    """Character `character` of a crowd of `dancers` on a stage (the paper's ten dancers):
    exactly `solo_dancer` placed at its spot, with its own phase and heading so the crowd is not
    in lock-step: `spacing` m apart in rows of `columns` (None: auto, :func:`crowd_columns`),
    dancer i's motion starting (i `phase_step`) mod `phase_wrap` seconds late (each stands at
    rest until then) and turned i `heading_step` rad. A crowd run simulates every character as
    its own Simulation (see experiments/run.py); `crowd_size(params)` gives the number of dancers."""
    name = "multiple_dancers"
    if isinstance(dancers, bool) or int(dancers) != dancers or int(dancers) < 1:
        raise SceneError(f"scene {name!r}: dancers must be an integer >= 1, got {dancers!r}")
    if columns is not None and (isinstance(columns, bool) or int(columns) != columns or int(columns) < 1):
        raise SceneError(f"scene {name!r}: columns must be an integer >= 1 or None (auto), got {columns!r}")
    if not 0 <= int(character) < int(dancers):
        raise SceneError(f"scene {name!r}: character must be in [0, {int(dancers) - 1}], got {character}")
    _check_size(name, spacing=spacing)
    if not (phase_step >= 0 and phase_wrap > 0):
        raise SceneError(f"scene {name!r}: phase_step must be >= 0 s and phase_wrap > 0 s, got {phase_step}, "
                         f"{phase_wrap}")
    for key in ("position", "phase", "heading"):
        if key in dancer:
            raise SceneError(f"scene {name!r}: {key} is set per character by the crowd layout")
    pos, phases, headings = crowd_placement(dancers, spacing, columns, phase_step, heading_step, phase_wrap)
    k = int(character)
    scene = solo_dancer(material, position=tuple(pos[k]), phase=float(phases[k]), heading=float(headings[k]),
                        **dancer)
    scene.name = f"{name}/dancer_{k:02d}"
    return scene
