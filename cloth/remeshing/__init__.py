"""Adaptive anisotropic remeshing (Narain et al. 2012): the physics sizing field (one function per
criterion), the remesh operations (split, flip, collapse: numba kernels apart from their driver),
the pop filter that relaxes a remeshed region, and the adaptive remesh stage of the frame loop.

May import: ``cloth.core``, ``cloth.physics`` (strain, internal forces for the pop filter) and
``cloth.collision`` (keeping a remesh free of crossings); never ``cloth.view``, ``cloth.scenes``,
``cloth.eval`` or ``cloth.io``.
"""
