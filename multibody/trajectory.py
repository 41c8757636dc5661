"""The result of a simulation, :class:`Trajectory`: its arrays, its momenta and its ``.npz`` file."""

from __future__ import annotations

import contextlib
import os
import uuid
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import MISSING, dataclass, field, fields, replace

import numpy as np

from .model import Model
from .spatial import matvec


@dataclass
class Contacts:
    """The contact rows of one step (entry ``k`` of :attr:`multibody.Trajectory.contacts`, the step that ends at
    ``t[k]``): ``body (c,)`` a body's name (a joint's for a limit), ``other (c,)`` the other body's name, ``"ground"``
    or ``"limit"``, ``point (c, 3)`` (world, m), ``normal (c, 3)`` (world, from ``other`` into ``body``), ``force
    (c, 3)`` (world axes, on ``body``, the step's impulse / dt, N); a joint limit has zero point and normal and its
    generalized force (N·m or N, negative at an upper limit) in ``force[:, 0]``."""

    body: np.ndarray
    other: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    force: np.ndarray

    def __len__(self):
        return len(self.body)

    def __eq__(self, other):
        return (isinstance(other, Contacts) and all(np.array_equal(getattr(self, name), getattr(other, name))
                                                    for name in ("body", "other", "point", "normal", "force")))


