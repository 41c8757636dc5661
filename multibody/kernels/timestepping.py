"""Velocity-level time stepping with contact and joint limits: Moreau–Jean's scheme, every step compiled.

One step of ``dt`` from ``(q_k, v_k)`` (J. J. Moreau, *Unilateral contact and dry friction in finite freedom
dynamics*, CISM 302, 1988; M. Jean, *The non-smooth contact dynamics method*, Comput. Methods Appl. Mech. Engrg.
177, 1999; with θ = 1 and the positions updated with the new velocities, as in V. Acary and B. Brogliato,
*Numerical Methods for Nonsmooth Dynamical Systems*, Springer 2008, §10.1, and M. Anitescu and F. A. Potra,
Nonlinear Dynamics 14, 1997):

    M (v_{k+1} − v_k) = dt (τ − h)(q_k, v_k) + Jᵀ P                                  (Acary & Brogliato eq. 10.4)
    q_{k+1} = q_k ⊕ dt v_{k+1}

with ``M``, ``h`` and the rows ``J`` at ``q_k``. Eliminating ``v_{k+1}`` with the free velocity
``v* = v_k + dt M⁻¹ (τ − h)`` gives the one contact problem of the step, in the impulses ``P``:

    u = G P + c,   G = J M⁻¹ Jᵀ,   c = J v* + (offsets below),   v_{k+1} = v* + M⁻¹ Jᵀ P

solved by :func:`multibody.kernels.complementarity.solve` with one block per row kind: a bilateral row
``u = 0`` (the constraint program's rows, :mod:`multibody.kernels.constraints`, at velocity level with the
offset ``φ/dt``, so that the step closes ``φ`` to first order), a joint limit's unilateral row
``0 ≤ P ⊥ u ≥ 0``, and a contact's three rows (normal, two tangents) in De Saxcé's cone complementarity
``P ∈ K_μ``, ``u + μ‖u_T‖ e_N ∈ K_μ*``, ``P · (u + μ‖u_T‖ e_N) = 0`` (Acary & Brogliato §13.3). The solver
starts from the previous step's impulses (:func:`warm_start`); where the modes of those (each contact sticking or
separated) solve this step's problem to the tolerance, their one linear solve replaces its iterations
(:func:`held_modes`), as for a robot standing still.

The offset of a normal (or limit) row with gap ``g`` (m or rad; < 0 when penetrating) asks
``u⁺ₙ ≥ ℓ`` with

    ℓ = −(g − p)/dt,  p = min(0, min gⱼ)         the step ends with g + dt u⁺ₙ ≥ min(g, p) (to first order, p the
                                                 deepest gap of the same pair of bodies), and a penetrating
                                                 contact is not pushed out (no energy added); affine in the gaps,
                                                 so that the dependent rows of a face on a face stay consistent;
    ℓ = max(ℓ, −e u⁻ₙ)                           Newton's restitution, for a contact that closes within the step
                                                 (g + dt u*ₙ < 0) while approaching faster than one step's free
                                                 change of its normal velocity, |u*ₙ − u⁻ₙ|

(``u⁻ₙ`` the normal velocity at the step's start, ``u*ₙ`` the free one): so the row is ``u = u⁺ₙ − ℓ ≥ 0``,
``c = Jₙ v* − ℓ``. Restitution applies to approaches faster than ``max(1, 2e/(1 − e²)) δ`` with ``δ = |u*ₙ − u⁻ₙ|``
the step's free change of the normal velocity (``δ`` for ``e = 1``); slower ones are inelastic. The bound keeps
the energy from rising at an impact: a body that bounces at ``u⁺ₙ = e|u⁻ₙ|`` under a force giving ``δ`` per step
changes its energy (per unit mass along the normal) by ``½ u⁻ₙ² (e² − 1) + δ e |u⁻ₙ|`` in the step (the position
moves with ``u⁺ₙ``), which is ≤ 0 exactly above that speed; and a ball whose bounces shrink comes to rest instead
of bouncing ever more often (no Zeno chatter). A contact that penetrates at the end
of the step (rotation and curvature, which the first-order gap leaves out) is separated by a position
correction that leaves the velocities alone (:func:`separate`), so penetration never becomes speed.

Contacts come from :mod:`multibody.kernels.collision` at ``q_k``: every geometry against the half-spaces of
``Ground`` and the pairs of ``ContactPair``, with a margin that covers what the step's motion can close (the
geometries' speeds times ``2 dt`` beyond a fixed margin); a contact's rows are those of the velocity of body a
relative to body b at the contact point, in the frame ``(n, t₁, t₂)``. Joint limits are rows ``± e_i`` of a
one-coordinate joint whose gap to ``lower`` or ``upper`` is within the margin.

A run (:func:`run`) takes the steps of one trajectory; :mod:`multibody.contact` runs many on all cores.
"""

from __future__ import annotations

import math

import numpy as np

from ..tree import FRAME_JOINT, FRAME_POSITION, IQ, IV, KIND, NV
from . import collision, complementarity, configuration, crba, energy, kinematics, kkt, rnea, stepping
from . import joints as kinds
from .constraints import constraint_rows
from .jit import njit
from .spatial import all_finite, cross, dot3, load3, scale3

# ----------------------------------------------------------------------------- layouts

#: The plan's header (one float each): sizes, the controller, the counts of ground items, contact pairs and
#: limited coordinates, the solver's settings, where the blocks that follow start, the penetration the position
#: correction leaves, the workspaces of the kinematics and of the dynamics passes (:func:`pass_workspaces`), and
#: where the settings of the bilateral rows' projection start (:func:`multibody.kernels.kkt.project`: tolerance,
#: iterations, position mask) and its workspace.
(PLAN_NQ, PLAN_NV, PLAN_CONTROL, PLAN_GROUNDS, PLAN_PAIRS, PLAN_LIMITS, PLAN_MARGIN, PLAN_TOLERANCE,
 PLAN_MAX_ITERATIONS, PLAN_BILATERAL, PLAN_DAMPED, PLAN_GROUND_START, PLAN_PAIR_START, PLAN_LIMIT_START,
 PLAN_DAMPING_START, PLAN_PENETRATION, PLAN_KINEMATICS_WORKSPACE, PLAN_PASSES_WORKSPACE, PLAN_SETTINGS_START,
 PLAN_PROJECTION_WORKSPACE) = range(20)
PLAN_HEADER = 20

#: A ground item: a geometry against the half-space ``n · x ≥ height``, with its friction and restitution.
GROUND_GEOMETRY, GROUND_NORMAL, GROUND_HEIGHT, GROUND_FRICTION, GROUND_RESTITUTION = 0, 1, 4, 5, 6
GROUND_COLUMNS = 7
#: A pair item: two geometries, friction and restitution.
PAIR_A, PAIR_B, PAIR_FRICTION, PAIR_RESTITUTION = 0, 1, 2, 3
PAIR_COLUMNS = 4
#: A limited coordinate: its index in ``q`` and in ``v``, its limits (``±inf`` where none), restitution, the joint.
LIMIT_IQ, LIMIT_IV, LIMIT_LOWER, LIMIT_UPPER, LIMIT_RESTITUTION, LIMIT_JOINT = range(6)
LIMIT_COLUMNS = 6

#: A geometry row: its frame row (:mod:`multibody.tree`: the joint that moves it and its pose in that joint's
#: frame), its size in the kernel convention of :mod:`multibody.kernels.collision`, shape code, the radius of a
#: ball about its origin that holds it (m), its vertices' start and count, and its body's index in the model.
GEOMETRY_FRAME, GEOMETRY_SIZE, GEOMETRY_SHAPE, GEOMETRY_RADIUS, GEOMETRY_VERTEX_START, GEOMETRY_VERTEX_COUNT, \
    GEOMETRY_BODY = 0, 13, 16, 17, 18, 19, 20
