"""Batches beyond one machine: chunks of states on a Dask cluster (the ``[dask]`` extra).

    mb.distributed.map_states(fn, model, *arrays, chunks=None, client=None)
    mb.distributed.simulate_many(system, q0, v0, t_final, *, chunks=None, client=None, **kw)

A batch is split along its leading axis into chunks; each chunk is one task on a worker of the cluster
(``dask.distributed``), which computes it with the batch driver on its cores, as one process would. The
model is sent once to every worker (``Client.scatter(..., broadcast=True)``), each chunk once to the
worker that computes it, and the results come back in the order of the states, concatenated.

Each task runs the compiled kernels on its share of its machine's cores: the machine's cores divided
among the Dask threads of the workers on it, so that a process per core, or a process with a thread per
core, does not run more threads than there are cores.

Without a ``client``, the functions use the current Dask client (``distributed.get_client()``), or else
start a ``LocalCluster`` for the call (a process per core) and close it after.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import replace

import numpy as np

INSTALL_HINT = "multibody.distributed needs Dask's distributed scheduler: pip install 'multibody[dask]'"


@contextlib.contextmanager
def _connected(client):
    """The client to use: ``client``, else the current one, else one of a ``LocalCluster`` for this call."""
    try:
        import distributed
    except ImportError as error:
        raise ImportError(INSTALL_HINT) from error
    if client is None:
        try:
            client = distributed.get_client()
        except ValueError:  # no client in this process
            client = None
    if client is not None:
        yield client
        return
    with distributed.LocalCluster(dashboard_address=None) as cluster, distributed.Client(cluster) as local:
        yield local


def _host_threads(client):
    """``{worker address: Dask threads of all workers on its host}``, which share that host's cores."""
    workers = client.scheduler_info()["workers"]
    per_host = {}
    for info in workers.values():
        per_host[info["host"]] = per_host.get(info["host"], 0) + info["nthreads"]
    return {address: per_host[info["host"]] for address, info in workers.items()}


