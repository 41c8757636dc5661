"""The dynamics on CUDA arrays: the same kernel source, compiled for the GPU, one thread per state.

When ``q`` is a CUDA array (CuPy, PyTorch or Numba device arrays, anything with
``__cuda_array_interface__``; the simulator's arrays have ``__cuda_ndarray__``), :mod:`multibody.dynamics`
hands the call here, and the result is a device array: of CuPy or PyTorch when ``q`` is one, else a
Numba device array (each of the others takes it without a copy through ``__cuda_array_interface__``).

How the same source runs on the GPU: each launcher here is a ``numba.cuda.jit`` kernel that calls the
CPU kernel (an ``@njit`` dispatcher) for the states of its thread. Numba's CUDA typing context treats
a CPU dispatcher called from device code as a device function and compiles its Python source
(``py_func``) again for the CUDA target, with the same options (``error_model="numpy"``), and so
on down through the helpers of :mod:`multibody.kernels.spatial`, ``joints`` and ``placement``
(``numba/cuda/target.py``, ``CUDATypingContext.resolve_value_type``). No kernel code is copied. The
first launch of each kernel in a process compiles it (seconds; the CUDA code is not cached on disk).

A launcher runs ``min(states, MAX_THREADS)`` threads; a thread computes the states
``s = thread, thread + threads, …`` (one state per thread up to ``MAX_THREADS`` states) in one
workspace row of its own, from a device array ``(threads, workspace)`` allocated per call. Inputs
with one row serve every state, as in :func:`multibody.driver.evaluate`.

Limits: float64 only (the kernels' literals and the compiled tree are float64, so float32 inputs would
still be computed in float64: a ``dtype=float32`` option is not offered); inputs must be C-contiguous
float64 arrays whose leading axes are the batch's or of one state; values are not validated on the
device (a quaternion is not checked for unit norm; a non-finite input, or a singular mass matrix in
forward dynamics, gives NaN where the CPU path warns or raises). ``numba.cuda`` is imported on first use
only. This lives in the ``[gpu]`` extra (``numba-cuda``).

:func:`multibody.simulate` given CUDA arrays ``q0``, ``v0`` runs the compiled fixed-step run of
:mod:`multibody.kernels.stepping` the same way, one trajectory per thread (:func:`advance_batch`): the launcher
calls :func:`multibody.kernels.stepping.advance`, which the CUDA target compiles with everything beneath it (the
chart maps, ABA or the constrained step and the projection of :mod:`multibody.kernels.kkt`, the PD law), and a
``numba.njit`` controller as a device function. A contact batch runs its Moreau–Jean steps the same way
(:func:`contact_batch`: :func:`multibody.kernels.timestepping.run`, one trajectory per thread).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

#: Most threads a launch runs; a larger batch runs several states per thread (bounds the workspace).
MAX_THREADS = 1 << 18
#: Threads per block.
THREADS_PER_BLOCK = 128

_CACHE_KEY = "_multibody_device_trees"


def is_device_array(x) -> bool:
    """Whether ``x`` is a CUDA array: ``__cuda_array_interface__`` (CuPy, PyTorch, Numba) or the
    simulator's ``__cuda_ndarray__``. Never true of a NumPy array (a CPU PyTorch tensor, whose
    ``__cuda_array_interface__`` raises, is not one either)."""
    if type(x) is np.ndarray or x is None:
        return False
    try:
        return hasattr(x, "__cuda_array_interface__") or hasattr(x, "__cuda_ndarray__")
    except Exception:  # e.g. PyTorch's TypeError for a CPU tensor
        return False


#: ``numba.cuda``, imported on first use: a global of this module, which the launchers read (the CUDA
#: simulator swaps a kernel's globals that are ``numba.cuda``, not its closure's).
cuda = None


def _cuda():
    global cuda
    if cuda is None:
        from numba import cuda as module
        cuda = module
    return cuda


class DeviceTree(NamedTuple):
    """A compiled tree's arrays on one CUDA device, and an empty ``(1, 0)`` row table for unused inputs."""

    joints: object
    reals: object
    bodies: object
    empty: object
    nq: int
    nv: int


