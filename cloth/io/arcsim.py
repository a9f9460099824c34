"""ARCSim scene configurations (Narain et al. 2012; versions 0.2.1 and 0.3.1) as plain, checked data.

:func:`load_arcsim_config` reads a config (JSON with ``//`` and ``/* */`` comments) and the files
it names, and returns an :class:`ArcsimConfig` of dataclasses and numpy arrays. It builds no
project Scene and knows no Hydra: a scene builder maps this data onto the project's objects. The
semantics below are those of ARCSim's ``conf.cpp``; what ARCSim does with each value is said
where the value is declared. File names are resolved against `root` (ARCSim resolves them
against its working directory, the parent of ``conf/``); every path in the result is absolute and
exists. Material files are only located here (their contents are another module's business).

Nothing is ignored. A key this reader does not know, a key ARCSim knows but this reader does not
support, a value of the wrong type or length, a missing file and an index out of range each raise
:class:`ArcsimConfigError`, whose message (and ``.key``, ``.path``) names the key as a JSON path
(``cloths[0].materials[0].thicken``) and the config file. An explicit ``null`` is an absent key,
as in jsoncpp.

Supported keys (ARCSim's defaults when absent):

* timing, two forms. ``frame_time`` (s, required in this form), ``frame_steps`` (1), ``end_time``
  (inf), ``end_frame`` (none); or ``timestep`` (s), ``save_frames`` (1: steps per frame),
  ``duration`` (inf). ``duration`` is the end time in both forms: ARCSim reads it only in the
  timestep form and ignores it next to ``frame_time`` (flag.json gives both, so ARCSim runs it
  forever); here it ends the run, and giving it together with ``end_time`` is an error. Keys of
  the other form are errors (ARCSim would ignore them).
* ``cloths`` (required, non-empty): ``mesh`` (OBJ, :mod:`cloth.io.arcsim_mesh`), ``transform``
  (identity), ``velocity`` {``linear``, ``angular``, ``origin``} (0: initial node velocity
  v = linear + angular x (x - origin), x after the transform), ``materials`` (required, exactly
  one: several need OBJ face labels), ``remeshing``.
  The transform maps the file positions to world positions, and its *scale also multiplies the
  material coordinates* (ARCSim scales the verts' u before computing rest data).
* ``materials[i]``: ``data`` (required: the material file), ``thicken`` (1), ``density_mult``,
  ``stretching_mult``, ``bending_mult`` (1 each; ARCSim multiplies each by ``thicken`` too),
  ``damping`` (0), ``strain_limits`` [min, max] (none: -inf, inf; as 1 + strain).
* ``remeshing``: ``refine_angle``, ``refine_compression``, ``refine_velocity`` (inf), ``size``
  [min, max] (-inf, inf; metres), ``aspect_min`` (-inf).
* ``motions``: a list of keyframe lists (``time`` required, ``transform`` (identity),
  ``velocity``), or an object {``motfile``, ``fps`` (both required), ``transform``} for the rigid
  parts of a .mot file; interpolation in :mod:`cloth.io.arcsim_motion`.
* ``handles``: node handles only (``type`` "node", the default): ``cloth`` (0), ``nodes``
  (required: node numbers = OBJ ``v`` lines from 0), ``motion`` (none; -1 is none), ``start_time``
  (0), ``end_time`` (inf), ``fade_time`` (0).
* ``obstacles``: a list of {``mesh`` (required), ``transform`` (identity), ``motion`` (none),
  ``start_time`` (0), ``end_time`` (inf)}, or a printf pattern with one integer field: one static-
  shape obstacle per existing file pattern % i, i = 0, 1, ... up to the first missing file, with
  motion i when there is one (none otherwise) and no transform.
* ``gravity`` (0, m/s^2), ``wind`` {``velocity`` (0, m/s), ``density`` (1, kg/m^3), ``drag`` (0)},
  ``friction`` (0.6, cloth-cloth), ``obs_friction`` (0.3, cloth-obstacle), ``disable`` (a list of
  :data:`MODULES` names), ``magic`` (:data:`MAGIC_DEFAULTS`, :data:`MAGIC_031`).

Rejected as unsupported: ``morphs``; plasticity (``yield_curv``, ``weakening`` and 0.3.1's
``yield_stretch``, ``plastic_flow``, ``plastic_limit``); 0.3.1's parametric and fracturing
materials (``thickness``, ``density``, ``elastic_modulus``, ``poisson_ratio``, ``toughness``,
``fracture_bending_mult``), ``reference``, ``size_uniform``, ``refine_fracture``, ``proxy``,
``passive_time``, ``save_every``; circle, glue and soft handles and label handles (``label``);
OBJ extension lines (labels, velocities, edges; :data:`cloth.io.arcsim_mesh.ARCSIM_OBJ_EXTENSIONS`).
``obstacle_friction`` is an error pointing at ``obs_friction`` (neither version reads it).

ARCSim 0.2.1's 17 example configs: crush, crush2, dress-blue, dress-yellow, flag, sleeve, sphere,
square and square-pop load; crumple, crumple-pnas and tshirt fail on plasticity (``yield_curv``),
cylinder and fold on node labels in their meshes (and circle handles, plasticity), dart on OBJ
edges (and plasticity), karate on its empty .mot file in the public snapshot (it loads with a
readable one), sphere-annotated on ``handles[0].vertices`` (ARCSim reads ``nodes``: ARCSim itself
aborts on that file). Of 0.3.1's: flag, sphere, square and square-pop load; paper-tearing and
sphere-break fail on ``remeshing_frames`` (read by neither version).
"""

from __future__ import annotations

from cloth.io.arcsim_json import ArcsimConfigError
from cloth.io.arcsim_motion import ArcsimMotion, Transformation
from cloth.io.arcsim_schema import (
    MAGIC_031,
    MAGIC_DEFAULTS,
    MODULES,
    ArcsimCloth,
    ArcsimConfig,
    ArcsimHandle,
    ArcsimMaterial,
    ArcsimMotfile,
    ArcsimObstacle,
    ArcsimRemeshing,
    ArcsimVelocity,
    ArcsimWind,
)
from cloth.io.arcsim_sections import load_arcsim_config

__all__ = [
    "ArcsimCloth", "ArcsimConfig", "ArcsimConfigError", "ArcsimHandle", "ArcsimMaterial", "ArcsimMotfile",
    "ArcsimMotion", "ArcsimObstacle", "ArcsimRemeshing", "ArcsimVelocity", "ArcsimWind", "MAGIC_031",
    "MAGIC_DEFAULTS", "MODULES", "Transformation", "load_arcsim_config",
]
