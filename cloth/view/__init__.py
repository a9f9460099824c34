"""The camera and the paper's view-dependent sizing: pinhole camera and frustum distance, camera
paths with cuts, the view factors and screen-space clamp (eqs 2-8, section 3.3), and the
view-dependent remesh stage, which is the adaptive one with its sizing scaled by the view.

May import: ``cloth.core``, ``cloth.remeshing`` (the stage it extends); never ``cloth.scenes``,
``cloth.eval`` or ``cloth.io``.
"""
