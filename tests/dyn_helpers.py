"""Helpers shared by the dynamics tests (``test_dynamics_*.py``).

Re-exports what ``conftest.py`` already provides (example-robot-data lookup, Pinocchio q mapping,
the random tree that uses every joint type) and adds:

* ``rel_err``: per-sample relative error ``max|ours − ref| / max(1, max|ref|)``;
* ``assert_rel``: the same, asserted against a tolerance with a readable message;
* ``coordinate_tree_model(seed)``: a random tree whose joints all have ``v = q̇``
  (Revolute with random axes, Continuous, Prismatic, Translation, with branches and fixed
  attachments), on which the Christoffel ("lagrangian") Coriolis matrix and ``∂M/∂q`` apply;
* ``dynamics_calls(model)``: every batched dynamics function as ``name -> f(q, v, a, f_ext)``.
"""

from __future__ import annotations

import numpy as np

import multibody as mb
from multibody import joints as jt
from multibody.dynamics import mass_matrix_derivative

from conftest import (  # noqa: F401  (re-exported)
    erd_urdf,
    q_to_pinocchio,
    random_axis,
    random_inertia,
    random_placement,
    random_tree_model,
)


#: A URDF with only fixed joints (no degrees of freedom): 2 kg base (centre of mass 0.5 m up),
#: 1 kg head 1.2 m up, a massless hat. Total 3 kg, centre of mass at z = (2·0.5 + 1·1.2)/3 m.
STATUE_URDF = """<?xml version="1.0"?>
<robot name="statue">
  <link name="base">
    <inertial><origin xyz="0 0 0.5"/><mass value="2"/>
      <inertia ixx="0.2" iyy="0.2" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <link name="head">
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <link name="hat"/>
  <joint name="neck" type="fixed"><parent link="base"/><child link="head"/><origin xyz="0 0 1.2"/></joint>
  <joint name="brim" type="fixed"><parent link="head"/><child link="hat"/><origin xyz="0 0 0.2"/></joint>
</robot>
"""


def rel_err(ours, ref, batch_ndim=1):
    """Per-sample relative error over the trailing (non-batch) axes, shape ``ours.shape[:batch_ndim]``."""
    ours, ref = np.asarray(ours, dtype=float), np.asarray(ref, dtype=float)
    assert ours.shape == ref.shape, f"shape {ours.shape} != reference shape {ref.shape}"
    axes = tuple(range(batch_ndim, ours.ndim))
    if ours.size == 0:
        return np.zeros(ours.shape[:batch_ndim])
    diff = np.abs(ours - ref).max(axis=axes) if axes else np.abs(ours - ref)
    scale = np.abs(ref).max(axis=axes) if axes else np.abs(ref)
    return diff / np.maximum(1.0, scale)


def assert_rel(ours, ref, tol, what="", batch_ndim=1):
    """Assert ``rel_err(ours, ref) <= tol`` for every sample; report the worst one."""
    err = rel_err(ours, ref, batch_ndim)
    worst = np.unravel_index(np.argmax(err), err.shape) if err.ndim else ()
    assert np.all(err <= tol), f"{what}: relative error {err[worst]:.3e} > {tol:.1e} (sample {worst})"
    return err


def coordinate_tree_model(seed=0, n_bodies=9):
    """A seeded random tree with ``v = q̇`` joints only, branches and fixed attachments.

    Every type among Revolute (random axis, limits), Continuous, Prismatic and Translation appears;
    the remaining bodies pick a random type and a random earlier parent, so the tree branches.
    A massive body is fixed to a moving one and a massless tip to that one.
    """
    rng = np.random.default_rng(1000 + seed)
    b = mb.ModelBuilder(f"coordinate_tree_{seed}")
    names = []
    makers = [
        lambda: (jt.Revolute(random_axis(rng)), dict(lower=[-2.5], upper=[2.0])),
        lambda: (jt.Continuous(random_axis(rng)), {}),
        lambda: (jt.Prismatic(random_axis(rng)), dict(lower=[-0.4], upper=[0.3])),
        lambda: (jt.Translation(), {}),
    ]
    for k in range(n_bodies):
        joint, limits = makers[k % 4]() if k < 4 else makers[rng.integers(4)]()
        parent = None if k == 0 else names[rng.integers(len(names))]
        name = f"{joint.kind}_{k}"
        b.add_body(name, joint, parent=parent, placement=random_placement(rng), inertia=random_inertia(rng), **limits)
        names.append(name)
    b.add_body("fixed_a", jt.Fixed(), parent=names[rng.integers(1, len(names))], placement=random_placement(rng),
               inertia=random_inertia(rng))
    b.add_body("fixed_tip", jt.Fixed(), parent="fixed_a", placement=random_placement(rng))
    return b.build()