def device_tree(model) -> DeviceTree:
    """``model.tree`` on the current CUDA device, copied once per model and device.

    The copy is kept in the model's own ``__dict__`` (as ``functools.cached_property`` keeps
    ``model.tree``), keyed by device: it lives and dies with the model, and no module-level table
    keyed by ``id`` outlives it or mistakes a new model for a freed one. (:class:`~multibody.tree.CompiledTree`
    is a ``NamedTuple`` and holds no attributes of its own.)"""
    cuda = _cuda()
    key = getattr(cuda.current_context().device, "id", 0)
    trees = model.__dict__.setdefault(_CACHE_KEY, {})
    tree = trees.get(key)
    if tree is None:
        t = model.tree
        tree = trees[key] = DeviceTree(cuda.to_device(t.joints), cuda.to_device(t.reals), cuda.to_device(t.bodies),
                                       cuda.to_device(np.zeros((1, 0))), t.nq, t.nv)
    return tree


def _host_view(x):
    """Under the CUDA simulator: a NumPy view of a simulated device array, which writes through to it (by its public
    ``__array__``); ``x`` itself for a NumPy array or scalar, a number or a function."""
    return np.asarray(x) if hasattr(x, "__array__") and not isinstance(x, (np.ndarray, np.generic)) else x


def _simulated(kernel):
    """The CPU kernel, called on the NumPy arrays behind the simulator's device arrays: under
    ``NUMBA_ENABLE_CUDASIM=1`` a launcher runs as Python and Numba's CPU dispatchers cannot type the
    simulator's arrays. The arithmetic is then the CPU kernel's; what the simulator checks is the launch
    (threads, rows, broadcasting, workspaces, shapes)."""
    def call(*args):
        return kernel(*[_host_view(a) for a in args])
    return call


def _launch_source(kernel):
    _cuda()

    def launch(joints, reals, frames, X0, X1, X2, X3, OUT, WS):
        thread = cuda.grid(1)
        for s in range(thread, OUT.shape[0], cuda.gridsize(1)):
            # an input of one row serves every state, as in driver.evaluate's batches
            kernel(joints, reals, frames, X0[s if X0.shape[0] > 1 else 0], X1[s if X1.shape[0] > 1 else 0],
                   X2[s if X2.shape[0] > 1 else 0], X3[s if X3.shape[0] > 1 else 0], OUT[s], WS[thread])

    return launch


@functools.lru_cache(maxsize=None)
def launcher(kernel):
    """The ``cuda.jit`` launcher of a CPU kernel (one per kernel, compiled lazily on first launch)."""
    from numba import config
    cuda = _cuda()
    return cuda.jit(_launch_source(_simulated(kernel) if config.ENABLE_CUDASIM else kernel))


def _as_device(x, name):
    """A CUDA array as a Numba device array (no copy); a host array is copied to the device."""
    cuda = _cuda()
    if not is_device_array(x):
        x = cuda.to_device(np.ascontiguousarray(x, dtype=np.float64))
    elif not hasattr(x, "__cuda_ndarray__"):
        x = cuda.as_cuda_array(x)
    if np.dtype(x.dtype) != np.float64:
        raise TypeError(f"{name} on the GPU must be float64, got {np.dtype(x.dtype)} (float32 is not offered: the "
                        "kernels compute in float64)")
    if x.ndim == 0:
        raise ValueError(f"{name} must have at least one axis")
    return x


def check(inputs):
    """``inputs``: ``(name, array or None, size)`` triples (``size``: the last axis, or a tuple of the trailing
    axes) -> the device arrays flattened to ``(..., k)`` (``None`` kept) and their common batch shape."""
    arrays, shapes = [], []
    for name, x, size in inputs:
        if x is None:
            arrays.append(None)
            continue
        x = _as_device(x, name)
        trailing = size if isinstance(size, tuple) else (size,)
        shape = tuple(x.shape)
        if len(shape) < len(trailing) or shape[len(shape) - len(trailing):] != trailing:
            raise ValueError(f"{name} must have shape (..., {', '.join(map(str, trailing))}), got {shape}")
        lead = shape[:len(shape) - len(trailing)]
        arrays.append(x.reshape(lead + (math.prod(trailing),)) if len(trailing) > 1 else x)
        shapes.append((name, lead))
    try:
        batch = np.broadcast_shapes(*[lead for _, lead in shapes])
    except ValueError:
        raise ValueError("the leading (batch) axes of " + ", ".join(f"{n} {s}" for n, s in shapes)
                         + " do not broadcast") from None
    for name, lead in shapes:
        if math.prod(lead) != 1 and lead != batch:
            raise ValueError(f"on the GPU each input's leading axes must be the batch's {batch} or of one state: "
                             f"{name} has {lead}")
    return arrays, batch


