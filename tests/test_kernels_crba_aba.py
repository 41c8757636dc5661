"""The CRBA and ABA kernels (:mod:`multibody.kernels.crba`, :mod:`multibody.kernels.aba`), called
directly on one state at a time.

Checked against Pinocchio (``crba`` and ``computeMinverse`` symmetrised from their upper triangle,
``aba`` with external forces) on Panda, UR5, Solo12 and Talos (reduced) on a free-flyer, and on
Pinocchio twins of the random trees with every joint kind; against the NumPy implementation
(``mb.mass_matrix``, ``mb.forward_dynamics``, ``mb.inverse_mass_matrix``) on the same models and on
the random trees in their own (not depth-first) joint order; and by the identities
``ABA(RNEA(a)) = a`` (with the RNEA kernel) and ``M⁻¹ M = 1``.

Error measure per state: ``max|ours − ref| / max(1, max|ref|)``. Every kernel runs on a workspace
filled with NaN (a read before a write shows) and longer than ``workspace_size`` (a write past it
shows), and writes into an output filled with NaN (an entry left unwritten shows).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import textwrap
import zlib

import numpy as np
import pytest

import multibody as mb
from multibody import joints as jt
from multibody.kernels import aba, crba, rnea
from multibody.kinematics import joint_world_poses
from multibody.tree import compile_tree

from conftest import pinocchio_twin
from dyn_helpers import STATUE_URDF, assert_rel, depth_first_model, erd_urdf, q_to_pinocchio, random_tree_model

pin = pytest.importorskip("pinocchio")

N_STATES = 5
TOL = 1e-12
#: ``M⁻¹`` and ABA carry an error of about ``cond(M) · eps`` relative to their magnitude
TOL_INVERSE = 1e-11
EMPTY = np.zeros(0)
GUARD = 64  # floats past the workspace that must stay untouched

ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", False),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False),
    "solo12": ("solo_description/robots/solo12.urdf", True),
    "talos_reduced": ("talos_data/robots/talos_reduced.urdf", True),
}
TWINS = ["random_tree_0", "random_tree_1", "random_tree_2"]
PIN_CASES = list(ROBOTS) + [f"twin_{name}" for name in TWINS]
OWN_CASES = list(ROBOTS) + TWINS  # the random trees in their own joint order: no Pinocchio


@functools.lru_cache(maxsize=None)
def get_case(name):
    return Case(name)


class Case:
    """A model, its compiled tree, random states and (when it has one) its Pinocchio model."""

    def __init__(self, name):
        self.pmodel = None
        if name in ROBOTS:
            relative, floating = ROBOTS[name]
            path = erd_urdf(relative)
            self.model = mb.load_urdf(path, floating_base=floating)
            self.pmodel = (pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating
                           else pin.buildModelFromUrdf(path))
        elif name.startswith("twin_"):
            # Pinocchio's crba and computeMinverse need depth-first joint order
            self.model = depth_first_model(random_tree_model(int(name[-1])))[0]
            self.pmodel, _ = pinocchio_twin(pin, self.model)
        else:
            self.model = random_tree_model(int(name[-1]))
        model = self.model
        self.tree = compile_tree(model)
        self.nj, self.nv = model.njoints, model.nv
        rng = np.random.default_rng(zlib.crc32(name.encode()))
        self.q = model.random_configuration(rng, shape=(N_STATES,))
        self.v = rng.standard_normal((N_STATES, self.nv))
        self.a = rng.standard_normal((N_STATES, self.nv))
        self.tau = rng.standard_normal((N_STATES, self.nv))
        self.f_ext = rng.standard_normal((N_STATES, self.nj, 6))
        if self.pmodel is not None:
            assert self.pmodel.nv == self.nv and list(self.pmodel.names)[1:] == list(model.joint_names)
            self.q_pin = q_to_pinocchio(model, self.q)
            self.pdata = self.pmodel.createData()

    def call(self, kernel, workspace_size, shape, x0, x1=EMPTY, x2=EMPTY, x3=EMPTY):
        """``kernel`` on one state, on NaN-filled output and workspace; checks the workspace bound."""
        out = np.full(shape, np.nan)
        size = workspace_size(self.nj, self.nv)
        ws = np.full(size + GUARD, np.nan)
        ws[size:] = 12345.0
        kernel(self.tree.joints, self.tree.reals, self.tree.bodies, x0, x1, x2, x3, out, ws)
        assert np.all(ws[size:] == 12345.0), "the kernel wrote past its workspace"
        return out

    def mass_matrix(self, k):
        return self.call(crba.mass_matrix, crba.workspace_size, (self.nv, self.nv), self.q[k])

    def forward_dynamics(self, k, v=None, tau=None, f_ext=None):
        v = self.v[k] if v is None else v
        tau = self.tau[k] if tau is None else tau
        f_ext = EMPTY if f_ext is None else np.ascontiguousarray(f_ext).reshape(-1)
        return self.call(aba.forward_dynamics, aba.workspace_size, (1, self.nv), self.q[k], v, tau, f_ext)[0]

    def inverse_mass_matrix(self, k):
        return self.call(crba.inverse_mass_matrix, crba.workspace_size, (self.nv, self.nv), self.q[k])

    def inverse_dynamics(self, k, a, f_ext=EMPTY):
        out = np.empty((1, self.nv))
        rnea.inverse_dynamics(self.tree.joints, self.tree.reals, self.tree.bodies, self.q[k], self.v[k], a,
                              np.ascontiguousarray(f_ext).reshape(-1), out,
                              np.empty(rnea.workspace_size(self.nj, self.nv)))
        return out[0]

    def pin_forces(self, k):
        """Our f_ext of state k as Pinocchio's list (universe first), each in Pinocchio's joint frame
        (a twin's continuous joint has a frame rotated about its origin: Pinocchio's RUBZ)."""
        pin.forwardKinematics(self.pmodel, self.pdata, self.q_pin[k])
        R_WJ, _ = joint_world_poses(self.model, self.q[k])
        forces = [pin.Force.Zero()]
        for i, f in enumerate(self.f_ext[k]):
            R = R_WJ[i].T @ self.pdata.oMi[i + 1].rotation  # Pinocchio's frame in ours
            forces.append(pin.Force(R.T @ f[:3], R.T @ f[3:]))
        return forces


def _symmetrised(upper):
    upper = np.triu(np.asarray(upper))
    return upper + np.triu(upper, 1).T


# ----------------------------------------------------------------------------- CRBA

@pytest.mark.parametrize("name", PIN_CASES)
def test_mass_matrix_matches_pinocchio(name):
    case = get_case(name)
    for k in range(N_STATES):
        M = case.mass_matrix(k)
        assert np.array_equal(M, M.T), "M is not exactly symmetric"
        ref = _symmetrised(pin.crba(case.pmodel, case.pdata, case.q_pin[k]))
        assert_rel(M, ref, TOL, f"{name} crba", batch_ndim=0)


@pytest.mark.parametrize("name", OWN_CASES)
def test_mass_matrix_matches_numpy(name):
    case = get_case(name)
    ref = mb.mass_matrix(case.model, case.q)
    for k in range(N_STATES):
        assert_rel(case.mass_matrix(k), ref[k], TOL, f"{name} crba vs mb.mass_matrix", batch_ndim=0)


@pytest.mark.parametrize("name", OWN_CASES)
def test_mass_matrix_columns_are_rnea_of_unit_accelerations(name):
    """``M e_c = RNEA(q, 0, e_c)`` without gravity, with the RNEA kernel."""
    case = get_case(name)
    tree = case.tree
    reals = tree.reals.copy()
    reals[case.nj] = 0.0  # no gravity
    M = case.mass_matrix(0)
    column = np.empty((1, case.nv))
    for c in range(case.nv):
        rnea.inverse_dynamics(tree.joints, reals, tree.bodies, case.q[0], EMPTY, np.eye(case.nv)[c], EMPTY, column,
                              np.empty(rnea.workspace_size(case.nj, case.nv)))
        assert_rel(M[:, c], column[0], TOL, f"{name} M[:, {c}]", batch_ndim=0)


# ----------------------------------------------------------------------------- ABA

@pytest.mark.parametrize("with_fext", [False, True], ids=["no_fext", "fext"])
@pytest.mark.parametrize("name", PIN_CASES)
def test_forward_dynamics_matches_pinocchio(name, with_fext):
    case = get_case(name)
    for k in range(N_STATES):
        if with_fext:
            a = case.forward_dynamics(k, f_ext=case.f_ext[k])
            ref = pin.aba(case.pmodel, case.pdata, case.q_pin[k], case.v[k], case.tau[k], case.pin_forces(k))
        else:
            a = case.forward_dynamics(k)
            ref = pin.aba(case.pmodel, case.pdata, case.q_pin[k], case.v[k], case.tau[k])
        assert_rel(a, ref, TOL_INVERSE, f"{name} aba", batch_ndim=0)


@pytest.mark.parametrize("name", OWN_CASES)
def test_forward_dynamics_matches_numpy(name):
    case = get_case(name)
    ref = mb.forward_dynamics(case.model, case.q, case.v, case.tau, f_ext=case.f_ext)
    for k in range(N_STATES):
        assert_rel(case.forward_dynamics(k, f_ext=case.f_ext[k]), ref[k], TOL_INVERSE,
                   f"{name} aba vs mb.forward_dynamics", batch_ndim=0)


@pytest.mark.parametrize("name", OWN_CASES)
def test_forward_dynamics_inverts_rnea_kernel(name):
    """``ABA(q, v, RNEA(q, v, a, f), f) = a`` with and without external forces."""
    case = get_case(name)
    for k in range(N_STATES):
        for f_ext in (EMPTY, case.f_ext[k]):
            tau = case.inverse_dynamics(k, case.a[k], f_ext)
            a = case.forward_dynamics(k, tau=tau, f_ext=f_ext if f_ext.size else None)
            assert_rel(a, case.a[k], TOL_INVERSE, f"{name} ABA(RNEA(a))", batch_ndim=0)


@pytest.mark.parametrize("name", ["panda", "random_tree_0"])
def test_forward_dynamics_empty_inputs_are_zero(name):
    """``v``, ``τ`` or ``f_ext`` of length 0 act as zero."""
    case = get_case(name)
    zeros_v, zeros_f = np.zeros(case.nv), np.zeros(6 * case.nj)
    np.testing.assert_array_equal(case.forward_dynamics(0, v=EMPTY, tau=EMPTY),
                                  case.forward_dynamics(0, v=zeros_v, tau=zeros_v, f_ext=zeros_f))


# ----------------------------------------------------------------------------- M⁻¹

@pytest.mark.parametrize("name", PIN_CASES)
def test_inverse_mass_matrix_matches_pinocchio(name):
    case = get_case(name)
    for k in range(N_STATES):
        Minv = case.inverse_mass_matrix(k)
        assert np.array_equal(Minv, Minv.T), "M⁻¹ is not exactly symmetric"
        ref = _symmetrised(pin.computeMinverse(case.pmodel, case.pdata, case.q_pin[k]))
        assert_rel(Minv, ref, TOL_INVERSE, f"{name} computeMinverse", batch_ndim=0)


@pytest.mark.parametrize("name", OWN_CASES)
def test_inverse_mass_matrix_matches_numpy_and_inverts_crba(name):
    case = get_case(name)
    ref = mb.inverse_mass_matrix(case.model, case.q)
    for k in range(N_STATES):
        Minv = case.inverse_mass_matrix(k)
        assert_rel(Minv, ref[k], TOL_INVERSE, f"{name} M⁻¹ vs mb.inverse_mass_matrix", batch_ndim=0)
        assert_rel(Minv @ case.mass_matrix(k), np.eye(case.nv), TOL_INVERSE, f"{name} M⁻¹ M", batch_ndim=0)


@pytest.mark.parametrize("name", ["panda", "random_tree_1"])
def test_inverse_mass_matrix_columns_are_aba_of_unit_forces(name):
    """Column c of ``M⁻¹`` is ABA's acceleration for ``τ = e_c`` at rest without gravity."""
    case = get_case(name)
    reals = case.tree.reals.copy()
    reals[case.nj] = 0.0
    Minv = case.inverse_mass_matrix(0)
    a = np.empty((1, case.nv))
    for c in range(case.nv):
        aba.forward_dynamics(case.tree.joints, reals, case.tree.bodies, case.q[0], EMPTY, np.eye(case.nv)[c], EMPTY,
                             a, np.empty(aba.workspace_size(case.nj, case.nv)))
        assert_rel(Minv[:, c], a[0], TOL_INVERSE, f"{name} M⁻¹[:, {c}]", batch_ndim=0)


