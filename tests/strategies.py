"""Hypothesis strategies shared by the property tests: random robots and random states.

* :func:`urdf_trees`: URDF text of a random tree of 1–``max_links`` links with every URDF joint type
  (revolute, continuous, prismatic, fixed, planar, floating, the last two also inside the tree),
  principal or arbitrary axes, random origins, and physically valid inertias (a box of random
  size, so the triangle inequality holds, on random principal axes, masses over four decades,
  centres of mass off the joint), with an optional floating base.
* :func:`builder_models`: random models from the Python builder, spherical and translation
  joints included (URDF cannot express them), from ``conftest.random_tree_model``.
* :func:`states`: ``(q, v, a)`` of a model, ``q`` on its configuration manifold.

The profiles: ``ci`` (the default, a few dozen examples per property) and ``thorough``
(``pytest --hypothesis-profile=thorough``), registered in ``conftest.py``.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from conftest import random_tree_model

URDF_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "planar", "floating")

_PRINCIPAL_AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1)]


def _numbers(values):
    return " ".join(repr(float(x)) for x in values)


@st.composite
def axes(draw):
    """A unit axis: principal, or an arbitrary direction."""
    if draw(st.booleans()):
        return np.array(draw(st.sampled_from(_PRINCIPAL_AXES)), dtype=float)
    direction = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 3)))
    norm = np.linalg.norm(direction)
    return direction / norm if norm > 0.1 else np.array([0.0, 0.0, 1.0])


@st.composite
def inertial_elements(draw):
    """``<inertial>`` of a box of random size and mass (kg, m), on random principal axes, with its
    centre of mass off the link origin."""
    mass = 10.0 ** draw(st.floats(-2.0, 2.0))
    x, y, z = draw(st.tuples(*[st.floats(0.02, 1.0)] * 3))
    moments = mass / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
    rpy = draw(st.tuples(*[st.floats(-math.pi, math.pi)] * 3))
    com = draw(st.tuples(*[st.floats(-0.3, 0.3)] * 3))
    c, s = np.cos(rpy), np.sin(rpy)
    R = (np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
         @ np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
         @ np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]]))
    I = R @ np.diag(moments) @ R.T
    ixx, ixy, ixz, iyy, iyz, izz = (repr(float(x)) for x in (I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]))
    return (f'<inertial><origin xyz="{_numbers(com)}" rpy="0 0 0"/><mass value="{mass!r}"/>'
            f'<inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial>')


@st.composite
def urdf_trees(draw, max_links=12):
    """``(urdf_text, floating_base)`` of a random tree (see the module docstring)."""
    n = draw(st.integers(1, max_links))
    links = [f'<link name="link0">{draw(inertial_elements())}</link>']
    joints = []
    for k in range(1, n):
        parent = draw(st.integers(0, k - 1))
        kind = draw(st.sampled_from(URDF_JOINT_TYPES))
        xyz = draw(st.tuples(*[st.floats(-0.5, 0.5)] * 3))
        rpy = draw(st.tuples(*[st.floats(-math.pi, math.pi)] * 3))
        # a planar joint moves in the x-y plane of its frame: its axis is the plane's normal, z
        axis = np.array([0.0, 0.0, 1.0]) if kind == "planar" else draw(axes())
        limit = ""
        if kind in ("revolute", "prismatic"):
            lower = draw(st.floats(-3.0, 0.0))
            limit = f'<limit lower="{lower!r}" upper="{lower + draw(st.floats(0.1, 3.0))!r}" effort="10" velocity="1"/>'
        joints.append(f'<joint name="joint{k}" type="{kind}"><parent link="link{parent}"/><child link="link{k}"/>'
                      f'<origin xyz="{_numbers(xyz)}" rpy="{_numbers(rpy)}"/><axis xyz="{_numbers(axis)}"/>{limit}</joint>')
        links.append(f'<link name="link{k}">{draw(inertial_elements())}</link>')
    text = '<?xml version="1.0"?>\n<robot name="random">' + "".join(links) + "".join(joints) + "</robot>"
    return text, draw(st.booleans())


def builder_models(max_extra=8):
    """Random builder models with every joint kind (``conftest.random_tree_model``)."""
    return st.builds(random_tree_model, seed=st.integers(0, 2**31 - 1), n_extra=st.integers(0, max_extra))


@st.composite
def states(draw, model):
    """``(q, v, a)``: ``q`` on the configuration manifold, ``v`` and ``a`` of order one."""
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    return model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