GEOMETRY_COLUMNS = 21

#: A recorded row: body, other (a body index; :data:`GROUND` or :data:`LIMIT`), point (3), normal (3), force (3).
RECORD_BODY, RECORD_OTHER, RECORD_POINT, RECORD_NORMAL, RECORD_FORCE = 0, 1, 2, 5, 8
RECORD_COLUMNS = 11
GROUND, LIMIT = -1.0, -2.0
#: A step's summary: rows recorded, the solver's residual (m/s), its iterations and status, the deepest
#: penetration its position correction removed (m or rad, ≤ 0; :func:`separate`), and the mechanical energy of the
#: state at its time (J), which the next step writes from its kinematics pass (:func:`step`).
SUMMARY_COUNT, SUMMARY_RESIDUAL, SUMMARY_ITERATIONS, SUMMARY_STATUS, SUMMARY_SEPARATION, SUMMARY_ENERGY = range(6)
SUMMARY_COLUMNS = 6

#: The entries of a run's ``io``: the next step (in and out), the step to stop before, the status (out), the
#: time of what it reports.
IO_STEP, IO_STOP, IO_STATUS, IO_TIME = 0, 1, 2, 3
IO_SIZE = 4
#: Status of a run: completed; ``M`` not positive definite; a bilateral row undefined; the solver did not reach
#: its tolerance (the step is taken, and the run stops after it); a non-finite state; non-finite joint forces; the
#: step's end not projected onto the bilateral rows (positions that do not converge); the step's rows (limits and
#: contacts) more than its record holds (the step is not taken, and its summary's count says how many it needs).
COMPLETED, NOT_POSITIVE_DEFINITE, UNDEFINED, NOT_SOLVED, NON_FINITE_STATE, NON_FINITE_TORQUE, NOT_PROJECTED, \
    RECORD_FULL = range(8)

#: A contact's data while the step is built: the bodies (model indices; a ground's ``other`` is GROUND), point
#: (3), normal, tangents (3 each), gap, restitution, friction, its first row in the step's problem, and the joints
#: that move the two bodies (``-1``: the world or the ground).
C_BODY, C_OTHER, C_POINT, C_NORMAL, C_T1, C_T2, C_GAP, C_RESTITUTION, C_FRICTION, C_ROW, C_JOINT, C_OTHER_JOINT = \
    0, 1, 2, 5, 8, 11, 14, 15, 16, 17, 18, 19
CONTACT_DATA = 20

#: The smallest pivot² of the Cholesky factor of ``G_AA``, relative to its row's diagonal entry of ``G``, with which
#: :func:`held_modes` solves: below it the row depends on the others to within rounding.
MODE_PIVOT = 1e-8

@njit(cache=True, error_model="numpy")
def max_contacts(grounds, pairs):
    """The most contact points a step can have: :data:`~multibody.kernels.collision.MAX_PAIR_CONTACTS` per ground
    item and per pair."""
    return (grounds + pairs) * collision.MAX_PAIR_CONTACTS


def pass_workspaces(nj, nv):
    """Floats of workspace of the kinematics pass (kept through the step) and of the dynamics passes (CRBA, RNEA,
    frame motions), the plan's :data:`PLAN_KINEMATICS_WORKSPACE` and :data:`PLAN_PASSES_WORKSPACE`."""
    return (kinematics.workspace_size(nj, nv),
            max(crba.workspace_size(nj, nv), rnea.workspace_size(nj, nv), kinematics.workspace_size(nj, nv)))


@njit(cache=True, error_model="numpy")
def row_capacity(bilateral, limits, contacts, record):
    """The contact points and rows a step has room for when its record holds ``record`` rows (limits and contacts;
    :data:`RECORD_FULL` stops a step with more), of at most ``contacts`` contact points (:func:`max_contacts`) and
    ``limits`` limited coordinates: ``(c, m)``. A step has ``m = m_b + r + 3 f`` rows for ``f`` contacts and ``r``
    limit rows with ``r + f ≤ record``, ``f ≤ c = min(contacts, record)`` and ``r ≤ 2 limits``; each contact more
    adds two rows, so the most is

        m = m_b + 3 c + min(2 limits, record − c)

    (every row the plan can have once ``record ≥ contacts + 2 limits``)."""
    # (comparisons rather than min, as lower_bound)
    c = contacts if contacts < record else record
    rest = record - c
    return c, bilateral + 3 * c + (2 * limits if 2 * limits < rest else rest)


def workspace_sizes(plan, nframes, record):
    """Floats and integers of workspace of a run's step on ``plan`` (with ``nframes`` frame rows of its bilateral
    program) whose record holds ``record`` rows (:func:`row_capacity`): its layout in :func:`step`, the solver's
    workspace (:func:`multibody.kernels.complementarity.workspace_size`), and the blocks' kinds and first rows."""
    nq, nv, bilateral = int(plan[PLAN_NQ]), int(plan[PLAN_NV]), int(plan[PLAN_BILATERAL])
    contacts, m = row_capacity(bilateral, int(plan[PLAN_LIMITS]),
                               max_contacts(int(plan[PLAN_GROUNDS]), int(plan[PLAN_PAIRS])), record)
    floats = (2 * nv * nv + 8 * nv + 2 * nq + int(plan[PLAN_KINEMATICS_WORKSPACE]) + int(plan[PLAN_PASSES_WORKSPACE])
              + kkt.projection_columns(nq, nv) + int(plan[PLAN_PROJECTION_WORKSPACE])
              + nframes * kinematics.motion_columns(nv) + bilateral * nv + 2 * bilateral
              + collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS + collision.PAIR_WORKSPACE + 9 + 9 + 3 * 3
              + 6 * nv + contacts * CONTACT_DATA + 3 * m * nv + m * m + 12 * m + complementarity.workspace_size(m))
    # one block per bilateral row, limit row and contact: m less two rows of each contact
    return floats, 2 * (m - 2 * contacts)


# ----------------------------------------------------------------------------- geometry

@njit(cache=True, error_model="numpy")
def tangents(n):
    """Two unit tangents ``(t₁, t₂)`` of the unit normal ``n`` with ``(n, t₁, t₂)`` right-handed: ``t₁`` along
    ``n × e`` for the axis ``e`` least aligned with ``n``."""
    if abs(n[0]) <= abs(n[1]) and abs(n[0]) <= abs(n[2]):
        e = (1.0, 0.0, 0.0)
    elif abs(n[1]) <= abs(n[2]):
        e = (0.0, 1.0, 0.0)
    else:
        e = (0.0, 0.0, 1.0)
    t = cross(n, e)
    t1 = scale3(1.0 / math.sqrt(dot3(t, t)), t)
    return t1, cross(n, t1)


@njit(cache=True, error_model="numpy")
def speed_bound(geometry, g, vel):
    """An upper bound on the speed of any point of geometry ``g`` (m/s): ``|v_O + ω × p| + |ω| r`` for its
    origin ``p`` in its joint's frame and the radius ``r`` of :data:`GEOMETRY_RADIUS`; the joints' velocities
    ``vel (nj, 6)`` (:func:`multibody.kernels.kinematics.joint_motions`, joint coordinates)."""
    j = int(geometry[g, GEOMETRY_FRAME + FRAME_JOINT])
    if j < 0:
        return 0.0
    p = load3(geometry[g], GEOMETRY_FRAME + FRAME_POSITION)
    v_j, w_j = load3(vel[j], 0), load3(vel[j], 3)
    w_p = cross(w_j, p)
    s = (v_j[0] + w_p[0], v_j[1] + w_p[1], v_j[2] + w_p[2])
    return math.sqrt(dot3(s, s)) + math.sqrt(dot3(w_j, w_j)) * geometry[g, GEOMETRY_RADIUS]