# ----------------------------------------------------------------------------- singular D

def _massless_leaf_model(joint):
    """A massive revolute link carrying ``joint`` on a massless body: that joint moves no inertia."""
    b = mb.ModelBuilder("massless_leaf")
    b.add_body("link", jt.Revolute((0.0, 1.0, 0.0)), inertia=mb.inertia.box(1.0, np.array([0.1, 0.2, 0.3])))
    b.add_body("tip", joint, parent="link", placement=mb.spatial.pose_matrix(np.eye(3), np.array([0.0, 0.0, 0.5])))
    return b.build()


@pytest.mark.parametrize("joint", [jt.Revolute((1.0, 0.0, 0.0)), jt.Spherical(), jt.FreeFlyer()],
                         ids=["revolute", "spherical", "free-flyer"])
def test_massless_joint_gives_non_finite_values_without_raising(joint):
    model = _massless_leaf_model(joint)
    tree = compile_tree(model)
    nj, nv = model.njoints, model.nv
    q = model.random_configuration(np.random.default_rng(0))
    a = np.zeros((1, nv))
    aba.forward_dynamics(tree.joints, tree.reals, tree.bodies, q, np.ones(nv), np.ones(nv), EMPTY, a,
                         np.empty(aba.workspace_size(nj, nv)))
    assert not np.all(np.isfinite(a))
    Minv = np.zeros((nv, nv))
    crba.inverse_mass_matrix(tree.joints, tree.reals, tree.bodies, q, EMPTY, EMPTY, EMPTY, Minv,
                             np.empty(crba.workspace_size(nj, nv)))
    assert not np.all(np.isfinite(Minv))
    # CRBA has nothing to invert: M is finite, with a zero block for the massless joint
    M = np.empty((nv, nv))
    crba.mass_matrix(tree.joints, tree.reals, tree.bodies, q, EMPTY, EMPTY, EMPTY, M,
                     np.empty(crba.workspace_size(nj, nv)))
    assert np.all(np.isfinite(M)) and np.all(M[1:, 1:] == 0.0)


