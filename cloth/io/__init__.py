"""I/O at the edge: OBJ meshes and OBJ sequences, per-frame states, checkpoints and final states,
run manifests and atomic writes, Rerun recordings (behind a do-nothing recorder) and stills; ARCSim
scene configurations read into plain data (:mod:`cloth.io.arcsim`, with :mod:`cloth.io.arcsim_motion`,
:mod:`cloth.io.arcsim_mesh` and :mod:`cloth.io.arcsim_json`) and ARCSim's output folders, read for
comparison (:mod:`cloth.io.arcsim_output`).

May import: ``cloth.core``, ``cloth.collision`` (obstacle shapes to save) and ``cloth.view``
(the camera of a still); never ``cloth.simulation``.
"""
