"""The camera and the paper's view-dependent sizing: pinhole camera and frustum distance, camera
paths with cuts, the view factors and screen-space clamp (eqs 2-8, section 3.3), the z-buffer
rasteriser (shared with cloth.eval's accuracy measures) and the occlusion test built on it (not in
the paper), and the view-dependent remesh stage, which is the adaptive one with its sizing scaled
by the view.

May import: ``cloth.core``, ``cloth.remeshing`` (the stage it extends), ``cloth.collision``
(obstacles); never ``cloth.scenes``,
``cloth.eval`` or ``cloth.io``.
"""
