"""The data every stage shares: the cloth mesh (struct of arrays, two refresh points), the
material, the scene (what a simulation is given, with its declared effects) and the schemas of
the per-frame record.

May import: numpy, scipy and the standard library only; nothing else of ``cloth``.
"""
