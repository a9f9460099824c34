"""Numba kernels of the remesher (:mod:`cloth.remeshing.remesh` is their Python driver).

They work on the capacity-sized arrays described in :mod:`cloth.remeshing.remesh`, half-edge
code h = 3*f + k for side k of face f (from fv[f, k] to fv[f, (k + 1) % 3]):

* :mod:`~cloth.remeshing.kernels.geometry`   edge size (eq 1), aspect ratio, world-space strain
* :mod:`~cloth.remeshing.kernels.halfedge`   connectivity primitives: local index, link, twin,
  vert ring, half-edge search, seam re-twinning, new face, canonical half-edge
* :mod:`~cloth.remeshing.kernels.flips`      anisotropic Delaunay test, flip, Lawson flip passes
* :mod:`~cloth.remeshing.kernels.splits`     edge split (both panels of a seam) and the split pass
* :mod:`~cloth.remeshing.kernels.collapses`  edge collapse with its tests, and the collapse pass

May import: numpy, numba and one another; nothing else of ``cloth`` (arrays in, arrays out).
"""
