"""The batch driver: the only place that knows about batches and threads.

A kernel (:mod:`multibody.kernels`) computes one state: ``kernel(joints, reals, frames, x0, x1, x2, x3,
out, workspace)`` with the compiled tree's arrays, a table of frame rows (:mod:`multibody.tree`), up
to four per-state input vectors (length 0 when unused), a per-state output ``out (rows, cols)``
written in place and a workspace. :func:`evaluate` broadcasts the leading batch axes of the inputs,
allocates the output and the workspaces, and runs the kernel on one state directly or on many
states in parallel: each thread takes its own contiguous share of the states and its own
workspace. The states are independent, so any number of threads gives the same numbers.

Batches run on Numba's threads: :func:`set_num_threads` or the environment variable
``MULTIBODY_NUM_THREADS`` sets how many (at most ``NUMBA_NUM_THREADS``, the cores by default); a batch
of fewer than ``STATES_PER_THREAD`` states per thread runs on fewer of them.
"""

from __future__ import annotations

import importlib
import math
import os
import subprocess
import sys

import numba
import numpy as np
from numba import njit, prange
from numba.core.dispatcher import Dispatcher
from numba.core.types.function_type import CompileResultWAP

from .kernels import (aba, centroidal, configuration, constraints, coriolis, crba, derivatives, energy, ik, integration,
                      kinematics, kkt, lagrangian, rnea, variational)

#: Every kernel the driver runs.
_KERNELS = (
    rnea.inverse_dynamics, rnea.joint_reaction_forces, crba.mass_matrix, aba.forward_dynamics,
    crba.inverse_mass_matrix, coriolis.coriolis_matrix, energy.kinetic_energy, energy.potential_energy,
    kinematics.frame_placements, kinematics.frame_jacobian, kinematics.frame_jacobian_time_variation,
    kinematics.frame_motions, configuration.integrate, configuration.difference, configuration.configuration_rate,
    configuration.chart, configuration.chart_coordinates, configuration.chart_rate, configuration.velocity_alignment,
    configuration.velocity_coupling, configuration.chart_magnitude, configuration.normalize, kkt.constrained_accelerations,
    constraints.constraint_levels, integration.chart_derivative, integration.constrained_chart_derivative,
    derivatives.inverse_dynamics_derivatives, derivatives.forward_dynamics_derivatives, centroidal.center_of_mass,
    centroidal.centroidal_momentum, centroidal.centroidal_map, centroidal.centroidal_map_time_variation,
    ik.inverse_kinematics, lagrangian.lagrangian_terms, variational.midpoint_iterate)
_WORKSPACE = {kernel: module.workspace_size for module in (rnea, crba, aba, coriolis, energy, kinematics, configuration,
                                                           derivatives, centroidal, lagrangian)
              for kernel in _KERNELS if getattr(kernel, "py_func", kernel).__module__ == module.__name__}


def compiled_before(kernels=None) -> bool:
    """Whether this machine has the compiled code of ``kernels`` (default: every kernel) on disk
    already (Numba's cache index of each), so that a first run can say it is compiling."""
    for kernel in _KERNELS if kernels is None else kernels:
        cache_file = getattr(getattr(kernel, "_cache", None), "_cache_file", None)
        if cache_file is None or not os.path.isfile(cache_file._index_path):
            return False
    return True


