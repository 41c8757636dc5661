"""The batch driver: the only place that knows about batches and threads.

A kernel (:mod:`multibody.kernels`) computes one state: ``kernel(joints, reals, frames, x0, x1, x2, x3,
out, workspace)`` with the compiled tree's arrays, a table of frame rows (:mod:`multibody.tree`), up
to four per-state input vectors (length 0 when unused), a per-state output ``out (rows, cols)`` and
a workspace. :func:`evaluate` broadcasts the leading batch axes of the inputs, allocates the output
and the workspaces, and runs the kernel on one state directly or on many states in parallel, each
thread over its own contiguous share of the states with its own workspace. The states are
independent, so any number of threads gives the same numbers.

The thread count is Numba's (``NUMBA_NUM_THREADS`` bounds it); :func:`set_num_threads` and the
environment variable ``MULTIBODY_NUM_THREADS`` set it.
"""

from __future__ import annotations

import math
import os

import numba
import numpy as np
from numba import njit, prange

from .kernels import rnea

#: Kernel codes of the parallel driver (one compiled loop serves them all)
INVERSE_DYNAMICS, JOINT_REACTION_FORCES = 0, 1

_KERNELS = {INVERSE_DYNAMICS: rnea.inverse_dynamics, JOINT_REACTION_FORCES: rnea.joint_reaction_forces}

_EMPTY = np.zeros(0)


def set_num_threads(n: int) -> None:
    """Use ``n`` threads for batches (at most ``numba.config.NUMBA_NUM_THREADS``)."""
    numba.set_num_threads(int(n))


def get_num_threads() -> int:
    """The number of threads batches run on."""
    return numba.get_num_threads()


if os.environ.get("MULTIBODY_NUM_THREADS"):
    set_num_threads(int(os.environ["MULTIBODY_NUM_THREADS"]))


@njit(cache=True)
def _kernel(code, joints, reals, frames, x0, x1, x2, x3, out, ws):
    if code == INVERSE_DYNAMICS:
        rnea.inverse_dynamics(joints, reals, frames, x0, x1, x2, x3, out, ws)
    elif code == JOINT_REACTION_FORCES:
        rnea.joint_reaction_forces(joints, reals, frames, x0, x1, x2, x3, out, ws)


@njit(cache=True, parallel=True)
def _batch(code, joints, reals, frames, X0, X1, X2, X3, OUT, workspace_size, shares):
    n = OUT.shape[0]
    for share in prange(shares):
        ws = np.empty(workspace_size)
        for s in range(share * n // shares, (share + 1) * n // shares):
            # an input of one row is shared by every state
            _kernel(code, joints, reals, frames, X0[s if X0.shape[0] > 1 else 0], X1[s if X1.shape[0] > 1 else 0],
                    X2[s if X2.shape[0] > 1 else 0], X3[s if X3.shape[0] > 1 else 0], OUT[s], ws)


def _as_kernel_input(x):
    """A writable C-contiguous float64 array (one compiled signature for every caller)."""
    if x is None:
        return _EMPTY
    if not (x.flags.c_contiguous and x.flags.writeable):
        x = np.array(x, order="C")
    return x


def evaluate(code, tree, frames, inputs, out_shape, batch, workspace_size):
    """Run kernel ``code`` on every state of ``batch``.

    ``inputs``: up to four arrays ``(..., k)`` whose leading axes broadcast to ``batch`` (``None``: unused);
    ``frames``: frame rows ``(m, 13)``; ``out_shape``: ``(rows, cols)`` of one state's output.
    Returns ``batch + out_shape``.
    """
    inputs = tuple(inputs) + (None,) * (4 - len(inputs))
    if batch == ():
        out = np.empty(out_shape)
        _KERNELS[code](tree.joints, tree.reals, frames, *map(_as_kernel_input, inputs), out,
                       np.empty(workspace_size))
        return out
    n = math.prod(batch)
    out = np.empty((n,) + tuple(out_shape))
    if n == 0:
        return out.reshape(batch + tuple(out_shape))
    rows = []
    for x in inputs:
        if x is None:
            rows.append(np.zeros((1, 0)))
        elif math.prod(x.shape[:-1]) == 1:
            rows.append(_as_kernel_input(x.reshape(1, x.shape[-1])))
        else:
            rows.append(_as_kernel_input(np.broadcast_to(x, batch + x.shape[-1:]).reshape(n, x.shape[-1])))
    _batch(code, tree.joints, tree.reals, frames, *rows, out, workspace_size, min(get_num_threads(), n))
    return out.reshape(batch + tuple(out_shape))
