"""The dynamics of one implicit step: membrane (StVK, with the buckling filter of eqs 9-11) and
bending elements, the force terms that assemble them, the block-sparse assembly, the linear
solve and the implicit Euler integrator with contact constraints.

May import: ``cloth.core`` only.
"""