def _grid(count):
    """``(blocks, threads)`` of a launch over ``count`` states or trajectories: at most :data:`MAX_THREADS` threads
    in blocks of :data:`THREADS_PER_BLOCK`, ``threads`` the workspace rows it needs (one per thread)."""
    blocks = -(-min(count, MAX_THREADS) // THREADS_PER_BLOCK)
    return blocks, blocks * THREADS_PER_BLOCK


def evaluate_device(kernel, tree: DeviceTree, inputs, out_shape, batch=()):
    """Run ``kernel`` on every state of ``batch`` on the GPU: ``-> device array batch + out_shape``.

    Mirrors :func:`multibody.driver.evaluate`: ``tree`` from :func:`device_tree`; ``inputs``: up to four
    C-contiguous float64 device arrays ``(..., k)``, each of the batch's leading axes or of one state
    (``None``: unused); ``out_shape``: ``(rows, cols)`` of one state's output."""
    from .driver import kernel_workspace_size
    cuda = _cuda()
    n = math.prod(batch)
    rows = []
    for x in tuple(inputs) + (None,) * (4 - len(inputs)):
        if x is None:
            rows.append(tree.empty)
        else:
            *lead, k = tuple(x.shape)  # (the simulator's shapes take no negative index)
            rows.append(x.reshape((1, k)) if math.prod(lead) == 1 else x.reshape((n, k)))
    out = cuda.device_array((n,) + tuple(out_shape), dtype=np.float64)
    if n:
        blocks, threads = _grid(n)
        workspace = cuda.device_array((threads, max(1, kernel_workspace_size(kernel, tree.joints.shape[0], tree.nv))))
        launcher(kernel)[blocks, THREADS_PER_BLOCK](tree.joints, tree.reals, tree.bodies, *rows, out, workspace)
    return out.reshape(tuple(batch) + tuple(out_shape))


def like(result, template):
    """``result`` (a Numba device array) as an array of ``template``'s library when that is CuPy or
    PyTorch (no copy, through ``__cuda_array_interface__``), else as it is."""
    module = type(template).__module__.split(".")[0]
    if module == "cupy":
        import cupy
        return cupy.asarray(result)
    if module == "torch":
        import torch
        return torch.as_tensor(result, device=template.device)
    return result


# ----------------------------------------------------------------------------- the compiled run of simulate


def to_host(x):
    """A CUDA array's values as a NumPy array (a copy from the device)."""
    cuda = _cuda()
    if not hasattr(x, "__cuda_ndarray__"):
        x = cuda.as_cuda_array(x)
    return x.copy_to_host()


def run_source(advance, controller):
    _cuda()

    def launch(joints, reals, frames, program, times, plan, control, states, io, rows, WS):
        thread = cuda.grid(1)
        for j in range(thread, rows.shape[0], cuda.gridsize(1)):
            r = rows[j]
            # one control row serves every trajectory, as in the CPU's loop over trajectories
            advance(controller, joints, reals, frames, program, times, plan, control[r if control.shape[0] > 1 else 0],
                    states[r], io[r], WS[thread])

    return launch


@functools.lru_cache(maxsize=None)
def _uncontrolled_launcher(source, kernel):
    return _cuda().jit(source(kernel, None))


def run_launcher(source, kernel, function, pointer, types):
    """The ``cuda.jit`` launcher ``source(kernel, controller)`` of a run (:func:`run_source` of
    :func:`multibody.kernels.stepping.advance`, :func:`contact_run_source` of
    :func:`multibody.kernels.timestepping.run`), compiled on first launch: with the ``numba.njit`` controller
    ``function`` as a device function, or with none (``function`` ``None``: the plan's controller is none, constant
    or :class:`multibody.PD`). The launcher of a controller lives in the controller's ``__dict__`` (as
    :func:`device_tree`'s copy in the model's): it is compiled once per controller, and dies with it.

    Under ``NUMBA_ENABLE_CUDASIM=1`` the launcher calls the CPU's ``kernel`` compiled for the argument ``types``
    with the first-class controller ``pointer``, as :func:`_simulated` does for the kernels."""
    from numba import config

    from . import driver
    cuda = _cuda()
    if config.ENABLE_CUDASIM:
        return cuda.jit(source(_simulated(driver.entry_point(kernel, types)), pointer))
    if function is None:
        return _uncontrolled_launcher(source, kernel)
    key = f"_multibody_cuda_{source.__name__}"
    launcher = function.__dict__.get(key)
    if launcher is None:
        launcher = function.__dict__[key] = cuda.jit(source(kernel, function))
    return launcher


def launch(run, states, io, rows):
    """The steps ``io[r, IO_STEP]`` up to ``io[r, IO_STOP]`` of the trajectories ``rows`` of a compiled ``run`` on the
    GPU, one trajectory per thread (:func:`multibody.kernels.stepping.advance`, each status in its ``io`` row), on
    device arrays: ``states (N, n, nq + nv)`` and ``io (N, io_size)`` float64, filled in place, and ``rows (k,)``
    int64. Returns at once (the launch is asynchronous); a thread runs ``rows[j]`` for ``j = thread, thread +
    threads, …`` in a workspace row of its own."""
    from . import integrators
    from .kernels import stepping
    cuda = _cuda()
    if not rows.shape[0]:
        return
    blocks, threads = _grid(rows.shape[0])
    workspace = cuda.device_array((threads, max(1, run.workspace)))
    arrays = [cuda.to_device(np.ascontiguousarray(x)) for x in (run.tree.joints, run.tree.reals, run.frames,
                                                                 run.program, run.times, run.plan, run.control)]
    function = run.controller.function if run.kind == stepping.FUNCTION else None
    launcher = run_launcher(run_source, stepping.advance, function, run.pointer,
                            dict(integrators.ENTRY_POINTS)[stepping.advance])
    launcher[blocks, THREADS_PER_BLOCK](*arrays, states, io, rows, workspace)


def advance_batch(run, states, io, rows):
    """:meth:`multibody.integrators.CompiledRun.advance_batch` on the GPU: host arrays ``states (N, n, nq + nv)``,
    ``io (N, io_size)`` (float64) copied to the device, :func:`launch` of the trajectories ``rows`` (int64), and
    both copied back in place."""
    cuda = _cuda()
    device_states, device_io = cuda.to_device(states), cuda.to_device(io)
    launch(run, device_states, device_io, cuda.to_device(np.ascontiguousarray(rows, dtype=np.int64)))
    device_states.copy_to_host(states)
    device_io.copy_to_host(io)


# ----------------------------------------------------------------------------- the contact run of simulate


def contact_run_source(run, controller):
    """The source of the contact run's launcher: ``run`` (:func:`multibody.kernels.timestepping.run`) for the
    trajectories ``thread, thread + threads, …`` of the batch, each in its own workspace rows ``WS[thread]``,
    ``IWS[thread]``; one control row serves every trajectory, as in the CPU's loop over trajectories."""
    _cuda()

    def launch(joints, reals, frames, program, geometry, vertices, plan, control, times, states, records, summaries,
               io, WS, IWS):
        thread = cuda.grid(1)
        for r in range(thread, states.shape[0], cuda.gridsize(1)):
            run(controller, joints, reals, frames, program, geometry, vertices, plan,
                control[r if control.shape[0] > 1 else 0], times, states[r], records[r], summaries[r], io[r],
                WS[thread], IWS[thread])

    return launch


def contact_batch(launcher, arrays, workspace, int_workspace, states, records, summaries, io):
    """The contact run of every trajectory on the GPU, one per thread: ``arrays`` (the tree's joints and reals, the
    program's frames, program, geometry and vertices, the plan, the control rows and the times, host arrays) and the
    host arrays ``states (N, n, nq + nv)``, ``records (N, n, rows, columns)``, ``summaries (N, n, columns)`` and
    ``io (N, io_size)`` copied to the device, the launch, and the last four copied back in place. ``workspace``,
    ``int_workspace``: the floats and integers of one thread's workspace rows."""
    cuda = _cuda()
    if not states.shape[0]:
        return
    blocks, threads = _grid(states.shape[0])
    ws = cuda.device_array((threads, max(1, workspace)))
    iws = cuda.to_device(np.zeros((threads, max(1, int_workspace)), dtype=np.int64))
    inputs = [cuda.to_device(np.ascontiguousarray(x)) for x in arrays]
    outputs = [cuda.to_device(x) for x in (states, records, summaries, io)]
    launcher[blocks, THREADS_PER_BLOCK](*inputs, *outputs, ws, iws)
    for device, host in zip(outputs, (states, records, summaries, io)):
        device.copy_to_host(host)

