"""Models shipped with multibody, found by name: ``robots.path("double_pendulum")``, ``robots.load(...)``.

The URDF files live in the project's ``robots/`` folder, installed as the package data of
``multibody.robot_files``.
"""

from __future__ import annotations

from importlib import resources

_PACKAGE = "multibody.robot_files"


def names() -> list[str]:
    """Names of the shipped models (URDF file names without ``.urdf``), sorted."""
    return sorted(entry.name[: -len(".urdf")] for entry in resources.files(_PACKAGE).iterdir()
                  if entry.name.endswith(".urdf"))


def path(name: str) -> str:
    """Filesystem path of the shipped URDF ``name`` (with or without the ``.urdf`` suffix)."""
    stem = name[: -len(".urdf")] if name.endswith(".urdf") else name
    entry = resources.files(_PACKAGE).joinpath(stem + ".urdf")
    if not entry.is_file():
        raise ValueError(f"no shipped robot named {name!r}; available: {names()}")
    return str(entry)


def load(name: str, **kwargs):
    """Load a shipped robot; keyword arguments go to :func:`multibody.load_urdf`."""
    from .urdf import load_urdf

    return load_urdf(path(name), **kwargs)
