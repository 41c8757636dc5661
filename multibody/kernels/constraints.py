"""Rows of the built-in constraints, ``A a = γ`` and their position error ``φ``, from frame kinematics.

A constrained step (:mod:`multibody.kernels.kkt`) reads each constraint from a *program*: a float
vector with a header ``[count, m, α, β, rank tolerance]`` and then, per constraint, ``STRIDE`` numbers
``[kind, first row, rows, frame a, frame b, parameters...]``. The frames index the rows of
:func:`multibody.kernels.kinematics.frame_motions` (world pose ``R_WF, p_WF``, Jacobian ``J (6, nv)``
of F's origin in world axes, and ``J̇ v``), computed once per state for all constraints.
:meth:`multibody.constraints.Constraint.program_entry` writes the parameters; the formulas, and
their derivations, are those in the docstrings of the constraint classes
(:mod:`multibody.constraints`, :mod:`multibody.rolling`). Every row function writes rows
``first … first + rows − 1`` of ``A (m, nv)``, ``γ (m,)`` and ``φ (m,)`` (zero for rows without a
position level), and returns 0, or ``UNDEFINED`` where the geometry has no constraint direction (a
disc lying flat, a blade across the plane, two coincident points).
"""

from __future__ import annotations

import math

from . import kinematics
from .jit import njit
from .kinematics import MOTION_JACOBIAN, MOTION_POSITION, MOTION_ROTATION
from .spatial import add3, cross, dot3, load3, load9, nan_unless_finite, rotate, scale3, sub3

#: Program layout: header size, entry size, and where an entry's fields are.
HEADER, STRIDE = 5, 20
KIND, FIRST_ROW, ROWS, FRAME_A, FRAME_B, PARAMETERS = 0, 1, 2, 3, 4, 5

#: Constraint kinds.
ROLLING_SPHERE, ROLLING_DISC, KNIFE_EDGE, DISTANCE, LOOP_CLOSURE, JOINT_COUPLING = 1, 2, 3, 4, 5, 6

#: Status of a row function.
UNDEFINED = 3


@njit(cache=True, error_model="numpy")
def column(R, k):
    """Column ``k`` of the row-major rotation ``R``: axis k of the rotated frame."""
    return (R[k], R[3 + k], R[6 + k])


@njit(cache=True, error_model="numpy")
def jacobian_vector(motion, nv, first, v):
    """``J[first : first + 3] v`` of a frame's motion row: its linear (first = 0) or angular (3) velocity."""
    base = MOTION_JACOBIAN + first * nv
    x = 0.0
    y = 0.0
    z = 0.0
    for c in range(nv):
        x += motion[base + c] * v[c]
        y += motion[base + nv + c] * v[c]
        z += motion[base + 2 * nv + c] * v[c]
    return (x, y, z)


@njit(cache=True, error_model="numpy")
def add_row(A, row, motion, nv, first, u, scale):
    """``A[row] += scale · uᵀ J[first : first + 3]`` for a frame's motion row (3-vector ``u``)."""
    base = MOTION_JACOBIAN + first * nv
    for c in range(nv):
        A[row, c] += scale * (u[0] * motion[base + c] + u[1] * motion[base + nv + c] + u[2] * motion[base + 2 * nv + c])


@njit(cache=True, error_model="numpy")
def clear_rows(A, gamma, phi, first, rows):
    for r in range(first, first + rows):
        for c in range(A.shape[1]):
            A[r, c] = 0.0
        gamma[r] = 0.0
        phi[r] = 0.0


