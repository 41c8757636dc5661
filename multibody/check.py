"""Cross-check a model against Pinocchio at random states (``multibody check URDF``).

Pinocchio (``pip install pin``) is optional: this module imports it only when called.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import dynamics, joints, kinematics
from .urdf import load_urdf

#: Largest accepted relative error for quantities computed without solving a linear system.
TOLERANCE = 1e-9


@dataclass
class Row:
    quantity: str
    error: float        # largest relative error over the samples
    tolerance: float

    @property
    def ok(self):
        return self.error <= self.tolerance


def to_pinocchio_configuration(model, q):
    """Our ``q`` in Pinocchio's layout: a continuous joint's angle θ becomes ``(cos θ, sin θ)``."""
    blocks = []
    for joint, start in zip(model.joints, model.idx_q):
        block = q[..., start : start + joint.nq]
        if isinstance(joint, joints.Continuous):
            block = np.concatenate([np.cos(block), np.sin(block)], axis=-1)
        blocks.append(block)
    return np.concatenate(blocks, axis=-1) if blocks else q.copy()


def _relative(ours, reference, floor=0.0):
    """``max |ours − reference| / max(max |reference|, floor)``: relative, but against at least the
    natural size ``floor`` of the quantity at that state, so that a result that is zero in exact
    arithmetic (a Coriolis matrix of one joint) compares its rounding with the terms it is made of
    (absolute error when both are zero)."""
    ours, reference = np.asarray(ours, dtype=float), np.asarray(reference, dtype=float)
    scale = max(np.abs(reference).max(initial=0.0), floor)
    error = np.abs(ours - reference).max(initial=0.0)
    return error / scale if scale > 0.0 else error


def _symmetric(upper):
    return np.triu(upper) + np.triu(upper, 1).T


def compare_with_pinocchio(path, floating_base=False, samples=20, seed=0, package_dirs=None):
    """Largest relative errors of every quantity against Pinocchio over ``samples`` random states.

    Returns ``(model, rows, largest cond(M))``. ABA and ``M⁻¹`` solve a linear system, so their
    forward error (the difference from Pinocchio's result) may grow with the condition number:
    its tolerance is ``max(1e-9, 10 κ(M) ε)``. Their *backward* error, the residual in
    Pinocchio's own ``M`` and RNEA relative to the sizes involved, must stay below 1e-9 whatever κ.
    Raises ``RuntimeError`` when the two joint orders differ.
    """
    import pinocchio as pin

    model = load_urdf(path, floating_base=floating_base, package_dirs=package_dirs, invalid_inertia="warn")
    reference = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer()) if floating_base \
        else pin.buildModelFromUrdf(str(path))
    if list(reference.names)[1:] != list(model.joint_names):
        raise RuntimeError(f"joint order differs from Pinocchio's: {list(reference.names)[1:]} vs {list(model.joint_names)}")
    data = reference.createData()
    rng = np.random.default_rng(seed)
    errors, condition = {}, 1.0

    def record(name, ours, theirs, floor=1.0):
        # (Pinocchio returns a matrix with one column, a Jacobian of one coordinate, as a vector)
        theirs = np.reshape(theirs, np.shape(ours))
        errors[name] = max(errors.get(name, 0.0), _relative(ours, theirs, floor))

    frame_ids = [reference.getFrameId(name, pin.BODY) for name in model.body_names]
    for _ in range(samples):
        q = model.random_configuration(rng)
        v, a, tau = rng.standard_normal((3, model.nv))
        f_ext = rng.standard_normal((model.njoints, 6))
        q_pin = to_pinocchio_configuration(model, q)
        f_pin = [pin.Force.Zero()] + [pin.Force(f) for f in f_ext]

        pin.forwardKinematics(reference, data, q_pin)
        pin.updateFramePlacements(reference, data)
        pin.computeJointJacobians(reference, data, q_pin)
        placements = kinematics.forward_kinematics(model, q)
        for b, frame in enumerate(frame_ids):
            if frame < reference.nframes:
                record("forward kinematics", placements[b], data.oMf[frame].homogeneous)
                if model.nv:  # (Pinocchio's getFrameJacobian crashes on a model without joints)
                    record("jacobian", kinematics.jacobian(model, q, b),
                           pin.getFrameJacobian(reference, data, frame, pin.LOCAL_WORLD_ALIGNED))
        if model.nv == 0:
            continue
        M_pin = _symmetric(pin.crba(reference, data, q_pin))
        condition = max(condition, np.linalg.cond(M_pin))
        # natural sizes at this state: of the forces (N, N m) and energies (J) M (a + v v) and m g
        force = np.abs(M_pin).max() * (np.abs(a).max() + np.abs(tau).max() + np.abs(v).max() ** 2) \
            + model.total_mass * np.linalg.norm(model.gravity)
        energy = np.abs(M_pin).max() * np.abs(v).max() ** 2 + model.total_mass * np.linalg.norm(model.gravity)
        record("mass matrix (crba)", dynamics.mass_matrix(model, q), M_pin, 0.0)
        record("mass matrix (lagrangian)", dynamics.mass_matrix(model, q, method="lagrangian"), M_pin, 0.0)
        C_pin = pin.computeCoriolisMatrix(reference, data, q_pin, v)
        record("coriolis (recursive)", dynamics.coriolis_matrix(model, q, v), C_pin, np.abs(M_pin).max() * np.abs(v).max())
        if all(joint.nq == joint.nv for joint in model.joints):
            record("coriolis (lagrangian)", dynamics.coriolis_matrix(model, q, v, method="lagrangian"), C_pin,
                   np.abs(M_pin).max() * np.abs(v).max())
        record("gravity g(q)", dynamics.generalized_gravity(model, q), pin.computeGeneralizedGravity(reference, data, q_pin),
               force)
        record("bias h(q, v)", dynamics.bias_forces(model, q, v), pin.nonLinearEffects(reference, data, q_pin, v), force)
        record("inverse dynamics (rnea, f_ext)", dynamics.inverse_dynamics(model, q, v, a, f_ext),
               pin.rnea(reference, data, q_pin, v, a, f_pin), force)
        a_ours = dynamics.forward_dynamics(model, q, v, tau, f_ext)
        record("forward dynamics (aba, f_ext)", a_ours, pin.aba(reference, data, q_pin, v, tau, f_pin), 0.0)
        # Backward error: how far our a is from solving Pinocchio's own equations of motion.
        residual = pin.rnea(reference, data, q_pin, v, a_ours, f_pin) - tau
        backward = np.abs(residual).max() / (np.abs(M_pin).sum(axis=1).max() * np.abs(a_ours).max() + np.abs(tau).max())
        errors["forward dynamics, backward error"] = max(errors.get("forward dynamics, backward error", 0.0), backward)
        M_inv = dynamics.inverse_mass_matrix(model, q)
        record("inverse mass matrix", M_inv, _symmetric(pin.computeMinverse(reference, data, q_pin)), 0.0)
        backward = np.abs(M_pin @ M_inv - np.eye(model.nv)).sum(axis=1).max() / (
            np.abs(M_pin).sum(axis=1).max() * np.abs(M_inv).sum(axis=1).max())
        errors["inverse mass matrix, backward error"] = max(errors.get("inverse mass matrix, backward error", 0.0), backward)
        record("kinetic energy", dynamics.kinetic_energy(model, q, v), pin.computeKineticEnergy(reference, data, q_pin, v),
               energy)
        record("potential energy", dynamics.potential_energy(model, q), pin.computePotentialEnergy(reference, data, q_pin),
               energy)

    solve_tolerance = max(TOLERANCE, 10.0 * condition * np.finfo(float).eps)
    rows = [Row(name, error, solve_tolerance if name in ("forward dynamics (aba, f_ext)", "inverse mass matrix") else TOLERANCE)
            for name, error in errors.items()]
    return model, rows, condition


#: Largest accepted relative error against MuJoCo, for quantities computed without solving a linear system.
MUJOCO_TOLERANCE = 1e-10


def mujoco_reference(source):
    """MuJoCo's model of the MJCF ``source`` (a path or XML text) with everything our model leaves out turned
    off: contacts, joint limits, equalities and friction loss (its constraints), springs and dampers,
    actuators, fluid forces and gravity compensation. What remains are the equations of motion of the
    tree, ``M(q) qacc + qfrc_bias = qfrc_applied``, with armature."""
    import mujoco

    from .modelfiles import is_xml_text

    if is_xml_text(source):
        reference = mujoco.MjModel.from_xml_string(source)
    else:
        reference = mujoco.MjModel.from_xml_path(str(source))
    for name in ("mjDSBL_CONSTRAINT", "mjDSBL_CONTACT", "mjDSBL_LIMIT", "mjDSBL_EQUALITY", "mjDSBL_FRICTIONLOSS",
                 "mjDSBL_PASSIVE", "mjDSBL_SPRING", "mjDSBL_DAMPER", "mjDSBL_ACTUATION"):
        flag = getattr(mujoco.mjtDisableBit, name, None)
        if flag is not None:
            reference.opt.disableflags |= int(flag)
    reference.opt.density, reference.opt.viscosity = 0.0, 0.0
    reference.opt.wind[:] = 0.0
    reference.body_gravcomp[:] = 0.0
    return reference


def _full_mass_matrix(mujoco, model, data, out):
    """``mj_fullM`` into ``out``: its arguments are ``(m, d, dst)`` from MuJoCo 4, ``(m, dst, d.qM)`` before."""
    try:
        mujoco.mj_fullM(model, data, out)
    except TypeError:
        mujoco.mj_fullM(model, out, data.qM)


def compare_with_mujoco(source, samples=20, seed=0, package_dirs=None):
    """Largest relative errors of the model :func:`multibody.load_mjcf` makes of ``source`` against MuJoCo's
    (:func:`mujoco_reference`) over ``samples`` random states: ``M`` (``mj_fullM``), the bias forces
    (``qfrc_bias``), inverse dynamics (``mj_inverse``), forward dynamics (``qacc`` of ``mj_forward`` with
    ``qfrc_applied``), the bodies' and sites' placements (``xpos``, ``xmat``, ``site_xpos``, ``site_xmat``)
    and the bodies' Jacobians (``mj_jacBody``), MuJoCo's free-joint coordinates mapped to ours
    (:func:`multibody.mjcf.velocity_to_mujoco`).

    Returns ``(model, rows, largest cond(M))``; forward dynamics solves a linear system, so its tolerance
    is ``max(MUJOCO_TOLERANCE, 10 κ(M) ε)``.
    """
    import mujoco

    from . import mjcf

    model = mjcf.load_mjcf(source, package_dirs=package_dirs)
    reference = mujoco_reference(source)
    if reference.nq != model.nq or reference.nv != model.nv or reference.nbody - 1 > model.nbodies:
        raise RuntimeError(f"sizes differ from MuJoCo's: nq {model.nq} vs {reference.nq}, nv {model.nv} vs "
                           f"{reference.nv}, {model.nbodies} bodies and sites vs {reference.nbody - 1} bodies")
    data = mujoco.MjData(reference)
    rng = np.random.default_rng(seed)
    errors, condition = {}, 1.0
    sites = [(k, model.body_index(name)) for k in range(reference.nsite)
             if (name := mujoco.mj_id2name(reference, mujoco.mjtObj.mjOBJ_SITE, k)) and name in model.body_names]

    def record(name, ours, theirs, floor=1.0):
        errors[name] = max(errors.get(name, 0.0), _relative(ours, theirs, floor))

    for _ in range(samples):
        q = model.random_configuration(rng)
        v, a, tau = rng.standard_normal((3, model.nv))
        data.qpos[:], data.qvel[:] = mjcf.to_mujoco(model, q, v)
        data.qacc[:] = mjcf.acceleration_to_mujoco(model, q, v, a)
        T = mjcf.velocity_to_mujoco(model, q)
        mujoco.mj_inverse(reference, data)
        tau_inverse = T.T @ data.qfrc_inverse
        data.qfrc_applied[:] = T @ tau
        data.ctrl[:] = 0.0
        mujoco.mj_forward(reference, data)
        M_mj = np.zeros((model.nv, model.nv))
        _full_mass_matrix(mujoco, reference, data, M_mj)
        M_ref = T.T @ M_mj @ T
        condition = max(condition, np.linalg.cond(M_ref))
        force = np.abs(M_ref).max() * (np.abs(a).max() + np.abs(tau).max() + np.abs(v).max() ** 2) \
            + model.total_mass * np.linalg.norm(model.gravity)
        placements = kinematics.forward_kinematics(model, q)
        for b in range(1, reference.nbody):
            record("body placements", placements[b - 1, :3], np.column_stack(
                [data.xmat[b].reshape(3, 3), data.xpos[b]]))
            jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            mujoco.mj_jacBody(reference, data, jacp, jacr, b)
            record("jacobian", kinematics.jacobian(model, q, b - 1), np.vstack([jacp, jacr]) @ T)
        for k, b in sites:
            record("site placements", placements[b, :3], np.column_stack(
                [data.site_xmat[k].reshape(3, 3), data.site_xpos[k]]))
        record("mass matrix (crba)", dynamics.mass_matrix(model, q), M_ref, 0.0)
        # at a = 0 our free joints' qacc is Ṫ v, whose forces MuJoCo's bias leaves out
        qacc_of_rest = mjcf.acceleration_to_mujoco(model, q, v, np.zeros(model.nv))
        record("bias h(q, v)", dynamics.bias_forces(model, q, v), T.T @ (data.qfrc_bias + M_mj @ qacc_of_rest), force)
        record("inverse dynamics", dynamics.inverse_dynamics(model, q, v, a), tau_inverse, force)
        a_ref = T.T @ (data.qacc - qacc_of_rest)
        record("forward dynamics", dynamics.forward_dynamics(model, q, v, tau), a_ref, 0.0)
    solve_tolerance = max(MUJOCO_TOLERANCE, 10.0 * condition * np.finfo(float).eps)
    rows = [Row(name, error, solve_tolerance if name == "forward dynamics" else MUJOCO_TOLERANCE)
            for name, error in errors.items()]
    return model, rows, condition