def depth_first_model(model):
    """The same moving bodies re-added in depth-first order, and the joint permutation used.

    Pinocchio's ``crba``, ``computeMinverse`` and ``computeCoriolisMatrix`` assume that the velocities
    of every subtree are contiguous (depth-first joint order, as ``buildModelFromUrdf`` produces); on a
    hand-built model in another order they return wrong matrices while ``rnea`` and ``aba`` stay right.
    Our random trees attach bodies to random earlier parents, so their Pinocchio twins are built from
    this reordering. Each moving body keeps its joint, placement and lumped inertia; bodies fixed to
    the world are dropped (they play no part in the dynamics). Returns ``(model, order)`` with
    ``order[k]`` the original index of new joint k.
    """
    children = {i: [] for i in range(-1, model.njoints)}
    for i, parent in enumerate(model.parents):
        children[int(parent)].append(i)
    order = []

    def visit(i):
        order.append(i)
        for child in children[i]:
            visit(child)

    for root in children[-1]:
        visit(root)
    b = mb.ModelBuilder(f"{model.name}_depth_first", gravity=model.gravity)
    for i in order:
        parent = int(model.parents[i])
        s, nq = model.idx_q[i], model.joints[i].nq
        b.add_body(f"body_of_{model.joint_names[i]}", model.joints[i],
                   parent=None if parent < 0 else f"body_of_{model.joint_names[parent]}",
                   placement=model.joint_placements[i], inertia=model.joint_inertias[i],
                   joint_name=model.joint_names[i], lower=model.lower[s : s + nq], upper=model.upper[s : s + nq])
    return b.build(), order


def coordinate_permutations(model, order):
    """Index arrays ``(iq, iv)`` with ``q_new = q_old[..., iq]``, ``v_new = v_old[..., iv]``."""
    iq = np.concatenate([np.arange(model.idx_q[i], model.idx_q[i] + model.joints[i].nq) for i in order])
    iv = np.concatenate([np.arange(model.idx_v[i], model.idx_v[i] + model.joints[i].nv) for i in order])
    return iq, iv


def dynamics_calls(model):
    """Every public dynamics function of ``model`` as ``name -> f(q, v, a, f_ext)``.

    ``a`` is also used as ``tau``; functions without a ``v``/``a``/``f_ext`` argument ignore it.
    The Christoffel variants are included only when every joint has ``v = q̇``.
    """
    calls = {
        "mass_matrix[crba]": lambda q, v, a, f: mb.mass_matrix(model, q),
        "mass_matrix[lagrangian]": lambda q, v, a, f: mb.mass_matrix(model, q, method="lagrangian"),
        "coriolis_matrix[recursive]": lambda q, v, a, f: mb.coriolis_matrix(model, q, v),
        "generalized_gravity": lambda q, v, a, f: mb.generalized_gravity(model, q),
        "bias_forces": lambda q, v, a, f: mb.bias_forces(model, q, v),
        "inverse_dynamics": lambda q, v, a, f: mb.inverse_dynamics(model, q, v, a),
        "inverse_dynamics[f_ext]": lambda q, v, a, f: mb.inverse_dynamics(model, q, v, a, f_ext=f),
        "forward_dynamics": lambda q, v, a, f: mb.forward_dynamics(model, q, v, a),
        "forward_dynamics[f_ext]": lambda q, v, a, f: mb.forward_dynamics(model, q, v, a, f_ext=f),
        "inverse_mass_matrix": lambda q, v, a, f: mb.inverse_mass_matrix(model, q),
        "kinetic_energy": lambda q, v, a, f: mb.kinetic_energy(model, q, v),
        "potential_energy": lambda q, v, a, f: mb.potential_energy(model, q),
    }
    if all(joint.nq == joint.nv for joint in model.joints):
        calls["coriolis_matrix[lagrangian]"] = lambda q, v, a, f: mb.coriolis_matrix(model, q, v, method="lagrangian")
        calls["mass_matrix_derivative"] = lambda q, v, a, f: mass_matrix_derivative(model, q)
    return calls


def central_differences(f, model, q, rel_step=1e-6):
    """``∂f(q ⊕ δq)/∂δq`` at ``δq = 0`` by central differences in the tangent space: ``(m, nv)`` for
    ``f(q) -> (m,)``. The step of coordinate k is ``rel_step · max(1, |q|)`` (the scale of the
    configuration, so that positions far from the origin keep their digits)."""
    h = rel_step * max(1.0, float(np.abs(q).max()))
    columns = []
    for k in range(model.nv):
        step = np.zeros(model.nv)
        step[k] = h
        columns.append((np.asarray(f(model.integrate(q, step))) - np.asarray(f(model.integrate(q, -step)))) / (2 * h))
    return np.stack(columns, axis=-1)


def central_differences_vector(f, x, rel_step=1e-6):
    """``∂f/∂x`` of ``f(x (n,)) -> (m,)`` by central differences: ``(m, n)``; step ``rel_step · max(1, |x|)``."""
    h = rel_step * max(1.0, float(np.abs(x).max()))
    columns = []
    for k in range(x.shape[-1]):
        step = np.zeros_like(x)
        step[k] = h
        columns.append((np.asarray(f(x + step)) - np.asarray(f(x - step))) / (2 * h))
    return np.stack(columns, axis=-1)
