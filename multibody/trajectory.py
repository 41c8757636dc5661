"""The result of a simulation, :class:`Trajectory`: its arrays, its momenta and its ``.npz`` file."""

from __future__ import annotations

import os
from dataclasses import MISSING, dataclass, field, fields, replace

import numpy as np

from .spatial import matvec


@dataclass
class Trajectory:
    """A simulated motion, one row per output time; or ``N`` of them (``simulate`` from ``q0 (N, nq)``), whose
    arrays then have a leading axis ``N`` (``t`` is shared).

    Attributes:
        t: ``(n,)`` times (s).
        q: ``(n, nq)`` configurations; v: ``(n, nv)`` velocities (``(N, n, nq)``, ``(N, n, nv)``).
        lam: ``(n, m)`` constraint multipliers (sign convention ``M a + h = τ + Aᵀ λ``; ``(N, n, m)``).
        energy: ``(n,)`` mechanical energy (J; NaN when the system defines none; ``(N, n)``).
        residual: ``(n,)`` largest constraint violation ``max(|φ|, |A v + b|)`` (``(N, n)``).
        row_names: names of the ``m`` constraint rows.
        status: ``"completed"``, or the reason the simulation stopped early; for ``N`` trajectories a list of
            ``N`` such strings. A trajectory of a batch that stopped early keeps its outputs up to the time its
            status names (its last good state), and is NaN from the next output time on.
        projection_tolerance: the residual above which output states were projected back onto the
            constraints (``simulate``'s ``projection_tolerance``), ``None`` when they were not.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    energy: np.ndarray
    residual: np.ndarray
    row_names: list = field(default_factory=list)
    status: str = "completed"
    projection_tolerance: float | None = None

    def __len__(self):
        """The number of output times ``n``."""
        return len(self.t)

    @property
    def batch_size(self):
        """``N`` for ``N`` trajectories simulated together (``q (N, n, nq)``); ``None`` for one."""
        return None if np.ndim(self.q) < 3 else int(np.shape(self.q)[0])

    @property
    def completed(self):
        """Whether the simulation ran to its end: a bool, or ``(N,)`` bools for ``N`` trajectories."""
        if self.batch_size is None:
            return self.status == "completed"
        return np.array([status == "completed" for status in self.status], dtype=bool)

    def select(self, k):
        """Trajectory ``k`` of ``N`` simulated together, as a trajectory of its own (arrays copied)."""
        if self.batch_size is None:
            raise ValueError("select(k) picks one of N trajectories simulated together; this is one trajectory")
        return replace(self, q=self.q[k].copy(), v=self.v[k].copy(), lam=self.lam[k].copy(),
                       energy=self.energy[k].copy(), residual=self.residual[k].copy(), status=self.status[k],
                       row_names=list(self.row_names))

    def momentum(self, system, kind="generalized"):
        """Momenta along the trajectory: ``kind="generalized"`` gives ``p = ∂L/∂q̇ = M(q) v`` at every output
        time, ``(n, nv)`` (``(N, n, nv)``), whose entries of cyclic coordinates are conserved (the lecture
        note's ``p_θ = m r² θ̇`` of a central force); ``kind="spatial"`` gives the total spatial momentum of
        the moving bodies, ``[linear (kg m/s); angular about the world origin (kg m²/s)]`` in world axes,
        ``(n, 6)``, conserved for a free system (no gravity, no external forces or constraints).

        ``system``: the :class:`~multibody.model.Model`, :class:`~multibody.constrained.ConstrainedSystem` or
        mechanical system the trajectory was simulated with (``"spatial"`` needs a model). Rows after a
        batched trajectory stopped are NaN, as its states.
        """
        from . import dynamics, robotics
        from .constrained import ConstrainedSystem, as_system

        mechanical = system.system if isinstance(system, ConstrainedSystem) else as_system(system)
        model = getattr(mechanical, "model", None)
        q, v = np.asarray(self.q), np.asarray(self.v)
        stopped = ~(np.isfinite(q).all(axis=-1) & np.isfinite(v).all(axis=-1))
        if model is not None:
            # the rows after a batched trajectory stopped: any valid configuration, the results masked below
            q = np.where(stopped[..., None], model.neutral(), q)
        if kind == "generalized":
            if model is not None:
                # p = M(q) v, every output time in one batched call
                return np.where(stopped[..., None], np.nan, matvec(dynamics.mass_matrix(model, q), v))
            return np.stack([mechanical.mass_matrix(q_k) @ v_k for q_k, v_k in
                             zip(q.reshape(-1, q.shape[-1]), v.reshape(-1, v.shape[-1]))]).reshape(v.shape)
        if kind == "spatial":
            if model is None:
                raise ValueError("the spatial momentum needs a Model (bodies in space); this system is "
                                 f"{type(mechanical).__name__}")
            # h_O = [l; k_G + c × l] from the centroidal momentum h_G = [l; k_G] about the centre of mass c
            h_G = robotics.centroidal_momentum(model, q, np.where(stopped[..., None], 0.0, v))
            c = robotics.center_of_mass(model, q)
            linear = h_G[..., :3]
            momentum = np.concatenate([linear, h_G[..., 3:] + np.cross(c, linear)], axis=-1)
            return np.where(stopped[..., None], np.nan, momentum)
        raise ValueError(f"kind must be 'generalized' or 'spatial', got {kind!r}")

    def save(self, path):
        """Write the trajectory to a NumPy ``.npz`` archive at ``path`` (``.npz`` added when missing) and
        return the path written. Every array keeps its shape and dtype; names and the status are stored
        as arrays of ``str``, so :meth:`load` reads the file without pickle."""
        arrays = {_FILE_FORMAT_KEY: np.array(_FILE_FORMAT)}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:  # an absent entry loads as the field's default, None
                arrays[f.name] = _stored(f.name, value)
        path = os.fspath(path)
        path = path if path.endswith(".npz") else path + ".npz"
        np.savez(path, **arrays)
        return path

    @classmethod
    def load(cls, path):
        """The trajectory that :meth:`save` wrote to ``path``. Raises ``FileNotFoundError`` when there is
        no such file, ``ValueError`` when the file is not a saved trajectory."""
        path = os.fspath(path)
        not_ours = f"{path!r} is not a trajectory saved by Trajectory.save"
        try:
            archive = np.load(path, allow_pickle=False)
        except (ValueError, EOFError, OSError) as error:
            if isinstance(error, FileNotFoundError | IsADirectoryError):
                raise
            raise ValueError(f"{not_ours}: {error}") from None
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise ValueError(f"{not_ours}: it holds one array, not a .npz archive")
        with archive:
            if _FILE_FORMAT_KEY not in archive.files:
                raise ValueError(f"{not_ours}: a .npz archive without the entry {_FILE_FORMAT_KEY!r} "
                                 f"(it has {sorted(archive.files)})")
            name, version = archive[_FILE_FORMAT_KEY].tolist()
            if name != _FILE_FORMAT[0] or version != _FILE_FORMAT[1]:
                raise ValueError(f"{not_ours}: its format is {name!r} version {version!r}; this version of "
                                 f"multibody reads {_FILE_FORMAT[0]!r} version {_FILE_FORMAT[1]!r}")
            required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
            missing = [key for key in required if key not in archive.files]
            if missing:
                raise ValueError(f"{not_ours}: it lacks the arrays {missing}")
            try:
                values = {f.name: _restored(archive[f.name]) for f in fields(cls) if f.name in archive.files}
            except ValueError as error:  # an object array, which only pickle could read
                raise ValueError(f"{not_ours}: {error}") from None
        return cls(**values)


# The entry that marks a file written by Trajectory.save, holding (format name, version).
_FILE_FORMAT_KEY = "__multibody_format__"
_FILE_FORMAT = ("multibody.Trajectory", "1")


def _stored(name, value):
    """A :class:`Trajectory` field as an array that loads without pickle: arrays as they are, strings and
    lists of strings as arrays of ``str``, numbers as 0-d arrays."""
    if isinstance(value, np.ndarray) and value.dtype != object:
        return value
    if isinstance(value, str) or (isinstance(value, list | tuple) and all(isinstance(x, str) for x in value)):
        return np.array(value, dtype=str)
    if isinstance(value, bool | int | float | np.number):
        return np.array(value)
    raise TypeError(f"Trajectory.save: field {name!r} holds {type(value).__name__} {value!r}, which is not an "
                    "array, a string, a list of strings or a number")


def _restored(array):
    """The field value of a stored array (inverse of :func:`_stored`): ``str`` arrays become a string
    (0-d) or a list of strings, 0-d numbers Python numbers, other arrays stay arrays."""
    if array.dtype.kind == "U":
        return str(array[()]) if array.ndim == 0 else array.tolist()
    return array[()].item() if array.ndim == 0 else array
