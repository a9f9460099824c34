"""The scenes a run can build: the registry of scene builders (sheets; the paper's
characters and crowd), the mannequin with its motions, garments, and obstacle bodies as meshes.

May import: ``cloth.core``, ``cloth.collision`` (obstacles), ``cloth.view`` (camera paths) and
``cloth.io`` (garments and obstacle sequences from OBJ files); never ``cloth.simulation``.
"""