@dataclass(repr=False)
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
        contacts: with contact or joint limits (:mod:`multibody.contact`), a sequence of one entry per output time
            (:class:`multibody.contact.ContactRecord`, which builds each entry when it is first read; from a file, a
            list), a list of them per trajectory of a batch; entry ``k`` the contact rows of the step that ends at
            ``t[k]`` (entry 0 empty): a :class:`Contacts` with ``body``, ``other``, ``point``, ``normal`` and
            ``force``; ``None`` otherwise.
        complementarity: with contact or joint limits, ``(n,)`` (``(N, n)``) the residual of each step's contact
            problem (non-penetration, the cone, complementarity; m/s), 0 at ``t[0]``; ``None`` otherwise.
        joint_names: the model the trajectory belongs to: the names of its moving joints
            (``Model.joint_names``), or of the coordinates of a symbolic system
            (``LagrangianSystem.numeric()``); ``None`` when the system names none. With the widths
            ``nq``, ``nv`` of ``q`` and ``v`` it is what :meth:`load` checks a model against.
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
    joint_names: list | None = None
    contacts: Sequence | None = None
    complementarity: np.ndarray | None = None

    def __len__(self):
        """The number of output times ``n``."""
        return len(self.t)

    @property
    def nq(self):
        """The size of a configuration, the width of ``q``."""
        return int(np.shape(self.q)[-1])

    @property
    def nv(self):
        """The size of a velocity, the width of ``v``."""
        return int(np.shape(self.v)[-1])

    def __repr__(self):
        """A few lines: the output times, the arrays' shapes, the constraint rows, the model and the status
        (the arrays themselves are ``trajectory.q`` and so on)."""
        t = np.asarray(self.t)
        span = f"t = {t[0]:.6g} to {t[-1]:.6g} s" if t.size else "no output times"
        runs = "" if self.batch_size is None else f"{self.batch_size} trajectories, "
        shapes = ", ".join(f"{name} {np.shape(getattr(self, name))}" for name in _ARRAYS if name != "t")
        lines = [f"Trajectory: {runs}{len(t)} output times, {span}", f"  {shapes}",
                 f"  constraint rows: {_listed(self.row_names)}"]
        if self.joint_names is not None:
            lines.append(f"  model: nq = {self.nq}, nv = {self.nv}, joints {_listed(self.joint_names)}")
        if self.projection_tolerance is not None:
            lines.append(f"  outputs projected onto the constraints above a residual of {self.projection_tolerance:.3g}")
        if self.batch_size is None:
            lines.append(f"  status: {self.status}")
        else:
            stopped = [k for k, status in enumerate(self.status) if status != "completed"]
            first = f"; trajectory {stopped[0]}: {self.status[stopped[0]]}" if stopped else ""
            lines.append(f"  status: {len(self.status) - len(stopped)} completed, {len(stopped)} stopped early{first}")
        return "\n".join(lines)

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
                       row_names=list(self.row_names), contacts=None if self.contacts is None else self.contacts[k],
                       complementarity=None if self.complementarity is None else self.complementarity[k].copy())

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

        mechanical = _system_of(system)
        model = _model_of(mechanical)
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
        as arrays of ``str``, so :meth:`load` reads the file without pickle.

        The archive is written to a temporary file in the same folder, flushed to disk, and then renamed
        onto ``path`` in one step (``os.replace``): a full disk or a killed process leaves any earlier file
        at ``path`` as it was. A failed write removes its temporary file and raises; a process killed while
        writing leaves it behind (a hidden ``.NAME.npz.*.tmp`` next to ``path``). Raises ``ValueError``,
        writing nothing, for a trajectory whose arrays disagree in shape or are not floating point."""
        _check_arrays(self, "Trajectory.save: the trajectory")
        arrays = {_FILE_FORMAT_KEY: np.array(_FILE_FORMAT)}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "contacts":
                if value is not None:
                    arrays.update(_stored_contacts(value, self.batch_size is not None))
            elif value is not None:  # an absent entry loads as the field's default, None
                arrays[f.name] = _stored(f.name, value)
        path = os.fspath(path)
        path = path if path.endswith(".npz") else path + ".npz"
        folder, name = os.path.split(os.path.abspath(path))
        temporary = os.path.join(folder, f".{name}.{uuid.uuid4().hex}.tmp")
        # (os.open with mode 0o666 gives the file the permissions the umask allows, as open() would)
        descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        try:
            with os.fdopen(descriptor, "wb") as file:
                np.savez(file, **arrays)
                file.flush()
                os.fsync(file.fileno())
            os.replace(temporary, path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)
            raise
        _sync_folder(folder)
        return path

    @classmethod
    def load(cls, path, model=None):
        """The trajectory that :meth:`save` wrote to ``path``.

        ``model``: the :class:`~multibody.model.Model`, :class:`~multibody.constrained.ConstrainedSystem`
        or mechanical system the trajectory is meant for, or ``None`` for no check. Given one, the file
        must belong to it: the widths of ``q`` and ``v`` must be its ``nq`` and ``nv``, and the joint (or
        coordinate) names the file records must be its own. A file without recorded names (written by a
        trajectory built without them, or by an earlier version of multibody) is checked on ``nq`` and
        ``nv`` only.

        Raises ``FileNotFoundError`` when there is no such file, ``ValueError`` when the file is not a
        saved trajectory: another kind of file, a truncated or corrupted archive, arrays that disagree in
        shape or are not floating point, or a trajectory of another model (each message names the
        arrays, or what differs from ``model``)."""
        path = os.fspath(path)
        not_ours = f"{path!r} is not a trajectory saved by Trajectory.save"
        with open(path, "rb") as file:  # (FileNotFoundError, IsADirectoryError as they are)
            start = file.read(len(_NPY_SIGNATURE))
        if not start.startswith((_ZIP_SIGNATURE, _EMPTY_ZIP_SIGNATURE, _NPY_SIGNATURE)):
            # (NumPy would read any other file as a pickle, and answer by suggesting to load it unsafely)
            raise ValueError(f"{not_ours}: it is not a .npz archive ({'empty' if not start else f'it starts with {start!r}'})")
        try:
            archive = np.load(path, allow_pickle=False)
        except (ValueError, EOFError, OSError, zipfile.BadZipFile) as error:
            if isinstance(error, FileNotFoundError | IsADirectoryError):
                raise
            raise ValueError(f"{not_ours}: {error}") from None
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise ValueError(f"{not_ours}: it holds one array, not a .npz archive")
        with archive:
            if _FILE_FORMAT_KEY not in archive.files:
                raise ValueError(f"{not_ours}: a .npz archive without the entry {_FILE_FORMAT_KEY!r} "
                                 f"(it has {sorted(archive.files)})")
            try:
                entry = archive[_FILE_FORMAT_KEY]
                if entry.dtype.kind != "U" or entry.shape != (2,):
                    raise ValueError(f"its entry {_FILE_FORMAT_KEY!r} is not (format name, version)")
                name, version = entry.tolist()
                if name != _FILE_FORMAT[0] or version != _FILE_FORMAT[1]:
                    raise ValueError(f"its format is {name!r} version {version!r}; this version of "
                                     f"multibody reads {_FILE_FORMAT[0]!r} version {_FILE_FORMAT[1]!r}")
                required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
                missing = [key for key in required if key not in archive.files]
                if missing:
                    raise ValueError(f"it lacks the arrays {missing}")
                # (an object array, which only pickle could read, raises ValueError; a truncated or
                # corrupted member BadZipFile, EOFError or zlib.error)
                values = {f.name: _restored(archive[f.name]) for f in fields(cls) if f.name in archive.files}
                if _CONTACT_KEYS[0] in archive.files:
                    values["contacts"] = _restored_contacts(archive)
            except (ValueError, TypeError, EOFError, OSError, zipfile.BadZipFile, zlib.error) as error:
                raise ValueError(f"{not_ours}: {error}") from None
        trajectory = cls(**values)
        _check_arrays(trajectory, not_ours)
        if model is not None:
            _check_model(trajectory, model, repr(path))
        return trajectory


# The first bytes of a .npz file (a zip archive; an empty one) and of a single .npy array.
_ZIP_SIGNATURE, _EMPTY_ZIP_SIGNATURE, _NPY_SIGNATURE = b"PK\x03\x04", b"PK\x05\x06", b"\x93NUMPY"

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


#: The arrays that hold :attr:`Trajectory.contacts` in a saved file: the rows of each step, then every step's rows
#: one after the other.
_CONTACT_KEYS = ("contacts_count", "contacts_body", "contacts_other", "contacts_point", "contacts_normal",
                 "contacts_force")


def _stored_contacts(contacts, batch):
    """:attr:`Trajectory.contacts` (a sequence of entries, or a list of them per trajectory) as arrays without
    pickle: the number of rows of each entry ``(n,)`` (``(N, n)``), then the rows of all entries in order."""
    entries = [entry for trajectory in contacts for entry in trajectory] if batch else list(contacts)
    count = np.array([len(entry) for entry in entries], dtype=np.int64)
    if batch:
        count = count.reshape(len(contacts), -1)

    def joined(name, shape):
        parts = [np.asarray(getattr(entry, name)) for entry in entries]
        return np.concatenate(parts) if parts else np.zeros(shape)

    return dict(zip(_CONTACT_KEYS, (count, joined("body", (0,)).astype(str), joined("other", (0,)).astype(str),
                                    joined("point", (0, 3)), joined("normal", (0, 3)), joined("force", (0, 3)))))


def _restored_contacts(archive):
    """:attr:`Trajectory.contacts` from the arrays of :func:`_stored_contacts`."""
    count, body, other, point, normal, force = (archive[key] for key in _CONTACT_KEYS)
    ends = np.cumsum(count.reshape(-1))
    starts = ends - count.reshape(-1)
    entries = [Contacts(body[a:b], other[a:b], point[a:b], normal[a:b], force[a:b]) for a, b in zip(starts, ends)]
    if count.ndim == 2:
        return [entries[r * count.shape[1] : (r + 1) * count.shape[1]] for r in range(count.shape[0])]
    return entries


def _restored(array):
    """The field value of a stored array (inverse of :func:`_stored`): ``str`` arrays become a string
    (0-d) or a list of strings, 0-d numbers Python numbers, other arrays stay arrays."""
    if array.dtype.kind == "U":
        return str(array[()]) if array.ndim == 0 else array.tolist()
    return array[()].item() if array.ndim == 0 else array


#: The array fields of a :class:`Trajectory`, in the order of their shapes ``(n,)``, ``(n, nq)``, ...
_ARRAYS = ("t", "q", "v", "lam", "energy", "residual")


def _listed(names, shown=4):
    """``"3: a, b, c"``, or the first ``shown`` of many names and how many more."""
    names = list(names)
    more = f", ... ({len(names) - shown} more)" if len(names) > shown else ""
    return f"{len(names)}" + (": " + ", ".join(map(str, names[:shown])) + more if names else "")


def _is_names(value):
    return isinstance(value, list) and all(isinstance(x, str) for x in value)


def _check_arrays(trajectory, what):
    """Raise ``ValueError`` (``what`` and the arrays at fault) unless the fields of ``trajectory`` fit
    together: ``t (n,)``, ``q (n, nq)``, ``v (n, nv)``, ``lam (n, m)``, ``energy (n,)``, ``residual (n,)``
    of floating point (a leading axis ``N`` but for ``t`` when ``q`` has three axes), ``m`` row names,
    the status a string (``N`` strings), names lists of strings."""
    arrays = {name: getattr(trajectory, name) for name in _ARRAYS}
    not_arrays = [name for name, value in arrays.items() if not isinstance(value, np.ndarray)]
    if not_arrays:
        raise ValueError(f"{what}: the fields {', '.join(not_arrays)} must be arrays of floating point, got "
                         f"{', '.join(type(arrays[name]).__name__ for name in not_arrays)}")
    not_float = [f"{name} ({value.dtype})" for name, value in arrays.items() if value.dtype.kind != "f"]
    if not_float:
        raise ValueError(f"{what}: the arrays {', '.join(not_float)} are not floating point")
    t, q = arrays["t"], arrays["q"]
    if t.ndim != 1 or q.ndim not in (2, 3):
        raise ValueError(f"{what}: t must be (n,) and q (n, nq) or (N, n, nq), got t {t.shape} and q {q.shape}")
    lead = q.shape[:-1]
    expected = {"t": lead[-1:], "v": lead, "lam": lead, "energy": lead, "residual": lead}
    wrong = [f"{name} {arrays[name].shape}" for name, shape in expected.items()
             if arrays[name].shape[: len(shape)] != shape
             or arrays[name].ndim != len(shape) + (name in ("v", "lam"))]
    if wrong:
        axes = "n" if len(lead) == 1 else "N, n"
        raise ValueError(f"{what}: the arrays disagree in length: q {q.shape} has ({axes}) = {lead}, but "
                         f"{', '.join(wrong)} (t (n,), v (..., nv), lam (..., m), energy and residual ({axes}))")
    if not _is_names(trajectory.row_names) or len(trajectory.row_names) != arrays["lam"].shape[-1]:
        raise ValueError(f"{what}: row_names must be the names of the {arrays['lam'].shape[-1]} constraint rows of "
                         f"lam {arrays['lam'].shape}, got {trajectory.row_names!r}")
    status = trajectory.status
    if len(lead) == 1 and not isinstance(status, str):
        raise ValueError(f"{what}: status must be a string, got {status!r}")
    if len(lead) == 2 and not (_is_names(status) and len(status) == lead[0]):
        raise ValueError(f"{what}: status must be a list of {lead[0]} strings (one per trajectory of q "
                         f"{q.shape}), got {status!r}")
    tolerance = trajectory.projection_tolerance
    if tolerance is not None and (isinstance(tolerance, bool) or not isinstance(tolerance, int | float)):
        raise ValueError(f"{what}: projection_tolerance must be a number or None, got {tolerance!r}")
    if trajectory.joint_names is not None and not _is_names(trajectory.joint_names):
        raise ValueError(f"{what}: joint_names must be a list of strings or None, got {trajectory.joint_names!r}")


def _system_of(system):
    """The mechanical system of a ConstrainedSystem (its ``system``), else ``system`` itself (a Model or a
    mechanical system)."""
    return getattr(system, "system", system)


def _model_of(mechanical):
    """The :class:`~multibody.model.Model` of a mechanical system (a Model is its own), or ``None``."""
    return mechanical if isinstance(mechanical, Model) else getattr(mechanical, "model", None)


def _names_of(mechanical):
    """The joint names of a mechanical system's model, or its coordinate names; ``None`` when it has neither."""
    model = _model_of(mechanical)
    names = list(model.joint_names) if model is not None else getattr(mechanical, "coordinate_names", None)
    return list(names) if names is not None else None