@njit(cache=True, error_model="numpy")
def rolling(entry, motions, v, A, gamma, phi, disc):
    """A sphere (``disc`` False) or a thin disc rolling without slipping on a plane
    (:class:`multibody.RollingSphere`, :class:`multibody.RollingDisc`).

    Parameters: ``E`` rows ``t₁, t₂, n`` (9), radius ``r``, plane offset ``c = p₀ · n``, and for a disc its
    axis in frame coordinates (3). Rows ``Eᵀ (J_O − [d]× J_ω) v = 0``, ``γ = −Eᵀ (J̇v_O + ω̇₀ × d + ω × ḋ)``,
    and for the normal row (the third, when present) ``φ = (x_O + d) · n − c``.
    """
    first, rows = int(entry[FIRST_ROW]), int(entry[ROWS])
    motion = motions[int(entry[FRAME_A])]
    nv = A.shape[1]
    P = PARAMETERS
    n = load3(entry, P + 6)
    radius, offset = entry[P + 9], entry[P + 10]
    R_WF = load9(motion, MOTION_ROTATION)
    x_O = load3(motion, MOTION_POSITION)
    omega = jacobian_vector(motion, nv, 3, v)
    if disc:
        a = rotate(R_WF, load3(entry, P + 11))
        a_dot = cross(omega, a)
        n_a = dot3(n, a)
        # e = (n − (n·a) a) / |n − (n·a) a|, the direction in the disc's plane closest to n
        u = sub3(n, scale3(n_a, a))
        length = math.sqrt(dot3(u, u))
        if length < 1e-9:
            return UNDEFINED
        e = scale3(1.0 / length, u)
        # u̇ = −(n·ȧ) a − (n·a) ȧ ;  ė = (u̇ − e (e·u̇)) / |u|
        u_dot = sub3(scale3(-dot3(a_dot, n), a), scale3(n_a, a_dot))
        e_dot = scale3(1.0 / length, sub3(u_dot, scale3(dot3(e, u_dot), e)))
        d, d_dot = scale3(-radius, e), scale3(-radius, e_dot)
    else:
        # d = −r n, fixed in the world
        d, d_dot = scale3(-radius, n), (0.0, 0.0, 0.0)
    bias = MOTION_JACOBIAN + 6 * nv
    # d/dt v_c at a = 0: J̇v_O + ω̇₀ × d + ω × ḋ
    contact_acceleration = add3(add3(load3(motion, bias), cross(load3(motion, bias + 3), d)), cross(omega, d_dot))
    clear_rows(A, gamma, phi, first, rows)
    for i in range(rows):
        e_i = load3(entry, P + 3 * i)
        # row i of Eᵀ J_O − (Eᵀ [d]×) J_ω, with e_iᵀ [d]× = (e_i × d)ᵀ
        add_row(A, first + i, motion, nv, 0, e_i, 1.0)
        add_row(A, first + i, motion, nv, 3, cross(e_i, d), -1.0)
        gamma[first + i] = -dot3(e_i, contact_acceleration)
    if rows == 3:
        phi[first + 2] = dot3(add3(x_O, d), n) - offset
    return 0


@njit(cache=True, error_model="numpy")
def knife_edge(entry, motions, v, A, gamma, phi):
    """A blade that cannot move sideways on a plane (:class:`multibody.KnifeEdge`).

    Parameters: plane normal ``n`` (3), blade direction in frame coordinates (3). With
    ``w = n × e / |n × e|``: the row ``wᵀ J_O``, ``γ = −(ẇ · ẋ + w · J̇v_O)``.
    """
    first = int(entry[FIRST_ROW])
    motion = motions[int(entry[FRAME_A])]
    nv = A.shape[1]
    n = load3(entry, PARAMETERS)
    e = rotate(load9(motion, MOTION_ROTATION), load3(entry, PARAMETERS + 3))
    raw = cross(n, e)
    length = math.sqrt(dot3(raw, raw))
    if length < 1e-9:
        return UNDEFINED
    w = scale3(1.0 / length, raw)
    omega = jacobian_vector(motion, nv, 3, v)
    x_dot = jacobian_vector(motion, nv, 0, v)
    # ẇ: the blade turns with the body
    raw_dot = cross(n, cross(omega, e))
    w_dot = scale3(1.0 / length, sub3(raw_dot, scale3(dot3(w, raw_dot), w)))
    clear_rows(A, gamma, phi, first, 1)
    add_row(A, first, motion, nv, 0, w, 1.0)
    gamma[first] = -(dot3(w_dot, x_dot) + dot3(w, load3(motion, MOTION_JACOBIAN + 6 * nv)))
    return 0


@njit(cache=True, error_model="numpy")
def distance(entry, motions, v, A, gamma, phi):
    """Two points a given distance apart (:class:`multibody.Distance`). Parameter: the distance.

    ``φ = d − |Δ|`` with ``Δ = x_a − x_b`` and ``u = Δ/|Δ|``; the row ``−uᵀ J_Δ``;
    ``γ = u · (J̇v_a − J̇v_b) + (|Δ̇|² − (u·Δ̇)²)/|Δ|``.
    """
    first = int(entry[FIRST_ROW])
    motion_a, motion_b = motions[int(entry[FRAME_A])], motions[int(entry[FRAME_B])]
    nv = A.shape[1]
    delta = sub3(load3(motion_a, MOTION_POSITION), load3(motion_b, MOTION_POSITION))
    length = math.sqrt(dot3(delta, delta))
    if length == 0.0:
        return UNDEFINED
    u = scale3(1.0 / length, delta)
    delta_dot = sub3(jacobian_vector(motion_a, nv, 0, v), jacobian_vector(motion_b, nv, 0, v))
    bias = MOTION_JACOBIAN + 6 * nv
    clear_rows(A, gamma, phi, first, 1)
    add_row(A, first, motion_a, nv, 0, u, -1.0)
    add_row(A, first, motion_b, nv, 0, u, 1.0)
    u_delta_dot = dot3(u, delta_dot)
    normal_part = (dot3(delta_dot, delta_dot) - u_delta_dot * u_delta_dot) / length
    gamma[first] = dot3(u, sub3(load3(motion_a, bias), load3(motion_b, bias))) + normal_part
    phi[first] = entry[PARAMETERS] - length
    return 0