@njit(cache=True, error_model="numpy")
def geometry_origin(pose, geometry, g):
    """Geometry ``g``'s world position (m), from the joints' poses ``pose`` of
    :func:`multibody.kernels.kinematics.joint_motions`: the position :func:`world_pose` gives, without the rotation."""
    frames = geometry[:, GEOMETRY_FRAME : GEOMETRY_FRAME + 13]
    return kinematics.world_position(pose, kinematics.frame_position(pose, frames, g))


@njit(cache=True, error_model="numpy")
def world_pose(pose, geometry, g, R, p):
    """Geometry ``g``'s world rotation into ``R (3, 3)`` and position (m) into ``p (3,)``, from the joints' poses
    ``pose`` of :func:`multibody.kernels.kinematics.joint_motions`."""
    rotation, p_O = kinematics.frame_pose(pose, geometry[:, GEOMETRY_FRAME : GEOMETRY_FRAME + 13], g)
    x = kinematics.world_position(pose, p_O)
    for r in range(3):
        p[r] = x[r]
        for c in range(3):
            R[r, c] = rotation[3 * r + c]


@njit(cache=True, error_model="numpy")
def add_contacts(rows, count, contacts, found, body, other, joint, other_joint, mu, e, limit):
    """Append the ``count`` detected rows ``rows (k, 7)`` (``[point, normal, gap]``) to ``contacts`` after
    ``found`` of them, with their frame ``(n, t₁, t₂)`` and the joints that move their two bodies; returns the new
    number (those past ``limit`` counted, not stored)."""
    for r in range(count):
        if found >= limit:
            # (the caller sizes contacts by its record, and grows both when a step has more)
            found += 1
            continue
        data = contacts[found]
        n = (rows[r, 3], rows[r, 4], rows[r, 5])
        t1, t2 = tangents(n)
        data[C_BODY], data[C_OTHER], data[C_JOINT], data[C_OTHER_JOINT] = body, other, joint, other_joint
        for c in range(3):
            data[C_POINT + c] = rows[r, c]
            data[C_NORMAL + c] = n[c]
            data[C_T1 + c] = t1[c]
            data[C_T2 + c] = t2[c]
        data[C_GAP], data[C_RESTITUTION], data[C_FRICTION] = rows[r, 6], e, mu
        found += 1
    return found


@njit(cache=True, error_model="numpy")
def detect(plan, geometry, vertices, pose, vel, dt, contacts, out, cws, R_a, p_a, R_b, p_b, normal):
    """Every contact of the ground items and pairs of ``plan`` at the joints' poses ``pose`` into ``contacts
    (·, CONTACT_DATA)``; returns their number (those past its rows counted, not stored). Each item's margin is the
    plan's plus ``2 dt`` times the speeds its geometries can reach (:func:`speed_bound`), so that a contact the step
    can close is in it."""
    margin = plan[PLAN_MARGIN]
    limit = contacts.shape[0]
    found = 0
    start = int(plan[PLAN_GROUND_START])
    for k in range(int(plan[PLAN_GROUNDS])):
        item = plan[start + k * GROUND_COLUMNS : start + (k + 1) * GROUND_COLUMNS]
        g = int(item[GROUND_GEOMETRY])
        for c in range(3):
            normal[c] = item[GROUND_NORMAL + c]
        reach = margin + 2.0 * dt * speed_bound(geometry, g, vel)
        # broad phase: every point of the geometry is within its radius r of its origin p, so none has a gap
        # n · x − height below the reach when n · p − height − r ≥ reach (the ground's normal is a unit vector);
        # the origin alone, so that the geometries far from the ground cost no world rotation
        if dot3(normal, geometry_origin(pose, geometry, g)) - item[GROUND_HEIGHT] - geometry[g, GEOMETRY_RADIUS] \
                >= reach:
            continue
        world_pose(pose, geometry, g, R_a, p_a)
        first, count = int(geometry[g, GEOMETRY_VERTEX_START]), int(geometry[g, GEOMETRY_VERTEX_COUNT])
        count = collision.halfspace_contacts(int(geometry[g, GEOMETRY_SHAPE]),
                                             geometry[g, GEOMETRY_SIZE : GEOMETRY_SIZE + 3],
                                             vertices[first : first + count], R_a, p_a, normal, item[GROUND_HEIGHT],
                                             reach, out, cws)
        found = add_contacts(out, count, contacts, found, geometry[g, GEOMETRY_BODY], GROUND,
                             geometry[g, GEOMETRY_FRAME + FRAME_JOINT], -1.0, item[GROUND_FRICTION],
                             item[GROUND_RESTITUTION], limit)
    start = int(plan[PLAN_PAIR_START])
    for k in range(int(plan[PLAN_PAIRS])):
        item = plan[start + k * PAIR_COLUMNS : start + (k + 1) * PAIR_COLUMNS]
        a, b = int(item[PAIR_A]), int(item[PAIR_B])
        world_pose(pose, geometry, a, R_a, p_a)
        world_pose(pose, geometry, b, R_b, p_b)
        first_a, count_a = int(geometry[a, GEOMETRY_VERTEX_START]), int(geometry[a, GEOMETRY_VERTEX_COUNT])
        first_b, count_b = int(geometry[b, GEOMETRY_VERTEX_START]), int(geometry[b, GEOMETRY_VERTEX_COUNT])
        reach = margin + 2.0 * dt * (speed_bound(geometry, a, vel) + speed_bound(geometry, b, vel))
        count = collision.pair_contacts(int(geometry[a, GEOMETRY_SHAPE]), geometry[a, GEOMETRY_SIZE : GEOMETRY_SIZE + 3],
                                        vertices[first_a : first_a + count_a], R_a, p_a,
                                        int(geometry[b, GEOMETRY_SHAPE]), geometry[b, GEOMETRY_SIZE : GEOMETRY_SIZE + 3],
                                        vertices[first_b : first_b + count_b], R_b, p_b, reach, out, cws)
        found = add_contacts(out, count, contacts, found, geometry[a, GEOMETRY_BODY], geometry[b, GEOMETRY_BODY],
                             geometry[a, GEOMETRY_FRAME + FRAME_JOINT], geometry[b, GEOMETRY_FRAME + FRAME_JOINT],
                             item[PAIR_FRICTION], item[PAIR_RESTITUTION], limit)
    return found


@njit(cache=True, error_model="numpy")
def contact_rows(joints, reals, pose, data, J, row, J6):
    """The three rows ``[n; t₁; t₂]ᵀ (J_a − J_b)`` of one contact into ``J[row : row + 3]``: the velocity of body a
    relative to body b at the contact point, in the contact frame (m/s per unit of ``v``). ``J6 (6, nv)`` is
    scratch for a body's Jacobian (:func:`multibody.kernels.kinematics.jacobian_columns`, world axes)."""
    nv = J.shape[1]
    for r in range(3):
        for c in range(nv):
            J[row + r, c] = 0.0
    # the point from the reference point O, where the joints' positions are
    origin = kinematics.world_origin(pose)
    x = (data[C_POINT] + origin[0], data[C_POINT + 1] + origin[1], data[C_POINT + 2] + origin[2])
    for side in range(2):
        j = int(data[C_JOINT] if side == 0 else data[C_OTHER_JOINT])
        if j < 0:
            continue
        sign = 1.0 if side == 0 else -1.0
        kinematics.jacobian_columns(joints, reals, pose, j, x, J6)
        for r in range(3):
            axis = C_NORMAL if r == 0 else (C_T1 if r == 1 else C_T2)
            for c in range(nv):
                J[row + r, c] += sign * (data[axis] * J6[0, c] + data[axis + 1] * J6[1, c] + data[axis + 2] * J6[2, c])