def _run(fn, model, arrays, host_threads):
    """One task: ``fn(model, *arrays)`` on this worker thread's share of the host's cores."""
    import numba
    from distributed import get_worker

    from .driver import local_num_threads

    sharing = host_threads.get(get_worker().address, 1)
    # (this task's batches only: a worker may share its process with the client or with other workers)
    with local_num_threads(max(1, numba.config.NUMBA_NUM_THREADS // sharing)):
        return fn(model, *arrays)


def _split(n, chunks, client):
    """``[(start, stop), ...]`` of chunks of ``chunks`` states (default: one chunk per Dask thread)."""
    if chunks is None:
        threads = sum(info["nthreads"] for info in client.scheduler_info()["workers"].values())
        chunks = max(1, math.ceil(n / max(threads, 1)))
    elif isinstance(chunks, bool) or not isinstance(chunks, int | np.integer) or chunks < 1:
        raise ValueError(f"chunks must be a positive number of states per chunk, or None, got {chunks!r}")
    return [(start, min(n, start + int(chunks))) for start in range(0, n, int(chunks))]


def _leading(arrays, names):
    """The common leading length ``N`` of ``arrays`` (each at least 1-d), or ``ValueError`` naming them."""
    lengths = {name: np.shape(x)[0] if np.ndim(x) else None for name, x in zip(names, arrays)}
    if None in lengths.values() or len(set(lengths.values())) != 1:
        shapes = ", ".join(f"{name} {np.shape(x)}" for name, x in zip(names, arrays))
        raise ValueError(f"the arrays must share a leading batch axis N to be split into chunks, got {shapes} "
                         "(a value shared by every state goes into fn, e.g. with functools.partial)")
    return next(iter(lengths.values()))


def _chunk(x, start, stop):
    """The rows ``[start:stop]`` of an array, or of an ``mb.PD``'s arguments given per trajectory."""
    from .integrators import PD

    return x.trajectories(start, stop) if isinstance(x, PD) else x[start:stop]


def _map_chunks(client, fn, model, arrays, chunks):
    """The results of ``fn(model, *chunk)`` for the chunks of ``arrays`` (arrays, or an ``mb.PD`` after the first), in
    order."""
    bounds = _split(len(arrays[0]), chunks, client)
    # Keys of this call's own (hash=False): a key named by content would be shared with an earlier call
    # whose data the cluster may be releasing at this moment.
    [shipped] = client.scatter([model], broadcast=True, hash=False)
    pieces = client.scatter([tuple(_chunk(x, start, stop) for x in arrays) for start, stop in bounds], hash=False)
    host_threads = _host_threads(client)
    futures = [client.submit(_run, fn, shipped, piece, host_threads, pure=False) for piece in pieces]
    return client.gather(futures)


def _concatenate(parts):
    """Chunk results joined along their leading axis: arrays, tuples of arrays, or batched trajectories."""
    from .trajectory import Trajectory

    first = parts[0]
    if isinstance(first, Trajectory):
        joined = {name: np.concatenate([getattr(p, name) for p in parts])
                  for name in ("q", "v", "lam", "energy", "residual")}
        return replace(first, status=[s for p in parts for s in p.status], **joined)
    if isinstance(first, tuple):
        return tuple(_concatenate([p[k] for p in parts]) for k in range(len(first)))
    if isinstance(first, np.ndarray) and first.ndim:
        return np.concatenate(parts)
    raise TypeError(f"fn must return arrays with the chunk's leading axis (or tuples of them), got "
                    f"{type(first).__name__}")


def map_states(fn, model, *arrays, chunks=None, client=None):
    """``fn(model, *arrays)`` for a large batch of states, computed in chunks on a Dask cluster.

    Args:
        fn: ``fn(model, *chunk_arrays)`` returning an array (or a tuple of arrays) with the chunk's leading
            axis, e.g. ``mb.mass_matrix`` or ``mb.forward_dynamics``; sent to the workers by cloudpickle
            (functions of a module by name, lambdas by value).
        model: a :class:`~multibody.model.Model`, or whatever ``fn`` takes first (a ``ConstrainedSystem``);
            sent once to every worker.
        arrays: ``(N, ...)`` arrays with the leading batch axis ``N`` in common (a value shared by every
            state goes into ``fn``, e.g. with ``functools.partial``).
        chunks: states per chunk (one task each); default ``N`` divided among the cluster's Dask threads.
        client: a ``distributed.Client``; default the current one, else a ``LocalCluster`` for this call.
    Returns:
        ``fn``'s result for the whole batch: the chunks' results concatenated in order.
    Raises:
        ImportError: Dask's distributed scheduler is not installed (``pip install 'multibody[dask]'``).
    """
    if not arrays:
        raise ValueError("map_states needs at least one array of states to split, e.g. q (N, nq)")
    arrays = tuple(np.asarray(x) for x in arrays)
    n = _leading(arrays, [f"arrays[{k}]" for k in range(len(arrays))])
    if n == 0:
        return fn(model, *arrays)
    with _connected(client) as connected:
        return _concatenate(_map_chunks(connected, fn, model, arrays, chunks))


def simulate_many(system, q0, v0, t_final, *, chunks=None, client=None, **kw):
    """:func:`multibody.simulate` of ``N`` initial states in chunks on a Dask cluster: each chunk a batch of
    trajectories that ``simulate`` integrates with a fixed-step method (``method="RK4"`` by default) on one worker,
    the trajectories joined in order.

    Args:
        system: a ``Model`` or a ``ConstrainedSystem`` with built-in constraints, sent once to every worker.
        q0, v0: ``(N, nq)``, ``(N, nv)`` (one of them may be a single state, shared by all).
        t_final: end time (s).
        chunks: trajectories per chunk; default ``N`` divided among the cluster's Dask threads.
        client: a ``distributed.Client``; default the current one, else a ``LocalCluster`` for this call.
        kw: :func:`~multibody.simulate`'s options (``dt``, ``method``, here ``"RK4"`` by default, a method that
            integrates batches; ``tau``, ...). An array ``tau (N, nv)`` is split with the states, and so are the
            arguments of an ``mb.PD`` given per trajectory, ``(N, …)`` (:meth:`~multibody.integrators.PD.trajectories`;
            checked against the system and the ``N`` states before anything is sent); a callable ``tau(t, q, v)``
            is sent to every worker and sees the states of its chunk, ``q (n, nq)`` with ``n`` at most ``chunks``
            (give values per trajectory as an array or an ``mb.PD``, or compute them from the state).
    Returns:
        a :class:`~multibody.trajectory.Trajectory` with a leading axis ``N``, as ``simulate`` returns for the
        whole batch; one ``RuntimeWarning`` when some trajectories stopped early (``trajectory.status``).
    """
    from .constrained import ConstrainedSystem
    from .integrators import PD
    from .simulation import batch_size, check_batchable, simulate, warn_if_stopped

    constrained = system if isinstance(system, ConstrainedSystem) else ConstrainedSystem(system)
    q0, v0 = np.asarray(q0, dtype=float), np.asarray(v0, dtype=float)
    n = batch_size(q0, v0, constrained.nq, constrained.nv)
    if n is None:
        raise ValueError(f"simulate_many takes a batch of initial states q0 (N, {constrained.nq}), v0 (N, "
                         f"{constrained.nv}), got {q0.shape} and {v0.shape}: simulate one with mb.simulate")
    kw.setdefault("method", "RK4")
    # refused here, before anything is sent
    check_batchable(constrained, kw["method"], q0.shape, v0.shape)
    q0 = np.broadcast_to(q0, (n, constrained.nq))
    v0 = np.broadcast_to(v0, (n, constrained.nv))
    if n == 0:
        return simulate(constrained, q0, v0, t_final, **kw)
    tau = kw.pop("tau", None)
    if isinstance(tau, PD):
        tau.bind(constrained.system, n)  # (its shapes against the system and the N states, before anything is sent)
        arrays = (q0, v0, tau)
    else:
        per_state = tau is not None and not callable(tau) and np.ndim(tau) == 2
        arrays = (q0, v0, np.asarray(tau, dtype=float)) if per_state else (q0, v0)
        if per_state:
            _leading(arrays, ("q0", "v0", "tau"))

    def run(shipped, q_chunk, v_chunk, tau_chunk=tau):
        with warnings.catch_warnings():
            # the client warns once for the whole batch (trajectory.status says why each stopped)
            warnings.filterwarnings("ignore", "\\d+ of \\d+ trajectories stopped early", RuntimeWarning)
            return simulate(shipped, q_chunk, v_chunk, t_final, tau=tau_chunk, **kw)

    with _connected(client) as connected:
        trajectory = _concatenate(_map_chunks(connected, run, constrained, arrays, chunks))
    warn_if_stopped(trajectory, stacklevel=3)
    return trajectory