def test_model_without_moving_joints():
    """No joints (a URDF of fixed joints only): nothing to compute, and nothing read or written."""
    model = mb.load_urdf(STATUE_URDF)
    tree = compile_tree(model)
    assert model.njoints == 0 and model.nv == 0
    a, M, Minv = np.empty((1, 0)), np.empty((0, 0)), np.empty((0, 0))
    aba.forward_dynamics(tree.joints, tree.reals, tree.bodies, np.zeros(0), EMPTY, EMPTY, EMPTY, a,
                         np.empty(aba.workspace_size(0, 0)))
    crba.inverse_mass_matrix(tree.joints, tree.reals, tree.bodies, np.zeros(0), EMPTY, EMPTY, EMPTY, Minv,
                             np.empty(crba.workspace_size(0, 0)))
    crba.mass_matrix(tree.joints, tree.reals, tree.bodies, np.zeros(0), EMPTY, EMPTY, EMPTY, M,
                     np.empty(crba.workspace_size(0, 0)))


# ----------------------------------------------------------------------------- plain Python

_PLAIN_PYTHON = textwrap.dedent("""
    import sys
    import numpy as np
    sys.path.insert(0, {tests!r})
    from conftest import random_tree_model
    from multibody.kernels import aba, crba
    from multibody.tree import compile_tree
    model = random_tree_model(0)
    tree = compile_tree(model)
    nj, nv, E = model.njoints, model.nv, np.zeros(0)
    rng = np.random.default_rng(7)
    q, v, tau, f = (model.random_configuration(rng), rng.standard_normal(nv), rng.standard_normal(nv),
                    rng.standard_normal(6 * nj))
    M, Minv, a = np.empty((nv, nv)), np.empty((nv, nv)), np.empty((1, nv))
    crba.mass_matrix(tree.joints, tree.reals, tree.bodies, q, E, E, E, M, np.empty(crba.workspace_size(nj, nv)))
    aba.forward_dynamics(tree.joints, tree.reals, tree.bodies, q, v, tau, f, a, np.empty(aba.workspace_size(nj, nv)))
    crba.inverse_mass_matrix(tree.joints, tree.reals, tree.bodies, q, E, E, E, Minv,
                             np.empty(crba.workspace_size(nj, nv)))
    # a joint that moves no inertia: NaN, no ZeroDivisionError from plain Python either
    import multibody as mb
    from multibody import joints as jt
    b = mb.ModelBuilder("massless_leaf")
    b.add_body("link", jt.Revolute((0.0, 1.0, 0.0)), inertia=mb.inertia.box(1.0, np.array([0.1, 0.2, 0.3])))
    b.add_body("tip", jt.Spherical(), parent="link")
    leaf = b.build()
    leaf_tree = compile_tree(leaf)
    a_leaf = np.empty((1, leaf.nv))
    aba.forward_dynamics(leaf_tree.joints, leaf_tree.reals, leaf_tree.bodies, leaf.random_configuration(rng),
                         np.ones(leaf.nv), np.ones(leaf.nv), E, a_leaf, np.empty(aba.workspace_size(2, leaf.nv)))
    assert not np.all(np.isfinite(a_leaf))
    np.save(sys.argv[1], np.concatenate([M.ravel(), Minv.ravel(), a.ravel()]))
""")


