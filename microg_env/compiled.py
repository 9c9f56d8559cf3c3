"""Compiled per-rig loops (numba): one decorator, so every kernel is compiled and cached alike.

The control period's work per rig is a few dozen scalar operations; as NumPy calls on arrays of one
element it costs several times the physics. Kernels written as loops over the rigs are compiled
once per machine (the machine code is cached beside the module, or in numba's user cache where that
is not writable) and serve one rig and a batch of rigs alike.
"""

from __future__ import annotations

import numba

#: Compile a function of arrays and scalars to machine code (no Python objects inside).
jit = numba.njit(cache=True, nogil=True)


def ufunc(signature: str):
    """Compile a scalar function of float64s into a NumPy ufunc (``signature``, e.g.
    ``"float64(float64)"``), callable on scalars and arrays and from :data:`jit` kernels."""
    return numba.vectorize([signature], cache=True)