@njit(cache=True, error_model="numpy")
def loop_closure(entry, motions, v, A, gamma, phi):
    """Frame B held to frame A (:class:`multibody.LoopClosure`).

    Parameters: the number of position axes and the axes (3), the number of perpendicular pairs and
    the pairs ``(i, j)`` (6). Position rows ``e_k^A · (ẋ_b − ẋ_a − ω_a × Δ)`` with ``φ = e_k^A · Δ``;
    orientation rows ``(e_i^A × f_j^B) · (ω_a − ω_b)`` with ``φ = e_i^A · f_j^B``.
    """
    first = int(entry[FIRST_ROW])
    motion_a, motion_b = motions[int(entry[FRAME_A])], motions[int(entry[FRAME_B])]
    nv = A.shape[1]
    bias = MOTION_JACOBIAN + 6 * nv
    R_a, R_b = load9(motion_a, MOTION_ROTATION), load9(motion_b, MOTION_ROTATION)
    delta = sub3(load3(motion_b, MOTION_POSITION), load3(motion_a, MOTION_POSITION))
    w_a, w_b = jacobian_vector(motion_a, nv, 3, v), jacobian_vector(motion_b, nv, 3, v)
    delta_dot = sub3(jacobian_vector(motion_b, nv, 0, v), jacobian_vector(motion_a, nv, 0, v))
    Jv_a_lin, Jv_a_ang = load3(motion_a, bias), load3(motion_a, bias + 3)
    Jv_b_lin, Jv_b_ang = load3(motion_b, bias), load3(motion_b, bias + 3)
    # r̈'s a-free part: J̇v_b − J̇v_a − ω̇_a × Δ − 2 ω_a × Δ̇ + ω_a × (ω_a × Δ)
    free = add3(sub3(sub3(sub3(Jv_b_lin, Jv_a_lin), cross(Jv_a_ang, delta)), scale3(2.0, cross(w_a, delta_dot))),
                cross(w_a, cross(w_a, delta)))
    positions, pairs = int(entry[PARAMETERS]), int(entry[PARAMETERS + 4])
    clear_rows(A, gamma, phi, first, positions + pairs)
    for r in range(positions):
        e = column(R_a, int(entry[PARAMETERS + 1 + r]))
        # e · (ẋ_b − ẋ_a + Δ × ω_a), with e · (Δ × ω_a) = (e × Δ) · ω_a
        add_row(A, first + r, motion_b, nv, 0, e, 1.0)
        add_row(A, first + r, motion_a, nv, 0, e, -1.0)
        add_row(A, first + r, motion_a, nv, 3, cross(e, delta), 1.0)
        gamma[first + r] = -dot3(e, free)
        phi[first + r] = dot3(e, delta)
    for r in range(pairs):
        row = first + positions + r
        e = column(R_a, int(entry[PARAMETERS + 5 + 2 * r]))
        f = column(R_b, int(entry[PARAMETERS + 6 + 2 * r]))
        axis = cross(e, f)
        # d/dt (e · f) = (e × f) · (ω_a − ω_b)
        add_row(A, row, motion_a, nv, 3, axis, 1.0)
        add_row(A, row, motion_b, nv, 3, axis, -1.0)
        axis_dot = add3(cross(cross(w_a, e), f), cross(e, cross(w_b, f)))
        gamma[row] = -(dot3(axis, sub3(Jv_a_ang, Jv_b_ang)) + dot3(axis_dot, sub3(w_a, w_b)))
        phi[row] = dot3(e, f)
    return 0