@njit(cache=True, error_model="numpy")
def row_dot(J, row, x):
    """``J[row] · x``."""
    s = 0.0
    for c in range(J.shape[1]):
        s += J[row, c] * x[c]
    return s


@njit(cache=True, error_model="numpy")
def lower_bound(gap, dt, u_start, u_free, e):
    """``ℓ`` of a normal or limit row (module docstring): the least ``u⁺ₙ`` the step allows, from its gap ``g``,
    the normal velocity ``u⁻ₙ`` at the start, the free one ``u*ₙ`` and the restitution ``e`` (0 for a step of
    zero length, which solves nothing)."""
    if not dt > 0.0:
        return 0.0
    # ℓ = −max(g, 0)/dt, the gap less the pair's deepest penetration (step)   (comparisons rather than max and min,
    # which Numba's CUDA target does not compile for floats)
    bound = -gap / dt if gap > 0.0 else 0.0
    # Newton's restitution, u⁺ₙ ≥ −e u⁻ₙ, for a contact that closes within the step, approaching faster than
    # max(1, 2e/(1 − e²)) times the step's free change of its normal velocity, δ = |u*ₙ − u⁻ₙ| (δ itself for e = 1)
    change = abs(u_free - u_start)
    threshold = 2.0 * e * change / (1.0 - e * e) if e < 1.0 else change
    if threshold < change:
        threshold = change
    if e > 0.0 and gap + dt * u_free < 0.0 and u_start < -threshold and -e * u_start > bound:
        bound = -e * u_start
    return bound


# ----------------------------------------------------------------------------- one step

@njit(cache=True, error_model="numpy")
def aligned_blocks(joints, q, x, T, out, transpose):
    """``out = T(q) x`` (``transpose``: ``T(q)ᵀ x``) for ``x (nv,)``, with ``T`` the velocity alignment of
    :func:`multibody.kernels.configuration.velocity_alignment`, which is block-diagonal by joint: each joint's block
    into ``T (nv, nv)`` (entries outside the blocks not written) and applied to that joint's coordinates alone."""
    for i in range(joints.shape[0]):
        kind, n, iv = joints[i, KIND], joints[i, NV], joints[i, IV]
        kinds.velocity_alignment(kind, n, q, joints[i, IQ], iv, T)
        for r in range(iv, iv + n):
            # out_r = Σ_c T_rc x_c over the joint's block (Tᵀ: T_cr)
            s = 0.0
            for c in range(iv, iv + n):
                s += (T[c, r] if transpose else T[r, c]) * x[c]
            out[r] = s


@njit(cache=True, error_model="numpy")
def metric_rows(L, parent, J, W):
    """``W = L⁻ᵀ Jᵀ (nv, m)`` of the first ``m`` rows of ``J`` for ``M = Lᵀ L`` (:func:`multibody.kernels.crba.factor_ltl`,
    ``parent`` of :func:`~multibody.kernels.crba.coordinate_parents`), so that ``J M⁻¹ Jᵀ = Wᵀ W`` and
    ``M⁻¹ Jᵀ x = L⁻¹ W x``. A contact's row is zero outside the support of its bodies, and so is its column of ``W``
    (``Lᵀ`` has the tree's sparsity, RBDA §6.5)."""
    nv, m = W.shape[0], W.shape[1]
    for i in range(m):
        for c in range(nv):
            W[c, i] = J[i, c]
    # W = L⁻ᵀ Jᵀ
    crba.solve_lt(L, parent, W)


@njit(cache=True, error_model="numpy")
def delassus(W, G):
    """``G = Wᵀ W (m, m)`` of ``W (nv, m)`` (:func:`metric_rows`): the Delassus matrix ``J M⁻¹ Jᵀ``, exactly
    symmetric. Summed over the coordinates in turn, skipping the zero entries of ``W`` (a contact's column is zero
    outside its bodies' support)."""
    nv, m = W.shape[0], W.shape[1]
    for i in range(m):
        for k in range(i + 1):
            G[i, k] = 0.0
    for c in range(nv):
        for i in range(m):
            a = W[c, i]
            if a != 0.0:
                # G_ik += W_ci W_ck  (k ≤ i)
                for k in range(i + 1):
                    G[i, k] += a * W[c, k]
    for i in range(m):
        for k in range(i):
            G[k, i] = G[i, k]


@njit(cache=True, error_model="numpy")
def metric_motion(L, parent, W, x, out):
    """``out = M⁻¹ Jᵀ x = L⁻¹ W x (nv,)`` for the impulses ``x (m,)`` of the rows of ``W (nv, m)``
    (:func:`metric_rows`)."""
    nv, m = W.shape[0], W.shape[1]
    for c in range(nv):
        s = 0.0
        for i in range(m):
            s += W[c, i] * x[i]
        out[c] = s
    # L⁻¹ (W x)
    crba.solve_l(L, parent, out.reshape((nv, 1)))


@njit(cache=True, error_model="numpy")
def separate(joints, plan, L, parent, W, gaps, normal_rows, count, Wn, G, x, u, mu, kinds_, starts, sws, nq, nv, q, dq,
             moved):
    """The position correction of the rows (contact normals, joint limits) ``normal_rows[:count]`` of a step whose
    first-order gaps at its end, ``gaps[:count]`` (m or rad), go below ``−plan[PLAN_PENETRATION]``: the smallest move
    ``w`` in the metric of ``M`` with ``Jₙ w ≥ −g`` on all of them (the frictionless problem ``0 ≤ P ⊥ Gₙ P + g ≥ 0``
    with ``Gₙ = Jₙ M⁻¹ Jₙᵀ``, ``w = M⁻¹ Jₙᵀ P``; the rows still open keep ``g + Jₙ w ≥ 0``), then ``q ← q ⊕ w``. The
    velocities are left alone, so penetration is removed without adding energy: a post-stabilization of the
    positions (E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical Integration*, §IV.4's projection, here
    onto the unilateral set; Acary & Brogliato §10.3). ``L``, ``parent``, ``W``: the factor of ``M`` and the rows of
    :func:`metric_rows`; ``Wn (nv · count,)`` scratch for the columns of ``W`` of the rows corrected. Returns the
    deepest end gap corrected (m or rad, ≤ 0), 0 when nothing penetrates."""
    deepest = 0.0
    for i in range(count):
        if gaps[i] < deepest:
            deepest = gaps[i]
    if deepest >= -plan[PLAN_PENETRATION]:
        return 0.0
    # Gₙ = Wₙᵀ Wₙ ;  0 ≤ P ⊥ Gₙ P + g ≥ 0
    Wn = Wn[: nv * count].reshape((nv, count))
    for i in range(count):
        for c in range(nv):
            Wn[c, i] = W[c, int(normal_rows[i])]
    Gn = G[: count * count].reshape((count, count))
    delassus(Wn, Gn)
    for i in range(count):
        x[i] = 0.0
        kinds_[i] = complementarity.UNILATERAL
        starts[i] = i
        mu[i] = 0.0
    complementarity.solve(Gn, gaps[:count], kinds_[:count], starts[:count], mu[:count], plan[PLAN_TOLERANCE],
                          int(plan[PLAN_MAX_ITERATIONS]), x[:count], u[:count], sws)
    # w = M⁻¹ Jₙᵀ P ;  q ← q ⊕ w
    metric_motion(L, parent, Wn, x, dq)
    for i in range(joints.shape[0]):
        kinds.integrate(joints[i, KIND], joints[i, NV], q, dq, joints[i, IQ], joints[i, IV], moved)
    for col in range(nq):
        q[col] = moved[col]
    return deepest


