"""The batch driver: the only place that knows about batches and threads.

A kernel (:mod:`multibody.kernels`) computes one state: ``kernel(joints, reals, frames, x0, x1, x2, x3,
out, workspace)`` with the compiled tree's arrays, a table of frame rows (:mod:`multibody.tree`), up
to four per-state input vectors (length 0 when unused), a per-state output ``out (rows, cols)``
written in place and a workspace. :func:`evaluate` broadcasts the leading batch axes of the inputs,
allocates the output (or takes the caller's, :func:`output`) and the workspaces, and runs the kernel
on one state directly or on many states in parallel: each thread takes its own contiguous share of
the states and its own workspace. The states are independent: any number of threads, same numbers.

Batches run on Numba's threads: :func:`set_num_threads` or the environment variable
``MULTIBODY_NUM_THREADS`` sets how many for the whole process (at most ``NUMBA_NUM_THREADS``, the cores by
default; a larger ``MULTIBODY_NUM_THREADS`` is lowered to it with a warning), whichever Python thread runs a
batch; a batch of fewer than ``STATES_PER_THREAD`` states per thread runs on fewer of them. Batches from
several Python threads run at once, except under Numba's ``workqueue`` threading layer (no OpenMP or TBB
found), which cannot: there they take turns.

A call that compiles a function of multibody, the first on a machine (Numba's on-disk cache has the machine
code afterwards), says so in one line on standard error, once per function and process; the environment
variable ``MULTIBODY_QUIET=1`` silences these lines.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import pickle
import subprocess
import sys
import threading
import warnings

import numba
import numpy as np
from numba import njit, prange
from numba.extending import is_jitted

from . import numba_hooks, spatial
from .numba_hooks import event

from .kernels import (aba, centroidal, configuration, constraints, coriolis, crba, derivatives, energy, ik, integration,
                      kinematics, kkt, lagrangian, rnea, stepping)

#: Every kernel the driver runs (``multibody compile --all`` compiles them).
ALL_KERNELS = (
    rnea.inverse_dynamics, rnea.joint_reaction_forces, crba.mass_matrix, aba.forward_dynamics,
    crba.inverse_mass_matrix, coriolis.coriolis_matrix, energy.kinetic_energy, energy.potential_energy,
    energy.mechanical_energy, kinematics.frame_placements, kinematics.frame_jacobian,
    kinematics.frame_jacobian_time_variation, kinematics.frame_motions, configuration.integrate,
    configuration.difference, configuration.configuration_rate,
    configuration.chart, configuration.chart_coordinates, configuration.chart_rate, configuration.velocity_alignment,
    configuration.velocity_coupling, configuration.chart_magnitude, configuration.normalize, kkt.constrained_accelerations,
    constraints.constraint_levels, integration.chart_derivative, integration.constrained_chart_derivative,
    derivatives.inverse_dynamics_derivatives, derivatives.forward_dynamics_derivatives, centroidal.center_of_mass,
    centroidal.centroidal_momentum, centroidal.centroidal_map, centroidal.centroidal_map_time_variation,
    ik.inverse_kinematics, lagrangian.lagrangian_terms, kkt.project,
    configuration.exponential_terms, configuration.coadjoint, stepping.pd_kernel, stepping.aligned_velocity,
    stepping.chart_state, kkt.solve_arrays, kkt.correction_arrays)
_WORKSPACE = {kernel: module.workspace_size for module in (rnea, crba, aba, coriolis, energy, kinematics, configuration,
                                                           derivatives, centroidal, lagrangian)
              for kernel in ALL_KERNELS if getattr(kernel, "py_func", kernel).__module__ == module.__name__}


def compiled_before(kernels=None) -> bool:
    """Whether this machine has the compiled code of ``kernels`` (default: every kernel) on disk
    already (:func:`multibody.numba_hooks.cached_on_disk` of each), so that a first run can say it is
    compiling. Each entry is a kernel (its single call, :data:`_SINGLE_CALL_TYPES`) or a pair ``(function,
    argument types)`` of a compiled loop (:data:`ENTRY_POINTS`). ``False`` under ``NUMBA_DISABLE_JIT=1``,
    where nothing is compiled."""
    return all(is_jitted(function) and numba_hooks.cached_on_disk(function, types)
               for function, types in map(_signature, ALL_KERNELS if kernels is None else kernels))


def _signature(entry):
    """``(function, argument types)`` of an entry of :func:`compile_kernels`: a kernel, or such a pair already."""
    return entry if isinstance(entry, tuple) else (entry, _SINGLE_CALL_TYPES)


def compile_kernels(kernels=None, processes=None) -> None:
    """Compile the machine code of those ``kernels`` (default: every kernel) that Numba's on-disk cache lacks,
    sharing them among ``processes`` (default: the cores this process may use), so that later processes load
    them in a fraction of a second. An entry is a kernel, compiled for its single call (:func:`entry_point`), or a
    pair ``(function, argument types)``, compiled for those types: a loop that Python calls (:data:`ENTRY_POINTS`,
    :data:`multibody.integrators.ENTRY_POINTS`) or a function passed to one as a first-class function.

    Numba compiles in one thread, so a cold cache on a machine with several cores compiles faster this
    way: this process takes every ``processes``-th kernel of the list and a worker process each of the
    other shares, then this process waits for them. Kernels share helpers, which the workers may
    compile more than once; a worker that fails leaves its kernels to be compiled on first use, as
    without this call. Does nothing under ``NUMBA_DISABLE_JIT=1``."""
    missing = [entry for entry in (ALL_KERNELS if kernels is None else kernels)
               if is_jitted(_signature(entry)[0]) and not compiled_before((entry,))]
    if processes is None:
        processes = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    processes = max(1, min(int(processes), len(missing)))
    shares = [missing[k::processes] for k in range(processes)]
    # (the workers import this very package, wherever it was imported from here)
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (package_root, os.environ.get("PYTHONPATH"))))}
    # (a worker gets the functions by name and their argument types pickled: Numba's types pickle, and a function
    # is found again in its module, whose dispatcher holds the cache)
    workers = [subprocess.Popen([sys.executable, "-c", "import pickle; from multibody.driver import _compile_named; "
                                 f"_compile_named(pickle.loads(bytes.fromhex({_named(share).hex()!r})))"],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for share in shares[1:]]
    # (the caller says that it compiles, for every share: no line per kernel of this one)
    _COMPILE_NOTICES.said.update(function.py_func for function, _ in map(_signature, shares[0]))
    try:
        for entry in shares[0]:
            _compile(*_signature(entry))
    except BaseException:
        for worker in workers:  # (interrupted: the workers' compiling is no longer wanted)
            worker.kill()
        raise
    finally:
        for worker in workers:
            worker.wait()


class _CompileNotices(event.Listener):
    """One line on standard error when a function of multibody starts compiling, once per function and
    process: a first call compiles for seconds. Numba's ``numba:compile`` event comes only when no
    machine code is in its on-disk cache, so a cached function says nothing; nor does a function
    compiled as part of another (a kernel's helpers). ``MULTIBODY_QUIET=1`` silences the lines."""

    def __init__(self):
        self.said = set()  # the Python functions of the lines said (or not wanted)
        self.depth = 0  # multibody compiles under way in this one (Numba compiles under one lock)

    @staticmethod
    def _ours(event_):
        function = getattr(event_.data["dispatcher"], "py_func", None)
        return function if getattr(function, "__module__", "").startswith("multibody.") else None

    def on_start(self, event_):
        function = self._ours(event_)
        if function is None:
            return
        if self.depth == 0 and function not in self.said:
            self.said.add(function)
            if os.environ.get("MULTIBODY_QUIET", "0") in ("", "0"):
                name = f"{function.__module__.removeprefix('multibody.')}.{function.__qualname__}"
                print(f"multibody: compiling {name} for this machine (first use; cached afterwards) ...",
                      file=sys.stderr, flush=True)
        self.depth += 1

    def on_end(self, event_):
        if self._ours(event_) is not None:
            self.depth -= 1


_COMPILE_NOTICES = _CompileNotices()
event.register("numba:compile", _COMPILE_NOTICES)


def qualified_name(kernel) -> str:
    """``"module:function"`` of a kernel (or of the function of a pair ``(function, types)``), the name a worker
    process of :func:`compile_kernels` imports."""
    function = _signature(kernel)[0].py_func
    return f"{function.__module__}:{function.__qualname__}"


def _named(entries) -> bytes:
    """The pickled ``[("module:function", argument types), ...]`` of entries of :func:`compile_kernels`."""
    return pickle.dumps([(qualified_name(function), types) for function, types in map(_signature, entries)])


def _compile_named(entries) -> None:
    """A worker of :func:`compile_kernels`: compile the functions named ``"module:function"`` for their argument
    types, ``[(name, types), ...]``."""
    for name, types in entries:
        module, function = name.split(":")
        _compile(getattr(importlib.import_module(module), function), types)


def _compile(function, types) -> None:
    """Compile ``function`` for ``types`` (or load it from Numba's cache): a kernel's single call as
    :func:`entry_point` keeps it, any other function as Numba keeps it (:func:`entry_point` keeps one entry per function)."""
    if types == _SINGLE_CALL_TYPES:
        entry_point(function)
    else:
        function.compile(types)


def set_num_threads(n: int) -> None:
    """Run batches on ``n`` threads (``1 ≤ n ≤ numba.config.NUMBA_NUM_THREADS``), for the whole process:
    a batch that any Python thread runs afterwards uses them.

    Raises:
        TypeError: ``n`` is not an integer.
        ValueError: ``n`` is out of that range.
    """
    global _num_threads
    _num_threads = _thread_count(n, "set_num_threads")


def get_num_threads() -> int:
    """The number of threads batches run on (in this Python thread, within :func:`local_num_threads`)."""
    local = getattr(_LOCAL, "num_threads", None)
    return _num_threads if local is None else local


@contextlib.contextmanager
def local_num_threads(n: int):
    """Within the ``with`` block, batches that the calling Python thread runs use ``n`` threads, whatever
    :func:`set_num_threads` set for the process: a Dask task's share of its host's cores
    (:mod:`multibody.distributed`), beside other tasks of the same process. ``n`` as :func:`set_num_threads`."""
    previous = getattr(_LOCAL, "num_threads", None)
    _LOCAL.num_threads = _thread_count(n, "local_num_threads")
    try:
        yield
    finally:
        _LOCAL.num_threads = previous


def _thread_count(n, caller) -> int:
    """``n`` as a thread count of batches, or the error that names it and ``caller``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise TypeError(f"{caller}: n must be an integer, got {n!r}")
    if not 1 <= n <= numba.config.NUMBA_NUM_THREADS:
        raise ValueError(f"{caller}: n must be between 1 and NUMBA_NUM_THREADS = {numba.config.NUMBA_NUM_THREADS} "
                         f"(the threads Numba starts), got {n}")
    return int(n)


def _environment_num_threads() -> int:
    """The thread count of ``MULTIBODY_NUM_THREADS``, at most ``NUMBA_NUM_THREADS``; all of those when unset."""
    most = numba.config.NUMBA_NUM_THREADS
    value = os.environ.get("MULTIBODY_NUM_THREADS", "").strip()
    if not value:
        return most
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"MULTIBODY_NUM_THREADS must be a whole number of threads, at least 1, got {value!r}")
    if n > most:
        warnings.warn(f"MULTIBODY_NUM_THREADS={n} is more than the {most} threads Numba starts (NUMBA_NUM_THREADS, "
                      f"the cores by default): batches run on {most}", RuntimeWarning, stacklevel=2)
    return min(n, most)


#: The process's thread count of batches (:func:`set_num_threads`); Numba's own count is per Python
#: thread, so each batch sets it from this one.
_num_threads = _environment_num_threads()
#: :func:`local_num_threads` of each Python thread.
_LOCAL = threading.local()


@njit(cache=True, parallel=True, error_model="numpy")
def _batch(kernel, joints, reals, frames, X0, X1, X2, X3, OUT, workspace_size, shares):
    # `kernel` is the machine code of a kernel's single call as a first-class function (first_class): one loop
    # serves every kernel, instead of a specialization per kernel that would compile its whole call tree twice more
    n = OUT.shape[0]
    for share in prange(shares):
        ws = np.empty(workspace_size)
        for s in range(share * n // shares, (share + 1) * n // shares):
            # an input of one row serves every state
            kernel(joints, reals, frames, X0[s if X0.shape[0] > 1 else 0], X1[s if X1.shape[0] > 1 else 0],
                   X2[s if X2.shape[0] > 1 else 0], X3[s if X3.shape[0] > 1 else 0], OUT[s], ws)


#: :func:`first_class` of each function, made on first use.
_FIRST_CLASS = {}


def first_class(function, types):
    """``function`` (a Numba dispatcher of multibody) compiled for the argument ``types``, as a first-class
    function: a value that compiled code whose argument is ``numba.types.FunctionType`` of that signature calls
    through a pointer, so that one compiled loop serves every such function (:func:`_batch`; the compiled run of
    :mod:`multibody.integrators`; :func:`multibody.numba_hooks.first_class`). Kept per function, for one signature
    each as :func:`entry_point` keeps its entry: making the value costs about 30 µs, and a compiled run asks for it
    at every chunk of steps. Under ``NUMBA_DISABLE_JIT=1``: the Python function."""
    pointer = _FIRST_CLASS.get(function)
    if pointer is None:
        pointer = _FIRST_CLASS[function] = numba_hooks.first_class(function, types)
    return pointer


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
    C-contiguous float64 array. An input that is one already, of the whole batch or of one row, is
    used as it is (reshaped, not copied), read-only or not: the loop runs one set of argument types
    (:data:`_BATCH_TYPES`), and no kernel writes its inputs."""
    if x is None:
        return _NO_ROWS
    k = x.shape[-1]
    if math.prod(x.shape[:-1]) == 1:
        return contiguous(x.reshape(1, k))
    return contiguous(x if x.shape[:-1] == batch else np.broadcast_to(x, batch + (k,))).reshape(n, k)


def evaluate_one(kernel, tree, out_shape, x0=NO_INPUT, x1=NO_INPUT, x2=NO_INPUT, x3=NO_INPUT, frames=None, workspace=None,
                 out=None):
    """``kernel`` on one state whose inputs ``x0 … x3`` are C-contiguous float64 vectors already (a
    length-0 vector for an unused one): ``-> out_shape``. The path of a single call, which has no
    batch to broadcast and so costs little more than the kernel; :func:`evaluate` takes anything else.
    ``frames`` (C-contiguous float64 rows) and ``workspace`` as :func:`evaluate`; ``out``: a C-contiguous
    float64 array of ``out_shape`` to write into (default a new one).

    The kernel's machine code is called without Numba's dispatch (:func:`entry_point`), so the types
    above are the caller's to guarantee: every caller has checked them already, and a second look
    would cost as much as the kernel's own arithmetic on a small robot."""
    joints, reals, bodies, _, _, nv, nj = tree
    call = _SINGLE_CALLS.get((kernel, nj, nv))
    if call is None:
        size = kernel_workspace_size(kernel, nj, nv) if kernel in _WORKSPACE else None  # (else always given)
        call = _SINGLE_CALLS[kernel, nj, nv] = (entry_point(kernel), size)
    entry, size = call
    if out is None:
        out = np.empty(out_shape)
    entry(joints, reals, bodies if frames is None else frames, x0, x1, x2, x3, out,
          np.empty(size if workspace is None else workspace))
    return out


#: ``(kernel, nj, nv) -> (entry point, workspace size)`` of single calls: one look-up per call.
_SINGLE_CALLS = {}


def kernel_workspace_size(kernel, nj, nv):
    """Floats of workspace one state of ``kernel`` needs on a tree of ``nj`` joints and ``nv`` velocities."""
    return _WORKSPACE[kernel](nj, nv)


_DIRECT = {}
#: The types of a compiled tree's arrays (:class:`~multibody.tree.CompiledTree`), read-only, as every compiled call
#: reads them; and of a vector and a matrix it reads or writes.
TREE_INTS, TREE_FLOATS = (numba.types.Array(numba.types.int64, 2, "C", readonly=True),
                          numba.types.Array(numba.types.float64, 2, "C", readonly=True))
VECTOR, MATRIX = numba.types.float64[::1], numba.types.float64[:, ::1]
#: The argument types of every single call: the tree's read-only arrays, then writable inputs and outputs.
#: Machine code does not depend on whether an array is writable, and no kernel writes its inputs.
_SINGLE_CALL_TYPES = (TREE_INTS, TREE_FLOATS, TREE_FLOATS, VECTOR, VECTOR, VECTOR, VECTOR, MATRIX, VECTOR)


#: The argument types of :func:`_batch`: a kernel's single call (:func:`first_class`), the tree's arrays and
#: the frames read-only, the input rows and the outputs writable, whatever the arrays passed are.
_BATCH_TYPES = (numba.types.FunctionType(numba.types.none(*_SINGLE_CALL_TYPES)), TREE_INTS, TREE_FLOATS,
                TREE_FLOATS, MATRIX, MATRIX, MATRIX, MATRIX, numba.types.float64[:, :, ::1], numba.types.int64,
                numba.types.int64)

#: The compiled loops the driver calls from Python, as ``(function, argument types)``: a batch's loop compiles
#: once for every kernel, so ``multibody compile`` compiles it beside them (:func:`compile_kernels`).
ENTRY_POINTS = ((_batch, _BATCH_TYPES),)


def entry_point(kernel, types=_SINGLE_CALL_TYPES):
    """``kernel``'s compiled entry point for ``types`` (a kernel's: :data:`_SINGLE_CALL_TYPES`; a run loop's, called
    from Python with arguments of its types), compiled
    (or loaded from Numba's cache) on first use: a call that skips the dispatcher's look at every
    argument's type, a third of a small robot's single call, and that takes a read-only array where
    the types say writable (Numba's dispatch would compile the function again for it);
    :func:`multibody.numba_hooks.entry_point`, the dispatcher where Numba has no such entry. Under
    ``NUMBA_DISABLE_JIT=1``: the Python function."""
    entry = _DIRECT.get(kernel)
    if entry is None:
        entry = _DIRECT[kernel] = numba_hooks.entry_point(kernel, types)
    return entry


def vouches(out) -> bool:
    """Whether a kernel's output ``out`` shows that its inputs were finite: its first entry is finite
    (every kernel fills its whole output with NaN when an input is not:
    :func:`~multibody.kernels.spatial.nan_unless_finite`), or it has none. A single call checks its
    inputs' shapes and leaves their entries to this one look."""
    return out.size == 0 or math.isfinite(out.item(0))


def output(out, shape):
    """A new float64 array of ``shape``, or ``out`` when it can receive a result of that shape: a
    writable C-contiguous float64 ``numpy.ndarray`` of exactly ``shape``; ``ValueError`` otherwise,
    naming what was expected and what was given."""
    if out is None:
        return np.empty(shape)
    if (isinstance(out, np.ndarray) and out.shape == shape and out.dtype == _FLOAT and out.flags.c_contiguous
            and out.flags.writeable):
        return out
    if not isinstance(out, np.ndarray):
        raise ValueError(f"out must be a numpy.ndarray of shape {shape} and dtype float64, got {type(out).__name__}")
    got = ", ".join(word for word, bad in (("read-only", not out.flags.writeable),
                                          ("not C-contiguous", not out.flags.c_contiguous)) if bad)
    raise ValueError(f"out must be a writable C-contiguous float64 array of shape {shape}, got a "
                     f"{got + ' ' if got else ''}{out.dtype} array of shape {out.shape}")


def configuration_map(kernel, tree, a, b, shape):
    """``kernel`` of :mod:`multibody.kernels.configuration` on the float arrays ``a`` and ``b`` (``None`` when
    unused), of checked sizes, their leading axes broadcast, through :func:`evaluate`: ``(..., *shape)`` with
    ``shape`` ``(size,)`` or, for a matrix, ``(rows, cols)``. No other checks."""
    batch = a.shape[:-1] if b is None else spatial.batch_shape(a.shape[:-1], b.shape[:-1])
    out = evaluate(kernel, tree, (a, b), shape if len(shape) == 2 else (1,) + shape, batch)
    return out if len(shape) == 2 else out.reshape(batch + shape)


def evaluate(kernel, tree, inputs, out_shape, batch=(), frames=None, workspace=None, out=None, shape=None):
    """Run ``kernel`` on every state of ``batch``: ``-> batch + shape``.

    ``inputs``: up to four float arrays ``(..., k)`` whose leading axes broadcast to ``batch``
    (``None``: unused); ``out_shape``: ``(rows, cols)`` of one state's output; ``frames``: frame rows
    ``(m, 13)`` (default ``tree.bodies``); ``workspace``: floats of workspace per state, for a kernel
    whose need depends on more than the tree (default its module's ``workspace_size(nj, nv)``). A state
    with a non-finite input gets an output of NaN (every kernel ends with
    :func:`~multibody.kernels.spatial.nan_unless_finite`).

    ``shape``: one state's result as the caller returns it, of the size of ``out_shape`` (default
    ``out_shape``); ``out``: an array that receives the result and is returned, C-contiguous float64 of
    shape ``batch + shape`` (:func:`output`; default a new one). An input that shares memory with
    ``out`` is read from a copy, so that no state's output overwrites another's input.
    """
    shape = tuple(out_shape) if shape is None else tuple(shape)
    result = output(out, batch + shape)
    if out is not None:
        inputs = tuple(x.copy() if isinstance(x, np.ndarray) and np.may_share_memory(x, result) else x for x in inputs)
    if not batch:
        evaluate_one(kernel, tree, out_shape, *map(contiguous, inputs), frames=frames, workspace=workspace,
                     out=result.reshape(out_shape))
        return result
    frames = tree.bodies if frames is None else frames
    workspace = np.empty(kernel_workspace_size(kernel, tree.njoints, tree.nv) if workspace is None else workspace)
    x0, x1, x2, x3 = inputs + _UNUSED[len(inputs):]
    n = math.prod(batch)
    out = result.reshape((n,) + tuple(out_shape))  # (a view: the result is C-contiguous)
    if n == 1:  # one state with batch axes: the kernel directly, as for no batch axes
        entry_point(kernel)(tree.joints, tree.reals, frames, _rows(x0, batch, 1)[0], _rows(x1, batch, 1)[0],
                        _rows(x2, batch, 1)[0], _rows(x3, batch, 1)[0], out[0], workspace)
    elif n:
        # A small batch runs on fewer threads: waking a sleeping thread costs more than it would compute.
        shares = max(1, min(get_num_threads(), n // STATES_PER_THREAD))
        with parallel_shares(shares):
            rows = (_rows(x0, batch, n), _rows(x1, batch, n), _rows(x2, batch, n), _rows(x3, batch, n))
            entry_point(_batch, _BATCH_TYPES)(first_class(kernel, _SINGLE_CALL_TYPES), tree.joints, tree.reals, frames,
                                              *rows, out, workspace.size, shares)
    return result


@contextlib.contextmanager
def parallel_shares(shares):
    """Within the block, the parallel loops this Python thread runs use ``shares`` of Numba's threads (a batch's
    loop gives each its own share of the states), one batch at a time where Numba's threading layer needs it."""
    with _BATCH_LOCK if _one_at_a_time else _ANY_TIME:
        # Numba's count is this Python thread's: set from the process's for this batch, then put back
        # (inside the try, so that an interrupt cannot leave it changed).
        numba_threads = numba.get_num_threads()
        try:
            if shares != numba_threads:
                numba.set_num_threads(shares)
            yield
        finally:
            if shares != numba_threads:
                numba.set_num_threads(numba_threads)
        _threading_layer_seen()


#: Held by a running batch while batches run one at a time: under Numba's ``workqueue`` threading layer
#: (Numba's choice where neither OpenMP nor TBB is found), parallel code run by two Python threads at once
#: aborts the process.
_BATCH_LOCK = threading.Lock()
_ANY_TIME = contextlib.nullcontext()
#: Whether batches take :data:`_BATCH_LOCK`: until a batch has shown which threading layer Numba runs,
#: then while that is ``workqueue``.
_one_at_a_time = True


def _threading_layer_seen() -> None:
    """After a batch: batches go on one at a time only under Numba's ``workqueue`` threading layer (or
    where no layer has started: ``NUMBA_DISABLE_JIT=1``, and nothing runs in parallel anyway)."""
    global _one_at_a_time
    if _one_at_a_time:
        try:
            _one_at_a_time = numba.threading_layer() == "workqueue"
        except ValueError:  # no parallel code has run yet
            pass