def test_plain_python_gives_the_compiled_numbers(tmp_path):
    """Under ``NUMBA_DISABLE_JIT=1`` the kernels run as Python, with the same numbers (to rounding:
    LLVM may fuse or reorder floating-point operations)."""
    script = tmp_path / "run.py"
    script.write_text(_PLAIN_PYTHON.format(tests=os.path.dirname(__file__)))
    results = {}
    for jit in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=jit)
        subprocess.run([sys.executable, str(script), str(tmp_path / f"out{jit}.npy")], check=True, env=env,
                       cwd=os.path.dirname(os.path.dirname(__file__)))
        results[jit] = np.load(tmp_path / f"out{jit}.npy")
    assert np.all(np.isfinite(results["1"]))
    assert_rel(results["1"], results["0"], TOL_INVERSE, "plain Python vs compiled", batch_ndim=0)


@pytest.mark.parametrize("kind", ["revolute", "prismatic"])
def test_one_coordinate_factor_equals_general(kind):
    """ABA's path for a joint of one coordinate (:func:`aba.factor_single`, scalar ``D``, and :func:`aba.add_reduced`
    adding ``I^a = I^A − U D⁻¹ Uᵀ`` to the parent's) gives the ``U``, ``U D⁻¹``, ``D⁻¹`` and ``I^a`` of the general
    factorisation (:func:`aba.factor_joint`, ``D`` inverted by its LDLᵀ factor, ``I^a`` in place) to 1e-13, for random
    symmetric positive definite articulated inertias (packed), subspace columns of unit axes (principal and not)
    moved by random poses, and armatures; and leaves the joint's ``I^A`` as it is."""
    from multibody.kernels import joints as kinds
    from multibody.kernels.spatial import motion_to_parent
    from multibody.tree import ARMATURE, REAL_SIZE

    code = kinds.REVOLUTE if kind == "revolute" else kinds.PRISMATIC
    rng = np.random.default_rng(11 + code)
    upper = np.triu_indices(6)
    axes = [(0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)] + [tuple(a / np.linalg.norm(a))
                                                                     for a in rng.standard_normal((5, 3))]
    for axis in axes:
        G = rng.standard_normal((6, 6))
        inertia = G @ G.T + 0.1 * np.eye(6)
        packed = inertia[upper]
        arm = float(rng.uniform(0.0, 0.5))
        reals = np.zeros((1, REAL_SIZE))
        reals[0, ARMATURE] = arm
        # the column in world coordinates, as ABA holds it
        R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        s = motion_to_parent(tuple(R.ravel()), tuple(rng.standard_normal(3)), kinds.subspace_column(code, axis, 0))
        at = 7  # the matrix anywhere in the workspace
        single = np.full(at + aba.PACKED + 7, np.nan)
        single[at : at + aba.PACKED] = packed
        block, scratch = np.full(aba.BLOCK, np.nan), np.full(108, np.nan)
        block[aba.ARTICULATED : aba.ARTICULATED + aba.PACKED] = packed
        block[aba.SUBSPACE : aba.SUBSPACE + 6] = s
        U, U_D, d_inv = aba.factor_single(single, at, s, arm)
        # the parent's I^A (packed, at offset 3), to which I^a is added
        parent = rng.standard_normal(aba.PACKED)
        reduced = np.full(aba.PACKED + 3, np.nan)
        reduced[3:] = parent
        aba.add_reduced(single, at, U_D, U, reduced, 3)
        aba.factor_joint(1, reals, 0, block, scratch)
        scale = np.abs(inertia).max()
        np.testing.assert_allclose(U, scratch[:6], rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(U_D, block[aba.U_D_INV : aba.U_D_INV + 6], rtol=0, atol=1e-13)
        assert d_inv == pytest.approx(scratch[72], rel=1e-13)
        np.testing.assert_allclose(reduced[3:] - parent, block[aba.ARTICULATED : aba.ARTICULATED + aba.PACKED], rtol=0,
                                   atol=1e-13 * scale)
        assert np.isnan(reduced[:3]).all()
        # the joint's own I^A is read, not written
        assert np.array_equal(single[at : at + aba.PACKED], packed)
        assert np.isnan(single[:at]).all() and np.isnan(single[at + aba.PACKED :]).all()


def test_packed_index_walks_the_upper_triangle_by_rows():
    """:func:`aba.packed_index` numbers the upper triangle of a 6×6 row by row, 0 to 20, as NumPy's
    ``triu_indices`` orders it; :func:`aba.matrix_times` of the packed triangle is the symmetric matrix's product."""
    rows, columns = np.triu_indices(6)
    assert [aba.packed_index(int(r), int(c)) for r, c in zip(rows, columns)] == list(range(aba.PACKED))
    rng = np.random.default_rng(5)
    G = rng.standard_normal((6, 6))
    Y, m = G + G.T, rng.standard_normal(6)
    np.testing.assert_allclose(aba.matrix_times(Y[rows, columns], 0, tuple(m)), Y @ m, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("kind", ["revolute", "prismatic"])
def test_principal_axis_pose_equals_general(kind):
    """The faster branch of a revolute or prismatic joint about a principal axis ``±e_x, ±e_y, ±e_z`` of its frame
    (:func:`multibody.kernels.joints.placed_transform`) gives the pose ``X_T X_J(q)`` of the general product
    (``compose(X_T, transform(q))``, Rodrigues' rotation) to 1e-13 on random placements and coordinates; and the
    subspace column moved to the parent (:func:`multibody.kernels.joints.subspace_column_to_parent`) equals
    ``motion_to_parent`` of the column for every axis."""
    from multibody.kernels import joints as kinds
    from multibody.kernels.spatial import compose, motion_to_parent

    code = kinds.REVOLUTE if kind == "revolute" else kinds.PRISMATIC
    rng = np.random.default_rng(23 + code)
    principal = [tuple(float(sign) * np.eye(3)[a]) for a in range(3) for sign in (1, -1)]
    for axis in principal + [tuple(a / np.linalg.norm(a)) for a in rng.standard_normal((3, 3))]:
        assert (kinds.principal_axis(axis)[0] >= 0) == (axis in principal)
        for _ in range(5):
            R_T = tuple(np.linalg.qr(rng.standard_normal((3, 3)))[0].ravel())
            p_T = tuple(rng.standard_normal(3))
            q = rng.uniform(-4.0, 4.0, 2)
            R, p = kinds.placed_transform(code, axis, q, 1, R_T, p_T)
            R_ref, p_ref = compose(R_T, p_T, *kinds.transform(code, axis, q, 1))
            np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-13)
            np.testing.assert_allclose(p, p_ref, rtol=0, atol=1e-13)
            column = kinds.subspace_column_to_parent(code, axis, 0, R, p)
            np.testing.assert_allclose(column, motion_to_parent(R, p, kinds.subspace_column(code, axis, 0)), rtol=0,
                                       atol=1e-13)


def test_forward_dynamics_of_a_floating_robot_far_from_the_origin_keeps_its_digits():
    """ABA works about the first joint's origin, not the world's: a floating Panda moved 5 km away has the
    accelerations it has near the origin (translation invariance) to 1e-12 relative, where spatial quantities about
    the world origin would lose four digits (velocities of ``ω × p`` ~ 10⁴ beside ones of ~1)."""
    model = mb.robots.load("panda", floating_base=True)
    rng = np.random.default_rng(31)
    for _ in range(5):
        q, v, tau = model.random_configuration(rng), rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        q[:3] = rng.uniform(-1.0, 1.0, 3)
        near = mb.forward_dynamics(model, q, v, tau)
        q[:3] += [3e3, -4e3, 1e3]
        far = mb.forward_dynamics(model, q, v, tau)
        np.testing.assert_allclose(far, near, rtol=0, atol=1e-12 * np.abs(near).max())
