"""Evaluation after the fact: the z-buffer rasteriser and the screen-space error measures that
compare a run's saved states with a reference's. Never imported by the simulation.

May import: ``cloth.core``, ``cloth.collision`` (BVH, closest points), ``cloth.view`` (camera)
and ``cloth.io`` (states).
"""
