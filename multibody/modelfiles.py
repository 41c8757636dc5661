"""What the model-file loaders share (:mod:`multibody.urdf`, :mod:`multibody.mjcf`): numbers as the files
write them, where a file or an XML string comes from, mesh and include paths, and the one warning about
meshes that cannot be found."""

from __future__ import annotations

import math
import os
import re
import warnings

import numpy as np

#: Largest absolute value accepted for a number in a model file, joint limits aside (SI units).
LARGEST_MAGNITUDE = 1e50

# A decimal number as model writers produce it (Python's float() would also take "1_0", "inf" and
# non-ASCII digits, which urdfdom and MuJoCo reject).
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INFINITY = re.compile(r"[+-]?inf(?:inity)?", re.IGNORECASE)


def parse_numbers(text, key, count=None, *, at_least=None, allow_infinite=False) -> np.ndarray:
    """The numbers of attribute ``key`` written ``text`` (separated by white space), ``(n,)``: exactly ``count``
    of them, or ``at_least`` to ``count`` (any number when ``count`` is ``None``).

    Each must be decimal (``-1.5``, ``2e-3``) and, unless ``allow_infinite`` (which also takes ``inf``),
    finite and at most :data:`LARGEST_MAGNITUDE` in absolute value. Raises ``ValueError`` naming the
    attribute and saying which token is wrong and why, for the loader to prefix with the file and element.
    """
    tokens = text.split()
    for token in tokens:
        if not (_DECIMAL.fullmatch(token) or (allow_infinite and _INFINITY.fullmatch(token))):
            raise ValueError(f"attribute {key}={text!r}: {token!r} is not a decimal number")
    values = [float(token) for token in tokens]
    # (a decimal past float64's range reads as inf; a file's few numbers compare faster in Python than in NumPy)
    if not allow_infinite and not all(-LARGEST_MAGNITUDE <= x <= LARGEST_MAGNITUDE for x in values):
        if not all(math.isfinite(x) for x in values):
            raise ValueError(f"attribute {key}={text!r}: numbers must be finite")
        raise ValueError(f"attribute {key}={text!r}: magnitude above {LARGEST_MAGNITUDE:g}, the largest accepted "
                         "(no physical robot needs it; the dynamics would overflow)")
    if count is not None and not (count if at_least is None else at_least) <= len(values) <= count:
        expected = count if at_least is None else f"{at_least} to {count}"
        raise ValueError(f"attribute {key}={text!r} must be {expected} number(s), got {len(values)}")
    return np.array(values, dtype=float)


def is_xml_text(source) -> bool:
    """Whether ``source`` is XML text rather than a path (its first non-blank character is ``<``)."""
    return isinstance(source, str) and source.lstrip().startswith("<")


def package_directories(package_dirs):
    """``package_dirs`` (``None``, a path or a list of paths) as a list of strings, followed by the
    directories of ``ROS_PACKAGE_PATH``, where ROS tools and Pinocchio also look."""
    if isinstance(package_dirs, (str, os.PathLike)):
        package_dirs = [package_dirs]
    out = [os.fspath(d) for d in (package_dirs or [])]
    return out + [d for d in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if d]


def resolve_file(uri, base_dirs, package_dirs):
    """Absolute path of a file a model refers to (a mesh, an included file), or ``None``.

    ``package://name/rest`` is looked up as ``d/name/rest`` in each of ``package_dirs``, and as ``d/rest``
    where ``d`` is the folder of package ``name`` itself; ``file://path`` is ``path``; any other relative
    path is looked up in each of ``base_dirs`` (a directory or a list of them, in order; the working
    directory when there are none).
    """
    if isinstance(base_dirs, (str, os.PathLike)) or base_dirs is None:
        base_dirs = [base_dirs] if base_dirs is not None else []
    if uri.startswith("package://"):
        relative = uri[len("package://"):]
        candidates = [os.path.join(d, relative) for d in package_dirs]
        # package://name/rest may also be looked up with the package name stripped.
        package, _, rest = relative.partition("/")
        candidates += [os.path.join(d, package, rest) for d in package_dirs]
        candidates += [os.path.join(d, rest) for d in package_dirs if os.path.basename(os.path.normpath(d)) == package]
    elif uri.startswith("file://"):
        candidates = [uri[len("file://"):]]
    elif os.path.isabs(uri):
        candidates = [uri]
    else:
        candidates = [os.path.join(d, uri) for d in (base_dirs or [os.getcwd()])]
    for candidate in candidates:
        if os.path.isfile(candidate):
            return os.path.abspath(candidate)
    return None


def warn_missing_meshes(model, source_name, remedy, stacklevel=2):
    """One ``UserWarning`` for all the meshes of ``model`` whose files were not found (none when all were):
    the dynamics need no mesh, but the user should know before asking for them. ``remedy`` says what
    resolves them; ``stacklevel`` is the loader's (2: its caller)."""
    missing = [g.uri for g in model.geometries if g.shape == "mesh" and g.filename is None]
    if missing:
        warnings.warn(f"{source_name}: {len(missing)} mesh file(s) not found, e.g. {missing[0]!r} ({remedy}); "
                      "the dynamics are unaffected, and collision meshes among them are left out of "
                      "model.collision_geometries", UserWarning, stacklevel=stacklevel + 1)
