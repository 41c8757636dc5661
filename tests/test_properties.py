"""Physics properties on random robots (tests/strategies.py): agreement with Pinocchio on random URDF
trees, and identities that need no reference on random builder models with every joint kind.
"""

from __future__ import annotations

import os
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

import multibody as mb
from multibody.check import compare_with_pinocchio

from strategies import builder_models, urdf_trees

pytest.importorskip("pinocchio")

#: Rows of ``compare_with_pinocchio`` that solve a linear system: their forward error may grow with
#: the condition number of ``M``, while their backward error (residual in Pinocchio's equations)
#: stays at rounding.
SOLVED = ("forward dynamics (aba, f_ext)", "inverse mass matrix")


@given(urdf_trees())
@example((  # one continuous joint: Pinocchio gives its 6×1 Jacobian as a vector
    '<?xml version="1.0"?>\n<robot name="one_joint"><link name="link0"><inertial><mass value="1.0"/>'
    '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link><link name="link1">'
    '<inertial><mass value="1.0"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>'
    '</link><joint name="joint1" type="continuous"><parent link="link0"/><child link="link1"/>'
    '<axis xyz="0 0 1"/></joint></robot>', False))
@example(('<?xml version="1.0"?>\n<robot name="no_joint"><link name="link0"><inertial><mass value="1.0"/>'
          '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link></robot>', False))
def test_random_urdf_trees_agree_with_pinocchio(tree):
    """Every quantity of ``multibody check`` at two random states: ≤ 1e-10 relative, and ABA and
    ``M⁻¹`` within the conditioning of ``M``."""
    text, floating_base = tree
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "random.urdf")
        with open(path, "w") as f:
            f.write(text)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # e.g. a joint limit the model does not use
            _, rows, condition = compare_with_pinocchio(path, floating_base, samples=2)
    for row in rows:
        if row.quantity in SOLVED:
            # a solve is judged by its backward error (below); its difference from Pinocchio's solve may
            # then reach the condition number times both sides' backward errors
            tolerance = max(1e-9, 1e-12 * condition)
        elif "backward error" in row.quantity:
            tolerance = 1e-13
        else:
            tolerance = 1e-10
        assert row.error <= tolerance, f"{row.quantity}: {row.error:.3g} > {tolerance:.3g} (cond M {condition:.3g})"


@given(builder_models(), st.integers(0, 2**31 - 1))
def test_identities_on_random_builder_models(model, seed):
    """``M`` symmetric positive definite; ``ABA(RNEA(a)) = a``; ``Ṁ = C + Cᵀ`` along the motion (central
    differences); a batch of states equals the states one by one, bitwise."""
    rng = np.random.default_rng(seed)
    q = model.random_configuration(rng, shape=(3,))
    v, a = rng.standard_normal((2, 3, model.nv))
    M = mb.mass_matrix(model, q)
    assert np.array_equal(M, np.swapaxes(M, -1, -2))
    assert np.linalg.eigvalsh(M).min() > 0.0
    tau = mb.inverse_dynamics(model, q, v, a)
    a_back = mb.forward_dynamics(model, q, v, tau)
    condition = np.linalg.cond(M).max()
    assert np.abs(a_back - a).max() <= 1e-12 * condition * max(1.0, np.abs(a).max())
    # Ṁ = C + Cᵀ: M along q(t) = q ⊕ v t, by central differences of step h (error O(h²))
    h = 1e-5
    M_dot = (mb.mass_matrix(model, model.integrate(q, v, h)) - mb.mass_matrix(model, model.integrate(q, v, -h))) / (2 * h)
    C = mb.coriolis_matrix(model, q, v)
    scale = max(1.0, np.abs(M_dot).max())
    assert np.abs(M_dot - (C + np.swapaxes(C, -1, -2))).max() <= 1e-6 * scale
    for k in range(3):
        assert np.array_equal(mb.inverse_dynamics(model, q[k], v[k], a[k]), tau[k])
        assert np.array_equal(mb.mass_matrix(model, q[k]), M[k])