@njit(cache=True, error_model="numpy")
def warm_start(plan, J, contacts, found, limit_rows, first_limit, limit_items, mb, previous, previous_summary, dt, x):
    """The impulses ``x`` of the step's rows guessed from the previous step's record (its forces times ``dt``), which
    the solver starts from (a resting contact's are its solution): a bilateral row's multiplier; a limit's force on
    the same joint and side; a contact's force at the nearest of the previous step's points of the same two bodies,
    within the plan's margin, in the contact's frame. Rows without a match start at zero."""
    start = int(plan[PLAN_LIMIT_START])
    for i in range(mb):
        x[i] = previous_summary[SUMMARY_COLUMNS + i] * dt
    count = int(previous_summary[SUMMARY_COUNT])
    for k in range(limit_rows):
        i = first_limit + k
        item = plan[start + int(limit_items[k]) * LIMIT_COLUMNS : start + (int(limit_items[k]) + 1) * LIMIT_COLUMNS]
        sign = J[i, int(item[LIMIT_IV])]
        for r in range(count):
            line = previous[r]
            if line[RECORD_OTHER] == LIMIT and line[RECORD_BODY] == item[LIMIT_JOINT] and sign * line[RECORD_FORCE] > 0.0:
                x[i] = sign * line[RECORD_FORCE] * dt
    margin = plan[PLAN_MARGIN]
    for k in range(found):
        data = contacts[k]
        i = int(data[C_ROW])
        nearest, best = -1, margin * margin
        for r in range(count):
            line = previous[r]
            if line[RECORD_BODY] != data[C_BODY] or line[RECORD_OTHER] != data[C_OTHER]:
                continue
            d = 0.0
            for c in range(3):
                d += (line[RECORD_POINT + c] - data[C_POINT + c]) ** 2
            if d <= best:
                nearest, best = r, d
        if nearest < 0:
            continue
        f = previous[nearest, RECORD_FORCE : RECORD_FORCE + 3]
        normal_impulse = dt * (f[0] * data[C_NORMAL] + f[1] * data[C_NORMAL + 1] + f[2] * data[C_NORMAL + 2])
        x[i] = normal_impulse if normal_impulse > 0.0 else 0.0
        if data[C_FRICTION] > 0.0:
            x[i + 1] = dt * (f[0] * data[C_T1] + f[1] * data[C_T1 + 1] + f[2] * data[C_T1 + 2])
            x[i + 2] = dt * (f[0] * data[C_T2] + f[1] * data[C_T2 + 1] + f[2] * data[C_T2 + 2])


@njit(cache=True, error_model="numpy")
def held_modes(G, c, kinds_, starts, mu, tolerance, x, ws):
    """The warm start ``x (m,)`` replaced by the impulses of its own modes, where those solve the step's problem
    ``u = G x + c`` to ``tolerance`` (m/s): a resting contact keeps its modes from step to step, and with the modes
    known the conditions of :mod:`multibody.kernels.complementarity` are linear (Acary & Brogliato §13.3: a contact
    that sticks has ``u = 0`` and ``x ∈ K_μ``, one that separates ``x = 0`` and ``u ∈ K_μ*``), so one solve
    replaces the solver's iterations. The rows held at ``u = 0`` (set ``A``): the bilateral rows, a limit's row and a
    contact's three rows whose warm impulses are positive, a contact's strictly inside its cone; the others have zero
    impulses, and

        G_AA x_A = −c_A

    by Cholesky. Returns the natural residual (m/s) of the new ``x`` (:func:`~multibody.kernels.complementarity.
    shift_and_residual`), or ``inf`` with ``x`` unchanged where a warm contact slides (on its cone's boundary), where
    ``G_AA`` is singular to :data:`MODE_PIVOT` (dependent rows, as a face's four corners, keep the solver's proximal
    rule), or where the solution leaves the cones or misses the tolerance (the modes changed). ``ws`` of
    ``m² + 5 m`` floats."""
    m = c.shape[0]
    F = ws[: m * m]
    held = ws[m * m : m * m + m]
    rhs = ws[m * m + m : m * m + 2 * m]
    z = ws[m * m + 2 * m : m * m + 3 * m]
    u = ws[m * m + 3 * m : m * m + 4 * m]
    s = ws[m * m + 4 * m : m * m + 5 * m]
    count = 0
    for b in range(kinds_.shape[0]):
        kind, i = kinds_[b], starts[b]
        if kind == complementarity.BILATERAL:
            keep = True
        elif kind == complementarity.UNILATERAL:
            keep = x[i] > 0.0
        else:
            tangential = math.hypot(x[i + 1], x[i + 2])
            keep = x[i] > 0.0 and tangential < mu[b] * x[i]
            if not keep and (x[i] != 0.0 or tangential != 0.0):
                return math.inf
        if keep:
            for r in range(complementarity.block_rows(kind)):
                held[count] = i + r
                count += 1
    if count == 0:
        return math.inf
    # G_AA x_A = −c_A
    A = F[: count * count].reshape((count, count))
    for a in range(count):
        for k in range(a + 1):
            A[a, k] = G[int(held[a]), int(held[k])]
        rhs[a] = -c[int(held[a])]
    if not kkt.cholesky(A, count):
        return math.inf
    for a in range(count):
        # the pivot² is the part of the row's G_ii independent of the rows before it
        if not A[a, a] * A[a, a] > MODE_PIVOT * G[int(held[a]), int(held[a])]:
            return math.inf
    kkt.cholesky_solve(A, count, rhs)
    for i in range(m):
        z[i] = 0.0
    for a in range(count):
        z[int(held[a])] = rhs[a]
    # in K: a limit's impulse ≥ 0, a contact's in its cone
    for b in range(kinds_.shape[0]):
        kind, i = kinds_[b], starts[b]
        if kind == complementarity.UNILATERAL and z[i] < 0.0:
            return math.inf
        if kind == complementarity.CONTACT and math.hypot(z[i + 1], z[i + 2]) > mu[b] * z[i]:
            return math.inf
    complementarity.velocities(G, c, z, u, m)
    residual = complementarity.shift_and_residual(kinds_, starts, mu, z, u, s)
    if not residual <= tolerance:
        return math.inf
    for i in range(m):
        x[i] = z[i]
    return residual


