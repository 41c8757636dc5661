"""The Lagrangian's terms that a variational integrator's step reads at one configuration.

``L = ½ vᵀ M(q) v − U(q)`` (``M`` of :func:`~multibody.kernels.crba.mass_matrix`, the joints' armature on
its diagonal) has ``∂L/∂v = M(q) v`` and, left-trivialised on the Lie-group joints
(``d/dε L(q exp(ε η), v)``, ``docs/theory.md``),

    ∂L/∂q = C(q, v)ᵀ v − g(q) − ad_vᵀ M(q) v

(``C`` the Christoffel-consistent Coriolis matrix, :mod:`~multibody.kernels.coriolis`, whose
``Ṁ = C + Cᵀ`` gives ``Cᵀ v = ½ vᵀ (∂M/∂q) v``; ``g = ∂U/∂q``, RNEA at rest; ``ad`` of
:func:`~multibody.kernels.configuration.coadjoint`, zero on the commutative joints).

The variational integrator moves a free flyer on SO(3) × R³, with the group velocities ``w`` whose
linear part is in the parent frame: ``v = T(q) w`` with ``T = Rᵀ`` on that part and the identity
elsewhere. Its Lagrangian ``L_G(q, w) = L(q, T(q) w)`` has

    M_G = Tᵀ M T,       ∂L_G/∂q = Tᵀ ∂L/∂q(q, T w) + (0, p_lin × v_lin)  (p = M v, on each free flyer),

the second term from turning the body under a fixed parent-frame velocity
(:mod:`multibody.variational`, "Lie-group joints").
"""

from __future__ import annotations

from .layout import IQ, IV, KIND
from . import coriolis, crba, rnea
from . import joints as kinds
from .configuration import coadjoint
from .jit import njit
from .joints import load4
from .spatial import nan_unless_finite


def workspace_size(nj, nv):
    """Floats of workspace one state needs: ``M``, ``C`` (``nv²`` each), ``g``, ``v``, ``M v`` and
    ``ad_vᵀ M v`` (``nv`` each), and the largest workspace of the kernels it calls."""
    return 2 * nv * nv + 4 * nv + max(crba.workspace_size(nj, nv), coriolis.workspace_size(nj, nv),
                                      rnea.workspace_size(nj, nv))


@njit(cache=True, error_model="numpy")
def to_group_velocities(joints, q, A):
    """``A ← A T(q)`` for rows ``A (k, nv)`` on the joints' velocities: onto the group velocities, a free
    flyer's linear columns times ``Rᵀ`` (``v_lin = Rᵀ w_lin``)."""
    for i in range(joints.shape[0]):
        if joints[i, KIND] == kinds.FREE_FLYER:
            R, iv = kinds.quat_rotation(load4(q, joints[i, IQ] + 3)), joints[i, IV]
            for r in range(A.shape[0]):
                x, y, z = A[r, iv], A[r, iv + 1], A[r, iv + 2]
                for k in range(3):
                    A[r, iv + k] = x * R[3 * k] + y * R[3 * k + 1] + z * R[3 * k + 2]


@njit(cache=True, error_model="numpy")
def lagrangian_terms(joints, reals, frames, q, w, group, x3, out, ws):
    """``M`` and ``∂L/∂q`` (module docstring) at ``(q, w)`` into ``out (nv + 1, nv)``: rows ``0 … nv − 1``
    the mass matrix (kg, kg m, kg m²), row ``nv`` the gradient (N, N m per coordinate).

    ``q (nq,)``; ``w (nv,)`` the velocities: the joints' own ``v`` when ``group`` has length 0, the
    variational integrator's group velocities (a free flyer's linear velocity in the parent frame)
    when it has one entry, and then ``M_G``, ``∂L_G/∂q``. ``frames`` and ``x3`` are unused.
    """
    nv = out.shape[1]
    M = ws[: nv * nv].reshape((nv, nv))
    C = ws[nv * nv : 2 * nv * nv].reshape((nv, nv))
    base = 2 * nv * nv
    g = ws[base : base + nv].reshape((1, nv))
    v = ws[base + nv : base + 2 * nv]
    p = ws[base + 2 * nv : base + 3 * nv]
    ad = ws[base + 3 * nv : base + 4 * nv].reshape((1, nv))
    scratch = ws[base + 4 * nv :]
    grouped = group.shape[0] > 0
    # v = T w: a free flyer's linear velocity from the parent frame into its body frame, v_lin = Rᵀ w_lin
    for c in range(nv):
        v[c] = w[c]
    if grouped:
        for i in range(joints.shape[0]):
            if joints[i, KIND] == kinds.FREE_FLYER:
                R, iv = kinds.quat_rotation(load4(q, joints[i, IQ] + 3)), joints[i, IV]
                x, y, z = w[iv], w[iv + 1], w[iv + 2]
                for r in range(3):
                    v[iv + r] = R[r] * x + R[3 + r] * y + R[6 + r] * z
    crba.mass_matrix(joints, reals, frames, q, x3, x3, x3, M, scratch)
    coriolis.coriolis_matrix(joints, reals, frames, q, v, x3, x3, C, scratch)
    rnea.inverse_dynamics(joints, reals, frames, q, x3, x3, x3, g, scratch)
    # p = M v
    for r in range(nv):
        total = 0.0
        for c in range(nv):
            total += M[r, c] * v[c]
        p[r] = total
    coadjoint(joints, reals, frames, v, p, x3, x3, ad, scratch)
    gradient = out[nv]
    # ∂L/∂q = Cᵀ v − g − ad_vᵀ M v
    for c in range(nv):
        total = 0.0
        for r in range(nv):
            total += C[r, c] * v[r]
        gradient[c] = total - g[0, c] - ad[0, c]
    for r in range(nv):
        for c in range(nv):
            out[r, c] = M[r, c]
    if grouped:
        to_group_velocities(joints, q, out[:nv])  # M T
        for i in range(joints.shape[0]):
            if joints[i, KIND] == kinds.FREE_FLYER:
                R, iv = kinds.quat_rotation(load4(q, joints[i, IQ] + 3)), joints[i, IV]
                # M_G = Tᵀ (M T): the linear block's rows times R (the columns are turned below)
                for c in range(nv):
                    x, y, z = out[iv, c], out[iv + 1, c], out[iv + 2, c]
                    for k in range(3):
                        out[iv + k, c] = R[3 * k] * x + R[3 * k + 1] * y + R[3 * k + 2] * z
                # ∂L_G/∂q = Tᵀ ∂L/∂q + (0, p_lin × v_lin)
                x, y, z = gradient[iv], gradient[iv + 1], gradient[iv + 2]
                for k in range(3):
                    gradient[iv + k] = R[3 * k] * x + R[3 * k + 1] * y + R[3 * k + 2] * z
                gradient[iv + 3] += p[iv + 1] * v[iv + 2] - p[iv + 2] * v[iv + 1]
                gradient[iv + 4] += p[iv + 2] * v[iv] - p[iv] * v[iv + 2]
                gradient[iv + 5] += p[iv] * v[iv + 1] - p[iv + 1] * v[iv]
    nan_unless_finite(q, w, group, x3, out)
