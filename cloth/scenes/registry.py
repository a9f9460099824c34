"""The scene registry: every scene by name (SCENES) and build_scene, which checks a scene's
parameters before building it. The builders: cloth.scenes.sheets (hanging_sheet,
sheet_on_sphere, flag, layered_sheets, crushed_sheet, mesh_obstacle, cusick_drape),
cloth.scenes.dancers (solo_dancer, karate), cloth.scenes.crowd (multiple_dancers: one Scene per
character) and cloth.scenes.arcsim (ARCSim's configs).
"""

from __future__ import annotations

import inspect

from cloth.core.material import Material
from cloth.core.scene import Scene, SceneError
from cloth.scenes.arcsim import arcsim_scene
from cloth.scenes.crowd import (
    CROWD_ASPECT,
    PAPER_COLUMNS,
    PAPER_CROWD,
    crowd_columns,
    crowd_placement,
    multiple_dancers,
)
from cloth.scenes.dancers import (
    BODIES,
    CHARACTER_EFFECTS,
    CHARACTER_JITTER,
    DANCER_GARMENTS,
    NO_SELF_COLLISION_NOTE,
    karate,
    solo_dancer,
)
from cloth.scenes.sheets import (
    crushed_sheet,
    cusick_drape,
    flag,
    hanging_sheet,
    layered_sheets,
    mesh_obstacle,
    sheet_on_sphere,
)

__all__ = ["BODIES", "CHARACTER_EFFECTS", "CHARACTER_JITTER", "CROWDS", "CROWD_ASPECT", "DANCER_GARMENTS",
           "NO_SELF_COLLISION_NOTE", "PAPER_COLUMNS", "PAPER_CROWD", "SCENES", "build_scene", "crowd_columns",
           "crowd_placement", "crushed_sheet", "cusick_drape", "flag", "hanging_sheet", "karate", "layered_sheets",
           "mesh_obstacle", "multiple_dancers", "sheet_on_sphere", "solo_dancer"]


CROWDS = {"multiple_dancers"}  # scenes whose builder makes one character of a crowd (parameter `character`)

SCENES = {"hanging_sheet": hanging_sheet, "sheet_on_sphere": sheet_on_sphere, "flag": flag,
          "solo_dancer": solo_dancer, "karate": karate, "multiple_dancers": multiple_dancers,
          "layered_sheets": layered_sheets, "crushed_sheet": crushed_sheet, "mesh_obstacle": mesh_obstacle,
          "cusick_drape": cusick_drape, "arcsim": arcsim_scene}


def build_scene(name: str, material: Material, **params) -> Scene:
    """Build a registered scene by name; unknown names and parameters raise SceneError."""
    if name not in SCENES:
        raise SceneError(f"unknown scene {name!r}; known scenes: {sorted(SCENES)}")
    builder = SCENES[name]
    allowed = {p for p in inspect.signature(builder).parameters if p not in ("material", "dancer")}
    if name in CROWDS:
        allowed |= {p for p in inspect.signature(solo_dancer).parameters
                    if p not in ("material", "position", "phase", "heading")}
    unknown = set(params) - allowed
    if unknown:
        raise SceneError(f"scene {name!r}: unknown parameter(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    return builder(material, **params)
