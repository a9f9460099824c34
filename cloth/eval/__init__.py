"""Evaluation after the fact: the screen-space error measures that compare a run's saved states
with a reference's (through the z-buffer rasteriser of cloth.view.zbuffer), and the shape
difference of two meshes of one cloth (``surface``: surface distance, bounding boxes). Never
imported by the simulation.

May import: ``cloth.core``, ``cloth.collision`` (BVH, closest points), ``cloth.view`` (camera, z-buffer)
and ``cloth.io`` (states).
"""
