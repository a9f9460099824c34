"""I/O at the edge: OBJ meshes and OBJ sequences, per-frame states, checkpoints and final states,
run manifests and atomic writes, Rerun recordings (behind a do-nothing recorder) and stills;
ARCSim's output folders, read for comparison (``arcsim_output``).

May import: ``cloth.core``, ``cloth.collision`` (obstacle shapes to save) and ``cloth.view``
(the camera of a still); never ``cloth.simulation``.
"""
