"""Configuration-space maps of a tree: the exponential ``q ⊕ v`` and logarithm ``q₁ ⊖ q₀`` of the
joints' configuration manifolds, the configuration rate ``q̇(q, v)``, and the charts of the Lie-group
integrator (``docs/conventions.md``, "Charts for integration"), as run by :class:`multibody.Model`.

Every kernel has the uniform signature ``kernel(joints, reals, frames, x0, x1, x2, x3, out, ws)`` of
:mod:`multibody.driver` and loops over the joints; per joint it calls the map of the same name in
:mod:`multibody.kernels.joints`, which dispatches on the joint's kind code (formulas and sources
there) and writes that joint's block of ``out`` at the joint's offset (``IQ`` for ``q``-shaped
results, ``IV`` for ``v``-shaped ones). Only :func:`exponential_terms` needs a workspace.
"""

from __future__ import annotations

from .layout import IQ, IV, KIND, NV
from . import joints as kinds
from .jit import njit
from .spatial import larger, nan_unless_finite


def workspace_size(nj, nv):
    """Floats of workspace one state needs: three 3×3 scratch matrices (:func:`exponential_terms`)."""
    return 3 * 9


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy")
def integrate(joints, reals, frames, q, v, x2, x3, out, ws):
    """Configuration exponential ``q ⊕ v`` into ``out[0] (nq,)`` (Solà et al. 2018 App. B–D, Pinocchio's
    ``integrate``): each joint moves with constant ``v`` for unit time (scale ``v`` by ``dt`` first).

    ``q (nq,)``, ``v (nv,)`` joint-frame velocities (rad/s, m/s). ``reals``, ``frames``, ``x2``, ``x3``,
    ``ws`` are unused.
    """
    for i in range(joints.shape[0]):
        kinds.integrate(joints[i, KIND], joints[i, NV], q, v, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def difference(joints, reals, frames, q0, q1, x2, x3, out, ws):
    """Configuration logarithm ``q₁ ⊖ q₀`` into ``out[0] (nv,)``: the ``v`` with ``q₀ ⊕ v = q₁``
    (Solà et al. 2018 App. B–D, Pinocchio's ``difference``). ``q0, q1 (nq,)``."""
    for i in range(joints.shape[0]):
        kinds.difference(joints[i, KIND], joints[i, NV], q0, q1, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q0, q1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def configuration_rate(joints, reals, frames, q, v, x2, x3, out, ws):
    """``q̇ (nq,)`` into ``out[0]`` of the configuration ``q (nq,)`` moving with velocity ``v (nv,)``:
    ``v`` for angles and displacements, ``½ q ⊗ (ω, 0)`` for quaternions (Solà et al. 2018 App. B),
    ``R v_lin`` for free-flyer positions and ``R(θ) (vx, vy)``, ``ω (−sin θ, cos θ)`` for planar joints."""
    for i in range(joints.shape[0]):
        kinds.configuration_rate(joints[i, KIND], joints[i, NV], q, v, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q, v, x2, x3, out)


@njit(cache=True, error_model="numpy")
def chart(joints, reals, frames, q0, delta, x2, x3, out, ws):
    """Configuration ``(nq,)`` into ``out[0]`` at chart coordinates ``delta (nv,)`` around ``q0 (nq,)``
    (``docs/conventions.md``, charts): ``q₀ + δ`` for angles and displacements, ``exp(δ) ⊗ q₀`` for
    quaternions (``δ`` a rotation vector in the parent frame, rad), planar angles turned by ``δ_θ``."""
    for i in range(joints.shape[0]):
        kinds.chart(joints[i, KIND], joints[i, NV], q0, delta, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q0, delta, x2, x3, out)


@njit(cache=True, error_model="numpy")
def chart_coordinates(joints, reals, frames, q0, q, x2, x3, out, ws):
    """Chart coordinates ``δ (nv,)`` into ``out[0]`` of the configuration ``q (nq,)`` around ``q0 (nq,)``:
    the inverse of :func:`chart` (``q − q₀`` for angles and displacements, ``log(q ⊗ q₀*)`` for
    quaternions, the planar angle's turn in ``(−π, π]``)."""
    for i in range(joints.shape[0]):
        kinds.chart_coordinates(joints[i, KIND], joints[i, NV], q0, q, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q0, q, x2, x3, out)


@njit(cache=True, error_model="numpy")
def chart_rate(joints, reals, frames, delta, w, x2, x3, out, ws):
    """``δ̇ (nv,)`` into ``out[0]`` of chart coordinates ``delta (nv,)`` moving with the parent-aligned
    velocity ``w (nv,)``: ``w``, but ``J_l(δ)⁻¹ ω`` for rotation vectors (Solà et al. 2018 App. B)."""
    for i in range(joints.shape[0]):
        kinds.chart_rate(joints[i, KIND], joints[i, NV], delta, w, joints[i, IV], out[0])
    nan_unless_finite(delta, w, x2, x3, out)


@njit(cache=True, error_model="numpy")
def velocity_alignment(joints, reals, frames, q, x1, x2, x3, out, ws):
    """The block-diagonal orthogonal ``T(q)`` into ``out (nv, nv)``, with ``w = T v`` the velocities in
    their parent frames' axes: ``diag(R, R)`` for a free flyer, ``R`` for a spherical joint, ``R(θ)``
    on a planar joint's ``(vx, vy)``, 1 for angles and displacements (``docs/conventions.md``, charts)."""
    n = out.shape[0]
    for r in range(n):
        for c in range(n):
            out[r, c] = 0.0
    for i in range(joints.shape[0]):
        kinds.velocity_alignment(joints[i, KIND], joints[i, NV], q, joints[i, IQ], joints[i, IV], out)
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def velocity_coupling(joints, reals, frames, v, x1, x2, x3, out, ws):
    """``κ(v) (nv,)`` into ``out[0]`` with ``d/dt (T v) = T (v̇ + κ(v))`` (see :func:`velocity_alignment`):
    ``[ω × v_lin; 0]`` for a free flyer, ``ω (−vy, vx, 0)`` for a planar joint, zero elsewhere."""
    for i in range(joints.shape[0]):
        kinds.velocity_coupling(joints[i, KIND], joints[i, NV], v, joints[i, IV], out[0])
    nan_unless_finite(v, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def chart_magnitude(joints, reals, frames, q, x1, x2, x3, out, ws):
    """Size ``(nv,)`` into ``out[0]`` of the configuration ``q (nq,)`` in each chart direction, against which
    an integrator measures relative errors of ``δ``: ``|q|`` for angles and displacements, 1 rad for
    rotation vectors (``docs/conventions.md``, charts)."""
    for i in range(joints.shape[0]):
        kinds.chart_magnitude(joints[i, KIND], joints[i, NV], q, joints[i, IQ], joints[i, IV], out[0])
    nan_unless_finite(q, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def normalize(joints, reals, frames, q, x1, x2, x3, out, ws):
    """``q (nq,)`` with every quaternion and planar ``(cos θ, sin θ)`` scaled to unit norm, into ``out[0]``."""
    for i in range(joints.shape[0]):
        kinds.normalize(joints[i, KIND], joints[i, NV], q, joints[i, IQ], out[0])
    nan_unless_finite(q, x1, x2, x3, out)


# ----------------------------------------------------------------------------- Lie-algebra terms of the joints

@njit(cache=True, error_model="numpy")
def rotation_block(kind, iv):
    """Offset in ``v`` of a joint's 3×3 block of the integrator's non-commutative group (:func:`_adjoint_block`):
    a spherical or planar joint's own ``iv``, a free flyer's rotation at ``iv + 3``; −1 for the others."""
    if kind == kinds.PLANAR or kind == kinds.SPHERICAL:
        return iv
    if kind == kinds.FREE_FLYER:
        return iv + 3
    return -1


@njit(cache=True, error_model="numpy")
def _adjoint_block(kind, x, iv, Y):
    """``ad_x`` of one joint's rotation group into ``Y[:3, :3]``; returns the offset of its block in ``v``,
    or −1 for a commutative joint.

    SO(3) (spherical ``x = ω``, and a free flyer's rotation ``x[iv + 3:iv + 6]``): ``ω×``; SE(2) (planar,
    ``x = [ux, uy, ω]``): ``[[0, −ω, uy], [ω, 0, −ux], [0, 0, 0]]``."""
    b = rotation_block(kind, iv)
    if b < 0:
        return b
    if kind == kinds.PLANAR:
        ux, uy, w = x[b], x[b + 1], x[b + 2]
        Y[0, 0], Y[0, 1], Y[0, 2] = 0.0, -w, uy
        Y[1, 0], Y[1, 1], Y[1, 2] = w, 0.0, -ux
        Y[2, 0], Y[2, 1], Y[2, 2] = 0.0, 0.0, 0.0
        return b
    Y[0, 0], Y[0, 1], Y[0, 2] = 0.0, -x[b + 2], x[b + 1]
    Y[1, 0], Y[1, 1], Y[1, 2] = x[b + 2], 0.0, -x[b]
    Y[2, 0], Y[2, 1], Y[2, 2] = -x[b + 1], x[b], 0.0
    return b


@njit(cache=True, error_model="numpy")
def exponential_terms(joints, reals, frames, x, x1, x2, x3, out, ws):
    """``Ad_exp(x)`` into ``out[:nv] (nv, nv)`` and the left Jacobian ``J_l(x)`` into ``out[nv:]``, block
    diagonal over the joints, for ``x (nv,)`` in the velocity coordinates of the variational integrator's
    group (Solà et al. 2018, eqs. 41–46; Hairer, Lubich and Wanner, *Geometric Numerical Integration*,
    §III.4): SO(3) for a spherical joint, SE(2) for a planar one, and SO(3) × R³ for a free flyer (its
    translation commutes; ``multibody.variational``), so that

        Ad_exp(x) = exp(ad_x) = Σ_{j≥0} ad_x^j / j!,        J_l(x) = Σ_{j≥0} ad_x^j / (j + 1)!,

    ``exp(x + δ) = exp(J_l(x) δ) exp(x)``, summed until the bound ``r^j / j!`` of the terms (``r`` the
    largest absolute row sum of ``ad_x``) falls below ``1e-17``; the identity on the commutative joints
    and translations. ``ws`` holds three 3×3 scratch matrices.
    """
    nv = x.shape[0]
    for r in range(2 * nv):
        for c in range(nv):
            out[r, c] = 0.0
    for r in range(nv):
        out[r, r] = 1.0
        out[nv + r, r] = 1.0
    Y, term, product = ws[:9].reshape((3, 3)), ws[9:18].reshape((3, 3)), ws[18:27].reshape((3, 3))
    for i in range(joints.shape[0]):
        iv = _adjoint_block(joints[i, KIND], x, joints[i, IV], Y)
        if iv < 0:
            continue
        bound = 0.0
        for r in range(3):
            bound = larger(bound, abs(Y[r, 0]) + abs(Y[r, 1]) + abs(Y[r, 2]))
        for r in range(3):
            for c in range(3):
                term[r, c] = 1.0 if r == c else 0.0
        j, factorial, size = 0, 1.0, 1.0
        # Y^j / j! ≤ bound^j / j!
        while size > 1e-17 and j < 80:
            j += 1
            size *= bound / j
            factorial *= j
            for r in range(3):
                for c in range(3):
                    product[r, c] = term[r, 0] * Y[0, c] + term[r, 1] * Y[1, c] + term[r, 2] * Y[2, c]
            for r in range(3):
                for c in range(3):
                    term[r, c] = product[r, c]
                    out[iv + r, iv + c] += term[r, c] / factorial
                    out[nv + iv + r, iv + c] += term[r, c] / (factorial * (j + 1))
    nan_unless_finite(x, x1, x2, x3, out)


@njit(cache=True, error_model="numpy")
def coadjoint(joints, reals, frames, x, p, x2, x3, out, ws):
    """``ad_xᵀ p (nv,)`` into ``out[0]`` for the joints' own velocities (a free flyer's ``[v, ω]`` in its
    body frame, on SE(3): ``ad_(v,ω) = [[ω×, v×], [0, ω×]]``), zero on the commutative joints: for
    SE(3) ``[f × ω, f × v + n × ω]`` with ``p = [f, n]``, for SO(3) ``p × ω``, for SE(2)
    ``[ω p_y, −ω p_x, uy p_x − ux p_y]``."""
    for r in range(x.shape[0]):
        out[0, r] = 0.0
    for i in range(joints.shape[0]):
        kind, iv = joints[i, KIND], joints[i, IV]
        if kind == kinds.PLANAR:
            w = x[iv + 2]
            out[0, iv], out[0, iv + 1] = w * p[iv + 1], -w * p[iv]
            out[0, iv + 2] = x[iv + 1] * p[iv] - x[iv] * p[iv + 1]
        elif kind == kinds.SPHERICAL or kind == kinds.FREE_FLYER:
            w = iv + 3 if kind == kinds.FREE_FLYER else iv
            wx, wy, wz = x[w], x[w + 1], x[w + 2]
            for b in range(iv, iv + 6 if kind == kinds.FREE_FLYER else iv + 3, 3):  # p_b × ω
                out[0, b] = p[b + 1] * wz - p[b + 2] * wy
                out[0, b + 1] = p[b + 2] * wx - p[b] * wz
                out[0, b + 2] = p[b] * wy - p[b + 1] * wx
            if kind == kinds.FREE_FLYER:  # + f × v on the angular part
                out[0, iv + 3] += p[iv + 1] * x[iv + 2] - p[iv + 2] * x[iv + 1]
                out[0, iv + 4] += p[iv + 2] * x[iv] - p[iv] * x[iv + 2]
                out[0, iv + 5] += p[iv] * x[iv + 1] - p[iv + 1] * x[iv]
    nan_unless_finite(x, p, x2, x3, out)
