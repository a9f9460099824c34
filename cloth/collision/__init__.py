"""Everything that keeps cloth out of obstacles and out of itself: bounding-volume hierarchies,
CCD primitives, analytic and triangle-mesh obstacles, node contact, the self-collision pass
(candidates, proximity and CCD response, rigid impact zones) and untangling of crossings.

    bvh          box tree, overlapping box pairs        nearest      closest triangle (branch and bound)
    ccd          primitives: closest points, CCD cubic  obstacles    analytic obstacles (plane, sphere, capsules)
    meshobstacle TriangleMeshObstacle                   meshkernels  its numba kernels (refit, signed query)
    contact      node contact with obstacles            untangle     removing crossings (contour minimisation)
    selfcollision  the step's collision pass (drivers): candidates -> response -> impactzones

May import: ``cloth.core``; never ``cloth.remeshing``, ``cloth.view``, ``cloth.scenes``,
``cloth.eval`` or ``cloth.io``.
"""