def compile_kernels(kernels=None, processes=None) -> None:
    """Compile the single-call machine code (:func:`_direct`) of those ``kernels`` (default: every kernel)
    that Numba's on-disk cache lacks, sharing them among ``processes`` (default: the cores this process
    may use), so that later processes load them in a fraction of a second.

    Numba compiles in one thread, so a cold cache on a machine with several cores compiles faster this
    way: this process takes every ``processes``-th kernel of the list and a worker process each of the
    other shares, then this process waits for them. Kernels share helpers, which the workers may
    compile more than once; a worker that fails leaves its kernels to be compiled on first use, as
    without this call. Does nothing under ``NUMBA_DISABLE_JIT=1``."""
    missing = [kernel for kernel in (_KERNELS if kernels is None else kernels)
               if isinstance(kernel, Dispatcher) and not compiled_before((kernel,))]
    if processes is None:
        processes = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    processes = max(1, min(int(processes), len(missing)))
    shares = [missing[k::processes] for k in range(processes)]
    # (the workers import this very package, wherever it was imported from here)
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (package_root, os.environ.get("PYTHONPATH"))))}
    workers = [subprocess.Popen([sys.executable, "-c", f"from multibody.driver import _compile_named; "
                                 f"_compile_named({[_qualified_name(kernel) for kernel in share]!r})"],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for share in shares[1:]]
    try:
        for kernel in shares[0]:
            _direct(kernel)
    except BaseException:
        for worker in workers:  # (interrupted: the workers' compiling is no longer wanted)
            worker.kill()
        raise
    finally:
        for worker in workers:
            worker.wait()


def _qualified_name(kernel) -> str:
    """``"module:function"`` of a kernel, the name a worker process of :func:`compile_kernels` imports."""
    return f"{kernel.py_func.__module__}:{kernel.py_func.__qualname__}"


def _compile_named(names) -> None:
    """A worker of :func:`compile_kernels`: compile the kernels named ``"module:function"``."""
    for name in names:
        module, function = name.split(":")
        _direct(getattr(importlib.import_module(module), function))


def set_num_threads(n: int) -> None:
    """Run batches on ``n`` threads (``1 ≤ n ≤ numba.config.NUMBA_NUM_THREADS``)."""
    numba.set_num_threads(int(n))


def get_num_threads() -> int:
    """The number of threads batches run on."""
    return numba.get_num_threads()


if os.environ.get("MULTIBODY_NUM_THREADS"):
    set_num_threads(int(os.environ["MULTIBODY_NUM_THREADS"]))


@njit(cache=True, parallel=True, error_model="numpy")
def _batch(kernel, joints, reals, frames, X0, X1, X2, X3, OUT, workspace_size, shares):
    # `kernel` is a first-class function (see _loop_kernel): one compiled loop serves every kernel
    n = OUT.shape[0]
    for share in prange(shares):
        ws = np.empty(workspace_size)
        for s in range(share * n // shares, (share + 1) * n // shares):
            # an input of one row serves every state
            kernel(joints, reals, frames, X0[s if X0.shape[0] > 1 else 0], X1[s if X1.shape[0] > 1 else 0],
                   X2[s if X2.shape[0] > 1 else 0], X3[s if X3.shape[0] > 1 else 0], OUT[s], ws)


_LOOP_KERNELS = {}


def _loop_kernel(kernel, joints, reals, frames, X0, X1, X2, X3, OUT, workspace):
    """``kernel`` as :func:`_batch` takes it: its machine code for the loop's argument types (the same
    code a single state runs), passed as a first-class function, a function pointer. The loop is then
    compiled once for every kernel, and no kernel is compiled again into a loop of its own (a
    specialization per kernel would compile the kernel's whole call tree twice more: the loop's
    body and the loop). Under ``NUMBA_DISABLE_JIT=1``: the Python function."""
    if not isinstance(kernel, Dispatcher):
        return kernel
    arrays = (joints, reals, frames, X0[0], X1[0], X2[0], X3[0], OUT[0], workspace)
    key = (kernel,) + tuple((a.flags.c_contiguous, a.flags.writeable) for a in arrays)  # all float64 but joints
    function = _LOOP_KERNELS.get(key)
    if function is None:
        types = tuple(numba.typeof(a) for a in arrays)
        kernel.compile(types)
        function = _LOOP_KERNELS[key] = CompileResultWAP(kernel.overloads[types])
    return function


#: Fewest states a batch gives each thread (the results do not depend on it).
STATES_PER_THREAD = 256

#: The input of a kernel's unused argument.
NO_INPUT = np.zeros(0)
_NO_ROWS = np.zeros((1, 0))
_UNUSED = (None, None, None, None)
_FLOAT = np.dtype(np.float64)


def contiguous(x):
    """``x`` as a C-contiguous float64 array (``None``: of length 0): one compiled signature serves every caller."""
    if x is None:
        return NO_INPUT
    if x.dtype is _FLOAT and x.flags.c_contiguous:
        return x
    return np.ascontiguousarray(x, dtype=np.float64)


def _rows(x, batch, n):
    """Input ``x (..., k)`` as ``(n, k)`` rows of the batch, or one row that serves every state: a
    writable C-contiguous float64 array (a read-only one would compile the loop again)."""
    if x is None:
        return _NO_ROWS
    x = x.reshape(1, -1) if math.prod(x.shape[:-1]) == 1 else np.broadcast_to(x, batch + x.shape[-1:]).reshape(n, -1)
    return x if x.dtype is _FLOAT and x.flags.c_contiguous and x.flags.writeable else np.array(x, np.float64, order="C")


def evaluate_one(kernel, tree, out_shape, x0=NO_INPUT, x1=NO_INPUT, x2=NO_INPUT, x3=NO_INPUT, frames=None, workspace=None):
    """``kernel`` on one state whose inputs ``x0 … x3`` are C-contiguous float64 vectors already (a
    length-0 vector for an unused one): ``-> out_shape``. The path of a single call, which has no
    batch to broadcast and so costs little more than the kernel; :func:`evaluate` takes anything else.
    ``frames`` (C-contiguous float64 rows) and ``workspace`` as :func:`evaluate`.

    The kernel's machine code is called without Numba's dispatch (:func:`_direct`), so the types
    above are the caller's to guarantee: every caller has checked them already, and a second look
    would cost as much as the kernel's own arithmetic on a small robot."""
    joints, reals, bodies, _, _, nv, nj = tree
    call = _SINGLE_CALLS.get((kernel, nj, nv))
    if call is None:
        size = _workspace_size(kernel, nj, nv) if kernel in _WORKSPACE else None  # (else always given)
        call = _SINGLE_CALLS[kernel, nj, nv] = (_direct(kernel), size)
    entry, size = call
    out = np.empty(out_shape)
    entry(joints, reals, bodies if frames is None else frames, x0, x1, x2, x3, out,
          np.empty(size if workspace is None else workspace))
    return out


#: ``(kernel, nj, nv) -> (entry point, workspace size)`` of single calls: one look-up per call.
_SINGLE_CALLS = {}


def _workspace_size(kernel, nj, nv):
    """Floats of workspace one state of ``kernel`` needs on a tree of ``nj`` joints and ``nv`` velocities."""
    return _WORKSPACE[kernel](nj, nv)


_DIRECT = {}
_TREE_INTS, _TREE_FLOATS = (numba.types.Array(numba.types.int64, 2, "C", readonly=True),
                            numba.types.Array(numba.types.float64, 2, "C", readonly=True))
_VECTOR, _MATRIX = numba.types.float64[::1], numba.types.float64[:, ::1]
#: The argument types of every single call: the tree's read-only arrays, then writable inputs and outputs.
#: Machine code does not depend on whether an array is writable, and no kernel writes its inputs.
_SINGLE_CALL_TYPES = (_TREE_INTS, _TREE_FLOATS, _TREE_FLOATS, _VECTOR, _VECTOR, _VECTOR, _VECTOR, _MATRIX, _VECTOR)


def _direct(kernel):
    """``kernel``'s compiled entry point for :data:`_SINGLE_CALL_TYPES`, compiled (or loaded from Numba's
    cache) on first use: a call that skips the dispatcher's look at every argument's type, a third of
    a small robot's single call. Under ``NUMBA_DISABLE_JIT=1``: the Python function."""
    entry = _DIRECT.get(kernel)
    if entry is None:
        if isinstance(kernel, Dispatcher):
            kernel.compile(_SINGLE_CALL_TYPES)
            entry = kernel.overloads[_SINGLE_CALL_TYPES].entry_point
        else:
            entry = kernel
        _DIRECT[kernel] = entry
    return entry


def vouches(out) -> bool:
    """Whether a kernel's output ``out`` shows that its inputs were finite: its first entry is finite
    (every kernel fills its whole output with NaN when an input is not:
    :func:`~multibody.kernels.spatial.nan_unless_finite`), or it has none. A single call checks its
    inputs' shapes and leaves their entries to this one look."""
    return out.size == 0 or math.isfinite(out.item(0))


def evaluate(kernel, tree, inputs, out_shape, batch=(), frames=None, workspace=None):
    """Run ``kernel`` on every state of ``batch``: ``-> batch + out_shape``.

    ``inputs``: up to four float arrays ``(..., k)`` whose leading axes broadcast to ``batch``
    (``None``: unused); ``out_shape``: ``(rows, cols)`` of one state's output; ``frames``: frame rows
    ``(m, 13)`` (default ``tree.bodies``); ``workspace``: floats of workspace per state, for a kernel
    whose need depends on more than the tree (default its module's ``workspace_size(nj, nv)``). A state
    with a non-finite input gets an output of NaN (every kernel ends with
    :func:`~multibody.kernels.spatial.nan_unless_finite`).
    """
    if not batch:
        return evaluate_one(kernel, tree, out_shape, *map(contiguous, inputs), frames=frames, workspace=workspace)
    frames = tree.bodies if frames is None else frames
    workspace = np.empty(_workspace_size(kernel, tree.njoints, tree.nv) if workspace is None else workspace)
    x0, x1, x2, x3 = inputs + _UNUSED[len(inputs):]
    n = math.prod(batch)
    out = np.empty((n,) + tuple(out_shape))
    if n == 1:  # one state with batch axes: the kernel directly, as for no batch axes
        kernel(tree.joints, tree.reals, frames, _rows(x0, batch, 1)[0], _rows(x1, batch, 1)[0], _rows(x2, batch, 1)[0],
               _rows(x3, batch, 1)[0], out[0], workspace)
    elif n:
        threads = get_num_threads()
        # A small batch runs on fewer threads: waking a sleeping thread costs more than it would compute.
        shares = max(1, min(threads, n // STATES_PER_THREAD))
        if shares < threads:
            numba.set_num_threads(shares)
        try:
            rows = (_rows(x0, batch, n), _rows(x1, batch, n), _rows(x2, batch, n), _rows(x3, batch, n))
            _batch(_loop_kernel(kernel, tree.joints, tree.reals, frames, *rows, out, workspace), tree.joints,
                   tree.reals, frames, *rows, out, workspace.size, shares)
        finally:
            if shares < threads:
                numba.set_num_threads(threads)
    return out.reshape(batch + tuple(out_shape))
