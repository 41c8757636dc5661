"""Compiled kernels: one per-state implementation of each algorithm (see ``docs/architecture.md``).

Every kernel is a function of one state, compiled by Numba, that reads the model's compiled tree
(:mod:`multibody.tree`), its inputs and a workspace, and writes its output in place. Kernels keep to
the subset of Python that Numba's CUDA target also compiles: loops, scalar and tuple arithmetic,
array indexing and slicing; no allocation and no NumPy array functions.
"""