@njit(cache=True, error_model="numpy")
def step(controller, joints, reals, frames, program, geometry, vertices, plan, control, t, dt, q, v, q_next, v_next,
         record, summary, previous, previous_summary, ws, iws):
    """One step of ``dt`` (s) from ``q (nq,)``, ``v (nv,)`` at ``t`` into ``q_next``, ``v_next`` (module docstring),
    the contact rows into ``record (R, RECORD_COLUMNS)`` (a step with more limit and contact rows than ``R`` returns
    :data:`RECORD_FULL` before it is taken) and ``summary (SUMMARY_COLUMNS + m_b,)`` (its last ``m_b``
    entries the bilateral rows' multipliers, impulse / dt); the solver starts from the previous step's ``previous``
    record and ``previous_summary`` (:func:`warm_start`), into which it writes the mechanical energy of ``(q, v)``
    (:data:`SUMMARY_ENERGY`, J). A step of zero length moves ``q`` by the position
    correction alone (:func:`separate`), which projects an initial state out of penetration. Returns a status
    (:data:`COMPLETED` ...). ``controller``, ``control`` as :func:`multibody.kernels.stepping.advance` takes them
    (the plan's controller kind: none, constant, PD, or a compiled function)."""
    nq, nv = q.shape[0], v.shape[0]
    kind = int(plan[PLAN_CONTROL])
    mb = int(plan[PLAN_BILATERAL])
    n_limits = int(plan[PLAN_LIMITS])
    # the rows of the record bound the step's (workspace_sizes)
    capacity = record.shape[0]
    n_contacts, m_max = row_capacity(mb, n_limits, max_contacts(int(plan[PLAN_GROUNDS]), int(plan[PLAN_PAIRS])),
                                     capacity)
    tolerance, iterations = plan[PLAN_TOLERANCE], int(plan[PLAN_MAX_ITERATIONS])
    none = plan[:0]
    # workspace
    at = 0
    L = ws[at : at + nv * nv].reshape((nv, nv))
    at += nv * nv
    parent = ws[at : at + nv].view(np.int64)
    at += nv
    h = ws[at : at + nv].reshape((1, nv))
    at += nv
    tau = ws[at : at + nv]
    at += nv
    v_free = ws[at : at + nv]
    at += nv
    dq = ws[at : at + nv]
    at += nv
    scratch = ws[at : at + nq + nv]
    at += nq + nv
    moved = ws[at : at + nq]
    at += nq
    T = ws[at : at + nv * nv].reshape((nv, nv))
    at += nv * nv
    kappa = ws[at : at + nv].reshape((1, nv))
    at += nv
    w = ws[at : at + nv]
    at += nv
    projection_columns = kkt.projection_columns(nq, nv)
    projected = ws[at : at + projection_columns].reshape((1, projection_columns))
    at += projection_columns
    projection_ws = ws[at : at + int(plan[PLAN_PROJECTION_WORKSPACE])]
    at += int(plan[PLAN_PROJECTION_WORKSPACE])
    kinematic_size, passes_size = int(plan[PLAN_KINEMATICS_WORKSPACE]), int(plan[PLAN_PASSES_WORKSPACE])
    kin = ws[at : at + kinematic_size]
    at += kinematic_size
    passes = ws[at : at + passes_size]
    at += passes_size
    cols = kinematics.motion_columns(nv)
    motions = ws[at : at + frames.shape[0] * cols].reshape((frames.shape[0], cols))
    at += frames.shape[0] * cols
    A = ws[at : at + mb * nv].reshape((mb, nv))
    at += mb * nv
    gamma = ws[at : at + mb]
    at += mb
    phi = ws[at : at + mb]
    at += mb
    out = ws[at : at + collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS].reshape(
        (collision.MAX_PAIR_CONTACTS, collision.CONTACT_COLUMNS))
    at += collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS
    cws = ws[at : at + collision.PAIR_WORKSPACE]
    at += collision.PAIR_WORKSPACE
    R_a = ws[at : at + 9].reshape((3, 3))
    at += 9
    R_b = ws[at : at + 9].reshape((3, 3))
    at += 9
    p_a = ws[at : at + 3]
    p_b = ws[at + 3 : at + 6]
    normal = ws[at + 6 : at + 9]
    at += 9
    J6 = ws[at : at + 6 * nv].reshape((6, nv))
    at += 6 * nv
    contacts = ws[at : at + n_contacts * CONTACT_DATA].reshape((n_contacts, CONTACT_DATA))
    at += n_contacts * CONTACT_DATA
    J = ws[at : at + m_max * nv].reshape((m_max, nv))
    at += m_max * nv
    W_space = ws[at : at + m_max * nv]
    at += m_max * nv
    Wn_space = ws[at : at + m_max * nv]
    at += m_max * nv
    G_space = ws[at : at + m_max * m_max]
    at += m_max * m_max
    c = ws[at : at + m_max]
    x = ws[at + m_max : at + 2 * m_max]
    u = ws[at + 2 * m_max : at + 3 * m_max]
    mu = ws[at + 3 * m_max : at + 4 * m_max]
    bound = ws[at + 4 * m_max : at + 5 * m_max]
    rows = ws[at + 5 * m_max : at + 6 * m_max]
    gaps = ws[at + 6 * m_max : at + 7 * m_max]
    sep_gap = ws[at + 7 * m_max : at + 8 * m_max]
    sep_rows = ws[at + 8 * m_max : at + 9 * m_max]
    sep_x = ws[at + 9 * m_max : at + 10 * m_max]
    sep_u = ws[at + 10 * m_max : at + 11 * m_max]
    sep_mu = ws[at + 11 * m_max : at + 12 * m_max]
    at += 12 * m_max
    sws = ws[at:]
    blocks = iws.shape[0] // 2
    block_kinds = iws[:blocks]
    block_starts = iws[blocks:]
    for k in range(summary.shape[0]):
        summary[k] = 0.0

    # the joint forces τ (less the joint damping D v)
    if not stepping.stage_torque(controller, joints, kind, control, t, q, v, tau, scratch):
        return NON_FINITE_TORQUE
    if plan[PLAN_DAMPED] != 0.0:
        damping = plan[int(plan[PLAN_DAMPING_START]) : int(plan[PLAN_DAMPING_START]) + nv]
        for col in range(nv):
            tau[col] -= damping[col] * v[col]

    # M = Lᵀ L (the tree's sparse factor, RBDA §6.5) and h at (q_k, v_k); v* = v_k + dt (M⁻¹ (τ − h) + κ(v_k)): the
    # free velocity in the parent-aligned axes of the chart at q_k, w* = T w_k + dt T (a + κ), written in the joints'
    # axes at q_k
    local, body_velocities, _, body_forces = rnea.forces(joints, reals, q, v, none, none, passes)
    rnea.joint_torques(joints, reals, none, body_forces, h[0])
    # the joints' world poses and velocities from the same pass (the contacts' detection and rows read them), then M
    # from its joint poses (CRBA's composite inertias overwrite the pass's velocities)
    pose, vel = kinematics.placed_motions(joints, reals, q, local, body_velocities, kin)
    crba.placed_mass_matrix(joints, reals, L, passes)
    crba.coordinate_parents(joints, parent)
    if not crba.factor_ltl(L, parent):
        return NOT_POSITIVE_DEFINITE
    configuration.velocity_coupling(joints, reals, frames, v, none, none, none, kappa, none)
    for col in range(nv):
        v_free[col] = tau[col] - h[0, col]
    crba.solve_ltl(L, parent, v_free.reshape((nv, 1)))
    for col in range(nv):
        v_free[col] = v[col] + dt * (v_free[col] + kappa[0, col])

    # the rows: bilateral, joint limits, contacts; each block's kind, first row and friction
    m, nb = 0, 0
    if mb > 0:
        kinematics.frame_motions(joints, reals, frames, q, v, none, none, motions, passes)
        if constraint_rows(program, motions, q, v, A, gamma, phi) != 0:
            return UNDEFINED
        for i in range(mb):
            for col in range(nv):
                J[m, col] = A[i, col]
            # A v⁺ = −φ/dt: the step closes φ to first order
            bound[m] = -phi[i] / dt if dt > 0.0 else 0.0
            gaps[m] = math.inf
            block_kinds[nb], block_starts[nb], mu[nb] = complementarity.BILATERAL, m, 0.0
            m += 1
            nb += 1
    margin = plan[PLAN_MARGIN]
    start = int(plan[PLAN_LIMIT_START])
    first_limit = m
    limit_rows = 0
    for k in range(n_limits):
        item = plan[start + k * LIMIT_COLUMNS : start + (k + 1) * LIMIT_COLUMNS]
        iq, iv = int(item[LIMIT_IQ]), int(item[LIMIT_IV])
        reach = margin + 2.0 * dt * (abs(v[iv]) + abs(v_free[iv]))
        for side in range(2):
            # lower: q − lower ≥ 0 along +e_i ; upper: upper − q ≥ 0 along −e_i
            sign = 1.0 if side == 0 else -1.0
            gap = q[iq] - item[LIMIT_LOWER] if side == 0 else item[LIMIT_UPPER] - q[iq]
            if not gap < reach:
                continue
            limit_rows += 1
            if limit_rows > capacity:
                # counted for RECORD_FULL below, with no room in the workspace
                continue
            for col in range(nv):
                J[m, col] = 0.0
            J[m, iv] = sign
            bound[m] = lower_bound(gap, dt, sign * v[iv], sign * v_free[iv], item[LIMIT_RESTITUTION])
            gaps[m] = gap
            rows[m - first_limit] = k
            block_kinds[nb], block_starts[nb], mu[nb] = complementarity.UNILATERAL, m, 0.0
            m += 1
            nb += 1
    # the energy T + U of the step's start, in its own summary row (energy.mechanical_energy's terms)
    previous_summary[SUMMARY_ENERGY] = energy.motion_energy(joints, reals, pose, vel, v)
    found = detect(plan, geometry, vertices, pose, vel, dt, contacts, out, cws, R_a, p_a, R_b, p_b, normal)
    if limit_rows + found > capacity:
        # the caller sizes the record and the workspace by the rows steps have, and grows them when one has more
        summary[SUMMARY_COUNT] = limit_rows + found
        return RECORD_FULL
    for k in range(found):
        data = contacts[k]
        contact_rows(joints, reals, pose, data, J, m, J6)
        # ℓ from the gap less the pair's deepest penetration p = min(0, min gⱼ): affine in the contact points'
        # positions, as the gaps are, so the dependent normal rows of a face landing flat (its corners' gaps a little
        # either side of zero) keep a consistent problem, where ℓ = −max(g, 0)/dt would ask those rows for velocities
        # no impulse gives; no row pushes out, and the position correction after the step removes the penetration
        deepest = 0.0
        for j in range(found):
            if contacts[j, C_BODY] == data[C_BODY] and contacts[j, C_OTHER] == data[C_OTHER] and \
                    contacts[j, C_GAP] < deepest:
                deepest = contacts[j, C_GAP]
        bound[m] = lower_bound(data[C_GAP] - deepest, dt, row_dot(J, m, v), row_dot(J, m, v_free),
                               data[C_RESTITUTION])
        bound[m + 1] = 0.0
        bound[m + 2] = 0.0
        gaps[m], gaps[m + 1], gaps[m + 2] = data[C_GAP], math.inf, math.inf
        data[C_ROW] = m
        if data[C_FRICTION] > 0.0:
            block_kinds[nb], block_starts[nb], mu[nb] = complementarity.CONTACT, m, data[C_FRICTION]
            m += 3
        else:
            # a frictionless contact: its normal row alone, 0 ≤ Pₙ ⊥ u ≥ 0 (the next contact's rows overwrite the
            # tangents)
            block_kinds[nb], block_starts[nb], mu[nb] = complementarity.UNILATERAL, m, 0.0
            m += 1
        nb += 1

    # G = J M⁻¹ Jᵀ = Wᵀ W, c = J v* − ℓ ; the impulses P of u = G P + c ; v⁺ = v* + M⁻¹ Jᵀ P = v* + L⁻¹ W P
    for col in range(nv):
        v_next[col] = v_free[col]
    for i in range(m):
        x[i] = 0.0
    warm_start(plan, J, contacts, found, limit_rows, first_limit, rows, mb, previous, previous_summary, dt, x)
    W = W_space[: nv * m].reshape((nv, m))
    if m > 0:
        metric_rows(L, parent, J, W)
    if m > 0 and dt > 0.0:
        G = G_space[: m * m].reshape((m, m))
        delassus(W, G)
        for i in range(m):
            c[i] = row_dot(J, i, v_free) - bound[i]
        # the warm start's modes kept where they solve the problem; the solver's iterations otherwise
        residual = held_modes(G, c[:m], block_kinds[:nb], block_starts[:nb], mu[:nb], tolerance, x[:m], sws)
        status, used = complementarity.CONVERGED, 0
        if not residual <= tolerance:
            status, used, residual = complementarity.solve(G, c[:m], block_kinds[:nb], block_starts[:nb], mu[:nb],
                                                           tolerance, iterations, x[:m], u[:m], sws)
        if status != complementarity.CONVERGED:
            # once more from zero impulses: the previous step's forces can start the iteration where it stalls
            for i in range(m):
                x[i] = 0.0
            status, again, residual = complementarity.solve(G, c[:m], block_kinds[:nb], block_starts[:nb], mu[:nb],
                                                            tolerance, iterations, x[:m], u[:m], sws)
            used += again
        summary[SUMMARY_RESIDUAL] = residual
        summary[SUMMARY_ITERATIONS] = used
        summary[SUMMARY_STATUS] = status
        metric_motion(L, parent, W, x[:m], w)
        for col in range(nv):
            v_next[col] = v_free[col] + w[col]

    # the rows near closing at the step's end, and their gaps there to first order, g + dt u⁺ₙ
    count = 0
    for i in range(m):
        if gaps[i] < math.inf:
            end_gap = gaps[i] + dt * row_dot(J, i, v_next)
            if end_gap < margin:
                sep_gap[count], sep_rows[count] = end_gap, i
                count += 1

    # w⁺ = T(q_k) v⁺ ;  q⁺ = chart(q_k, dt w⁺) ;  v_{k+1} = T(q⁺)ᵀ w⁺: the semi-implicit Euler step in the chart
    # (multibody.integrators' "semi-implicit Euler"), which keeps a body's world velocity through the position
    # update (a rolling ball's centre moves parallel to the ground)
    aligned_blocks(joints, q, v_next, T, w, False)
    for r in range(nv):
        dq[r] = dt * w[r]
    configuration.chart(joints, reals, frames, q, dq, none, none, q_next.reshape((1, nq)), none)
    aligned_blocks(joints, q_next, w, T, v_next, True)

    # penetration at the step's end (to first order: g + dt u⁺ₙ) removed by moving the positions alone
    summary[SUMMARY_SEPARATION] = separate(joints, plan, L, parent, W, sep_gap, sep_rows, count, Wn_space, G_space,
                                           sep_x, sep_u, sep_mu, block_kinds, block_starts, sws, nq, nv, q_next, dq,
                                           moved)

    # the step's end projected onto the bilateral rows, φ = 0 and A v = 0 (the projection of the fixed-step runs,
    # multibody.kernels.kkt.project: the smallest moves in the metric of M, which take no energy from the rows' rates
    # but what they violate)
    if mb > 0:
        settings = plan[int(plan[PLAN_SETTINGS_START]) : int(plan[PLAN_SETTINGS_START]) + 2 + mb]
        kkt.project(joints, reals, frames, q_next, v_next, settings, program, projected, projection_ws)
        if projected[0, projected.shape[1] - 1] != kkt.SOLVED:
            return NOT_PROJECTED
        for col in range(nq + nv):
            if col < nq:
                q_next[col] = projected[0, col]
            else:
                v_next[col - nq] = projected[0, col]

    # the record: each contact's force on body a (world axes, N), each limit's generalized force, each bilateral
    # row's multiplier (its impulse / dt)
    inverse_dt = 1.0 / dt if dt > 0.0 else 0.0
    for i in range(mb):
        summary[SUMMARY_COLUMNS + i] = x[i] * inverse_dt
    n_record = 0
    for k in range(limit_rows):
        i = first_limit + k
        item = plan[start + int(rows[k]) * LIMIT_COLUMNS : start + (int(rows[k]) + 1) * LIMIT_COLUMNS]
        line = record[n_record]
        for col in range(RECORD_COLUMNS):
            line[col] = 0.0
        line[RECORD_BODY], line[RECORD_OTHER] = item[LIMIT_JOINT], LIMIT
        # the generalized force added to τ: ±P/dt (negative at an upper limit)
        line[RECORD_FORCE] = J[i, int(item[LIMIT_IV])] * x[i] * inverse_dt
        n_record += 1
    for k in range(found):
        data = contacts[k]
        i = int(data[C_ROW])
        tangential = data[C_FRICTION] > 0.0
        line = record[n_record]
        line[RECORD_BODY], line[RECORD_OTHER] = data[C_BODY], data[C_OTHER]
        for col in range(3):
            line[RECORD_POINT + col] = data[C_POINT + col]
            line[RECORD_NORMAL + col] = data[C_NORMAL + col]
            # f = (Pₙ n + P₁ t₁ + P₂ t₂)/dt on body a
            force = x[i] * data[C_NORMAL + col]
            if tangential:
                force += x[i + 1] * data[C_T1 + col] + x[i + 2] * data[C_T2 + col]
            line[RECORD_FORCE + col] = force * inverse_dt
        n_record += 1
    summary[SUMMARY_COUNT] = n_record
    if not (all_finite(q_next) and all_finite(v_next)):
        return NON_FINITE_STATE
    if m > 0 and summary[SUMMARY_STATUS] != complementarity.CONVERGED:
        return NOT_SOLVED
    return COMPLETED