@njit(cache=True, error_model="numpy")
def joint_coupling(entry, q, v, A, gamma, phi):
    """One one-coordinate joint geared to another by a polynomial (:class:`multibody.JointCoupling`).
    Parameters: the joints' ``q`` and ``v`` indices ``(q_a, v_a, q_b, v_b)`` (``q_a < 0``: no joint a),
    the reference ``r`` of joint a and the coefficients ``c₀ … c₄``. With ``x = q_a − r`` and
    ``p(x) = Σ cₖ xᵏ``: ``φ = q_b − p(x)``; the row ``e_b − p′(x) e_a``; ``γ = p″(x) v_a²``, since
    ``d/dt (v_b − p′(x) v_a) = a_b − p′(x) a_a − p″(x) v_a²``. Without joint a, ``φ = q_b − c₀``."""
    first = int(entry[FIRST_ROW])
    qa, va, qb, vb = (int(entry[PARAMETERS]), int(entry[PARAMETERS + 1]), int(entry[PARAMETERS + 2]),
                      int(entry[PARAMETERS + 3]))
    c = entry[PARAMETERS + 5 : PARAMETERS + 10]
    clear_rows(A, gamma, phi, first, 1)
    A[first, vb] += 1.0
    if qa < 0:
        phi[first] = q[qb] - c[0]
        return 0
    x = q[qa] - entry[PARAMETERS + 4]
    # Horner's scheme for p, p′ and p″ together
    p = c[4]
    dp = 0.0
    ddp = 0.0
    for k in range(3, -1, -1):
        ddp = ddp * x + 2.0 * dp
        dp = dp * x + p
        p = p * x + c[k]
    A[first, va] -= dp
    gamma[first] = ddp * v[va] * v[va]
    phi[first] = q[qb] - p
    return 0


@njit(cache=True, error_model="numpy")
def failing_entry(program, motions, q, v, A, gamma, phi):
    """Every constraint of ``program`` into ``A (m, nv)``, ``γ (m,)``, ``φ (m,)``; returns −1, or the first row
    of the first constraint whose row function returned a non-zero status (``UNDEFINED``), which stops there."""
    for k in range(int(program[0])):
        entry = program[HEADER + k * STRIDE : HEADER + (k + 1) * STRIDE]
        kind = int(entry[KIND])
        if kind == ROLLING_SPHERE:
            status = rolling(entry, motions, v, A, gamma, phi, False)
        elif kind == ROLLING_DISC:
            status = rolling(entry, motions, v, A, gamma, phi, True)
        elif kind == KNIFE_EDGE:
            status = knife_edge(entry, motions, v, A, gamma, phi)
        elif kind == DISTANCE:
            status = distance(entry, motions, v, A, gamma, phi)
        elif kind == LOOP_CLOSURE:
            status = loop_closure(entry, motions, v, A, gamma, phi)
        else:
            status = joint_coupling(entry, q, v, A, gamma, phi)
        if status != 0:
            return int(entry[FIRST_ROW])
    return -1


@njit(cache=True, error_model="numpy")
def constraint_rows(program, motions, q, v, A, gamma, phi):
    """Every constraint of ``program`` into ``A (m, nv)``, ``γ (m,)``, ``φ (m,)``; returns 0, or ``UNDEFINED``
    where a row function found no constraint direction (:func:`failing_entry`)."""
    return 0 if failing_entry(program, motions, q, v, A, gamma, phi) < 0 else UNDEFINED


def levels_columns(nv, m):
    """Columns of :func:`constraint_levels`' output row: ``A (m nv, row-major) | γ (m) | φ (m) | status``."""
    return m * nv + 2 * m + 1


def workspace_size(nj, nv, nframes):
    """Floats of workspace of :func:`constraint_levels` with ``nframes`` frames."""
    return nv + nframes * kinematics.motion_columns(nv) + kinematics.workspace_size(nj, nv)


@njit(cache=True, error_model="numpy")
def constraint_levels(joints, reals, frames, q, v, x2, program, out, ws):
    """The rows of every constraint of ``program`` at ``(q, v)`` into ``out[0]`` (layout
    :func:`levels_columns`): ``A``, ``γ`` (no Baumgarte terms) and ``φ``, and the status of
    :func:`constraint_rows`. ``v`` of length 0 stands for zero; ``x2`` is unused."""
    m = int(program[1])
    nv = (out.shape[1] - 1 - 2 * m) // m
    cols = kinematics.motion_columns(nv)
    k = frames.shape[0]
    zeros = ws[:nv]
    motions = ws[nv : nv + k * cols].reshape((k, cols))
    row = out[0]
    for c in range(row.shape[0]):
        row[c] = 0.0
    for c in range(nv):
        zeros[c] = 0.0
    velocity = v if v.shape[0] > 0 else zeros
    kinematics.frame_motions(joints, reals, frames, q, velocity, x2, x2, motions, ws[nv + k * cols :])
    A = row[: m * nv].reshape((m, nv))
    status = constraint_rows(program, motions, q, velocity, A, row[m * nv : m * nv + m], row[m * nv + m : m * nv + 2 * m])
    if status != 0:
        for c in range(row.shape[0]):
            row[c] = 0.0
    row[row.shape[0] - 1] = status
    nan_unless_finite(q, v, x2, program, out)