def recorded_names(system):
    """What a :class:`Trajectory` of ``system`` records of its model (``Trajectory.joint_names``): the joint
    names of a :class:`~multibody.model.Model` (or of the model under a
    :class:`~multibody.constrained.ConstrainedSystem`), the coordinate names of a symbolic system, else
    ``None``."""
    return _names_of(_system_of(system))


def _check_model(trajectory, system, source):
    """Raise ``ValueError`` when ``trajectory`` (from ``source``) does not belong to ``system``: other widths
    ``nq``, ``nv``, or other recorded joint names."""
    mechanical = _system_of(system)
    model = _model_of(mechanical)
    of = f"the model {model.name!r}" if model is not None else f"the system {type(mechanical).__name__}"
    sizes = [f"{name} = {got} in the file, {want} in {of}" for name, got, want in
             (("nq", trajectory.nq, mechanical.nq), ("nv", trajectory.nv, mechanical.nv)) if got != want]
    if sizes:
        raise ValueError(f"{source} is a trajectory of another model: {'; '.join(sizes)}")
    names = _names_of(mechanical)
    if trajectory.joint_names is None or names is None or trajectory.joint_names == names:
        return
    recorded = trajectory.joint_names
    if len(recorded) != len(names):
        difference = f"{len(recorded)} joints in the file ({_listed(recorded)}), {len(names)} in {of}"
    else:
        k = next(k for k, (a, b) in enumerate(zip(recorded, names)) if a != b)
        difference = f"joint {k} is {recorded[k]!r} in the file, {names[k]!r} in {of}"
    raise ValueError(f"{source} is a trajectory of another model: {difference}")


def _sync_folder(folder):
    """Flush ``folder``'s entries (a rename into it) to disk, where folders can be opened (POSIX); a file
    system that cannot sync a folder leaves the rename to its own schedule."""
    if not hasattr(os, "O_DIRECTORY"):
        return
    descriptor = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        with contextlib.suppress(OSError):
            os.fsync(descriptor)
    finally:
        os.close(descriptor)