@njit(cache=True, error_model="numpy")
def run(controller, joints, reals, frames, program, geometry, vertices, plan, control, times, states, record, summary,
        io, ws, iws):
    """Steps ``io[IO_STEP]`` up to ``io[IO_STOP]`` (exclusive) of one trajectory: ``states (n, nq + nv)`` holds
    ``[q, v]`` at ``times (n,)``, each step ``k`` from ``states[k − 1]`` into ``states[k]``, its contact rows into
    ``record[k]`` and its summary into ``summary[k]`` (:func:`step`). Returns with the status in ``io`` and
    ``io[IO_STEP]`` the first step not taken (a step whose contact problem the solver did not finish is not taken:
    its record and summary say how far it got). ``ws``, ``iws``: the floats and integers of :func:`workspace_sizes` for
    the record's rows; a step with more rows than those stops the run with :data:`RECORD_FULL` before it."""
    nq = int(plan[PLAN_NQ])
    k, stop = int(io[IO_STEP]), int(io[IO_STOP])
    while k < stop:
        before, after = states[k - 1], states[k]
        status = step(controller, joints, reals, frames, program, geometry, vertices, plan, control, times[k - 1],
                      times[k] - times[k - 1], before[:nq], before[nq:], after[:nq], after[nq:], record[k], summary[k],
                      record[k - 1], summary[k - 1], ws, iws)
        if status != COMPLETED:
            io[IO_STEP], io[IO_STATUS], io[IO_TIME] = k, status, times[k - 1]
            return
        k += 1
    io[IO_STEP], io[IO_STATUS] = k, COMPLETED


