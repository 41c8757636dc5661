"""Configuration-space maps of a tree: the exponential ``q ⊕ v`` and logarithm ``q₁ ⊖ q₀`` of the
joints' configuration manifolds, the configuration rate ``q̇(q, v)``, and the charts of the Lie-group
integrator (``docs/conventions.md``, "Charts for integration"), as run by :class:`multibody.Model`.

Every kernel has the uniform signature ``kernel(joints, reals, frames, x0, x1, x2, x3, out, ws)`` of
:mod:`multibody.driver` and loops over the joints; per joint it calls the map of the same name in
:mod:`multibody.kernels.joints`, which dispatches on the joint's kind code (formulas and sources
there) and writes that joint's block of ``out`` at the joint's offset (``IQ`` for ``q``-shaped
results, ``IV`` for ``v``-shaped ones). None of the kernels needs a workspace.
"""

from __future__ import annotations

from ..tree import IQ, IV, KIND, NV
from . import joints as kinds
from .jit import njit
from .spatial import nan_unless_finite


def workspace_size(nj, nv):
    """Floats of workspace one state needs: none."""
    return 0


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
