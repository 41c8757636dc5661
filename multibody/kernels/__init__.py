"""Compiled kernels: one per-state implementation of each algorithm (see ``docs/architecture.md``).

Every kernel is a function of one state, compiled by Numba, that reads the model's compiled tree
(:mod:`multibody.tree`), its inputs and a workspace, and writes its output in place. Kernels keep to
the subset of Python that Numba's CUDA target also compiles: loops, scalar and tuple arithmetic,
array indexing and slicing; no allocation and no NumPy array functions.
"""

import hashlib
import os


def _machine_code_directory():
    """The folder where Numba caches the kernels' machine code, as Numba picks it for a function of this
    package (``NUMBA_CACHE_DIR``, else ``__pycache__`` beside the sources, else the user-wide cache);
    ``None`` where none is writable."""
    from ..numba_hooks import cache_directory

    return cache_directory(_machine_code_directory, __file__)


def _forget_stale_machine_code():
    """Remove the cached machine code of every kernel when any kernel source (the tree's layout, whose column
    numbers the kernels compile in as constants, among them) differs from the one it was compiled from.

    Numba checks a cached function against its own file only, while a kernel's machine code holds its
    helpers from other files, inlined: after an edit of ``crba.py`` (a ``git pull``, or an upgrade that
    leaves the old ``__pycache__`` behind) the constrained step in ``kkt.py`` would go on running the old
    mass matrix from the cache. One digest of all those sources, kept beside the cache, tells."""
    package = os.path.dirname(os.path.abspath(__file__))
    sources = sorted(os.path.join(package, name) for name in os.listdir(package) if name.endswith(".py"))
    # (and numba_hooks.py, whose options and typing the kernels compile with)
    sources.append(os.path.join(os.path.dirname(package), "numba_hooks.py"))
    digest = hashlib.sha256()
    for path in sources:
        with open(path, "rb") as source:
            digest.update(source.read())
    digest = digest.hexdigest()
    directory = _machine_code_directory()
    if directory is None:
        return
    stamp = os.path.join(directory, "multibody-kernels.sha256")
    try:
        with open(stamp) as file:
            if file.read() == digest:
                return
    except OSError:
        pass
    try:
        os.makedirs(directory, exist_ok=True)
        for name in os.listdir(directory):
            if name.endswith((".nbi", ".nbc")):
                os.remove(os.path.join(directory, name))
        # written whole or not at all, so that a process starting beside this one reads a complete digest
        temporary = f"{stamp}.{os.getpid()}"
        with open(temporary, "w") as file:
            file.write(digest)
        os.replace(temporary, stamp)
    except OSError:  # a cache another process is rewriting, or a folder not ours to change: Numba's own checks
        pass


_forget_stale_machine_code()
