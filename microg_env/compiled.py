"""Compiled per-rig loops (numba): one decorator, so every kernel is compiled and cached alike.

The control period's work per rig is a few dozen scalar operations; as NumPy calls on arrays of one
element it costs several times the physics. Kernels written as loops over the rigs are compiled
once per machine (the machine code is cached beside the module, or in numba's user cache where that
is not writable) and serve one rig and a batch of rigs alike.
"""

from __future__ import annotations

import glob
import os

import llvmlite.binding as llvm
import mujoco
import numba
from numba.core import types

#: Compile a function of arrays and scalars to machine code (no Python objects inside).
jit = numba.njit(cache=True, nogil=True)


def ufunc(signature: str):
    """Compile a scalar function of float64s into a NumPy ufunc (``signature``, e.g.
    ``"float64(float64)"``), callable on scalars and arrays and from :data:`jit` kernels."""
    return numba.vectorize([signature], cache=True)


def _mujoco_library() -> str | None:
    """The MuJoCo shared library the Python bindings load (beside them in the package), if found."""
    folder = os.path.dirname(mujoco.__file__)
    for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        found = sorted(glob.glob(os.path.join(folder, pattern)))
        if found:
            return found[0]
    return None


def _step_function() -> types.ExternalFunction | None:
    library = _mujoco_library()
    if library is None:
        return None
    try:
        llvm.load_library_permanently(library)
    except RuntimeError:  # pragma: no cover - a library the JIT cannot load
        return None
    return types.ExternalFunction("mj_step", types.void(types.uintp, types.uintp))


#: MuJoCo's C ``mj_step(m, d)`` for kernels, called with the addresses of an ``MjModel`` and an
#: ``MjData`` (their ``_address``): the function ``mujoco.mj_step`` runs, without the Python call
#: (None where the library is not found; then no kernel steps physics). Outside the bindings' own
#: calls MuJoCo has no Python error handler: an error inside it (an exhausted arena, which this
#: rig's fixed-size model never reaches, or a Python ``mjcb_*`` callback that raises; the package
#: sets none) ends the process instead of raising.
mj_step = _step_function()