# ----------------------------------------------------------------------------- the initial state

def gap_workspace_size(nj, nv, contacts):
    """Floats of workspace of :func:`deepest_gap` on a tree of ``nj`` joints and ``nv`` velocities whose plan has
    at most ``contacts`` contact points (:func:`max_contacts`)."""
    return (nv + kinematics.workspace_size(nj, nv) + contacts * CONTACT_DATA
            + collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS + collision.PAIR_WORKSPACE + 9 + 9 + 3 * 3)


@njit(cache=True, error_model="numpy")
def deepest_gap(joints, reals, geometry, vertices, plan, q, ws):
    """The smallest gap (m, or rad to a joint limit) of configuration ``q (nq,)`` over the plan's contacts within its
    margin (:func:`detect` at rest) and its limited coordinates, or the margin when none is closer: the depth of the
    deepest penetration when negative. A step of zero length from ``q`` at rest moves ``q`` (:func:`separate`) exactly
    when this is below ``−plan[PLAN_PENETRATION]``. ``ws``: :func:`gap_workspace_size` floats."""
    nv = int(plan[PLAN_NV])
    n_contacts = max_contacts(int(plan[PLAN_GROUNDS]), int(plan[PLAN_PAIRS]))
    margin = plan[PLAN_MARGIN]
    at = 0
    v = ws[at : at + nv]
    at += nv
    kinematic_size = int(plan[PLAN_KINEMATICS_WORKSPACE])
    kin = ws[at : at + kinematic_size]
    at += kinematic_size
    contacts = ws[at : at + n_contacts * CONTACT_DATA].reshape((n_contacts, CONTACT_DATA))
    at += n_contacts * CONTACT_DATA
    out = ws[at : at + collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS].reshape(
        (collision.MAX_PAIR_CONTACTS, collision.CONTACT_COLUMNS))
    at += collision.MAX_PAIR_CONTACTS * collision.CONTACT_COLUMNS
    cws = ws[at : at + collision.PAIR_WORKSPACE]
    at += collision.PAIR_WORKSPACE
    R_a = ws[at : at + 9].reshape((3, 3))
    R_b = ws[at + 9 : at + 18].reshape((3, 3))
    p_a = ws[at + 18 : at + 21]
    p_b = ws[at + 21 : at + 24]
    normal = ws[at + 24 : at + 27]
    deepest = margin
    start = int(plan[PLAN_LIMIT_START])
    for k in range(int(plan[PLAN_LIMITS])):
        item = plan[start + k * LIMIT_COLUMNS : start + (k + 1) * LIMIT_COLUMNS]
        iq = int(item[LIMIT_IQ])
        # the gaps q − lower and upper − q (as the step's limit rows)
        if q[iq] - item[LIMIT_LOWER] < deepest:
            deepest = q[iq] - item[LIMIT_LOWER]
        if item[LIMIT_UPPER] - q[iq] < deepest:
            deepest = item[LIMIT_UPPER] - q[iq]
    for col in range(nv):
        v[col] = 0.0
    pose, vel, _ = kinematics.joint_motions(joints, reals, q, v, kin, None)
    found = detect(plan, geometry, vertices, pose, vel, 0.0, contacts, out, cws, R_a, p_a, R_b, p_b, normal)
    for k in range(found):
        if contacts[k, C_GAP] < deepest:
            deepest = contacts[k, C_GAP]
    return deepest


@njit(cache=True, error_model="numpy")
def deepest_gaps(joints, reals, geometry, vertices, plan, q, out, ws):
    """:func:`deepest_gap` of each configuration of ``q (N, nq)`` into ``out (N,)``."""
    for r in range(q.shape[0]):
        out[r] = deepest_gap(joints, reals, geometry, vertices, plan, q[r], ws)
