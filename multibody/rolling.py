"""Nonholonomic contact constraints: rolling without slipping, and knife edges.

A body rolls on a plane when the material point of the body at the contact has the velocity of
the surface there. For a convex body whose contact point sits at ``c = x_O + d`` from a body point
``x_O`` (the sphere's or disc's centre), the contact velocity is

    v_c = ẋ_O + ω × d = (J_O − [d]× J_ω) v                  (rolling: v_c = v_surface(c, t))

and its rows, in the plane's frame ``E = [t₁ t₂ n]``, are the Pfaffian constraint
``Eᵀ (J_O − [d]× J_ω) v − Eᵀ v_surface = 0``. The multipliers are the contact force on the body in
that frame: two friction components and the normal force (N). The normal row is holonomic (the
body stays on the plane) and is projected at the position level as well.

Differentiating once more (``a = 0``) gives ``γ = −Eᵀ (J̇v_O + ω̇₀ × d + ω × ḋ − d/dt v_surface)``, with
``ω̇₀`` the angular part of ``J̇v``; ``d`` is constant in the world for a sphere (``−r n``) and turns with
the body for a disc.

References: J. I. Neimark and N. A. Fufaev, *Dynamics of Nonholonomic Systems*, AMS 1972, ch. III
(the rolling ball and disc); A. M. Bloch, *Nonholonomic Mechanics and Control*, §1.4 (knife edge).
"""

from __future__ import annotations

import numpy as np

from . import spatial
from .kernels import constraints as compiled
from .constraints import FIRST_STEP, CompiledRows, Constraint, OnBody, first_derivative, path_step
from .spatial import matvec


def _plane_frame(normal):
    """Unit normal ``n`` and an orthonormal frame ``E = [t₁ t₂ n]`` (columns) of a plane."""
    n = np.asarray(normal, dtype=float)
    if n.shape != (3,) or not np.linalg.norm(n) > 0:
        raise ValueError(f"plane normal must be a non-zero 3-vector, got {normal!r}")
    n = n / np.linalg.norm(n)
    helper = np.eye(3)[np.argmin(np.abs(n))]
    t1 = np.cross(helper, n)
    t1 /= np.linalg.norm(t1)
    return n, np.column_stack([t1, np.cross(n, t1), n])


class _RollingOnPlane(OnBody, CompiledRows):
    """Shared machinery of bodies rolling on a plane (see the module docstring)."""

    def __init__(self, body, radius, *, center, plane_point, plane_normal, surface_velocity, normal, name):
        super().__init__(body, center, name)
        if not radius > 0.0:
            raise ValueError(f"radius must be positive, got {radius!r}")
        self.radius = float(radius)
        self.normal, self.frame = _plane_frame(plane_normal)
        self.plane_point = np.asarray(plane_point, dtype=float)
        self.surface_velocity = surface_velocity
        self.include_normal = bool(normal)
        self._row_axes = slice(0, 3) if self.include_normal else slice(0, 2)
        self._plane_rows = self.frame[:, self._row_axes].T  # Eᵀ: the rows' directions (k, 3)

    def rows(self, system):
        return 3 if self.include_normal else 2

    def position_rows(self, system):
        return np.array([False, False, True][self._row_axes])

    def program_entry(self, model, frame_index):
        parameters = [*self.frame.T.reshape(9), self.radius, float(self.plane_point @ self.normal), *self._axis()]
        kind = compiled.ROLLING_SPHERE if isinstance(self, RollingSphere) else compiled.ROLLING_DISC
        return kind, parameters, frame_index(self.body, self.placement), 0

    def _axis(self):
        """The disc's axis in the contact frame's coordinates (none for a sphere)."""
        return []

    def _offset(self, R_WB, omega):
        """Contact offset ``d`` from the centre and its rate ``ḋ`` (world axes, ``(..., 3)`` each; ``ḋ``
        ``None`` where ``d`` is fixed in the world)."""
        raise NotImplementedError

    @property
    def batched(self):
        """Every method takes leading batch axes, unless a user ``surface_velocity`` is involved."""
        return self.surface_velocity is None

    @property
    def moving(self):
        return self.surface_velocity is not None

    def _contact(self, system, q, v, t):
        (R_WB, x_O, J, J_dot_v), = self._frame_terms(system, q, v)
        omega = matvec(J[..., 3:, :], v)
        d, d_dot = self._offset(R_WB, omega)
        return x_O, J, J_dot_v, omega, d, d_dot

    def _surface_velocity(self, point, t):
        return np.asarray(self.surface_velocity(point, t), float)

    def _levels(self, system, q, v, t):
        """The compiled rows of a fixed plane, and for a moving surface ``b = −Eᵀ v_surface(c, t)`` and
        its rate along the motion in ``γ = −Eᵀ (J̇v_O + ω̇₀ × d + ω × ḋ − d/dt v_surface)``, numerically."""
        A, b, gamma, phi = super()._levels(system, q, v, t)
        if self.surface_velocity is None:
            return A, b, gamma, phi
        E_T = self._plane_rows
        v = np.zeros(system.nv) if v is None else v
        x_O, _, _, _, d, _ = self._contact(system, q, v, t)
        b = -E_T @ self._surface_velocity(x_O + d, t)

        def surface_at(s):
            x_s, _, _, _, d_s, _ = self._contact(system, system.integrate(q, v, s), v, t + s)
            return self._surface_velocity(x_s + d_s, t + s)

        return A, b, gamma + E_T @ first_derivative(surface_at, path_step(v, FIRST_STEP)), phi

    def contact_point(self, system, q):
        """World position of the contact point ``(3,)``."""
        x_O, _, _, _, d, _ = self._contact(system, q, np.zeros(system.nv), 0.0)
        return x_O + d

    def body_forces(self, system, q, lam, t=0.0):
        # Aᵀλ = (J_O − [d]× J_ω)ᵀ E λ: the contact force E λ applied at the contact point.
        return self._load(system, q, self.frame[:, self._row_axes] @ lam, self.contact_point(system, q))


class RollingSphere(_RollingOnPlane):
    """A sphere of radius ``r`` fixed to ``body`` rolls without slipping on a plane.

    Rows (plane frame ``[t₁, t₂, n]``): ``Eᵀ (ẋ_O − r ω × n) = Eᵀ v_surface`` with ``x_O`` the
    sphere's centre. Multipliers: friction along ``t₁``, ``t₂`` and the normal force (N).

    Args:
        body: body name or index carrying the sphere.
        radius: ``r`` (m).
        center: sphere centre in body coordinates (default the body origin).
        plane_point, plane_normal: the plane (world), default the ground ``z = 0``.
        surface_velocity: ``v(point, t) -> (3,)``, velocity of the surface material at a world point
            (a moving or turning plane: rheonomic rolling); ``None`` for a fixed plane.
        normal: include the normal row (default). Leave it out when the model already keeps the
            centre at a constant height (e.g. the lecture note's five-coordinate ball).
    """

    def __init__(self, body, radius, *, center=None, plane_point=(0.0, 0.0, 0.0), plane_normal=(0.0, 0.0, 1.0),
                 surface_velocity=None, normal=True, name=None):
        super().__init__(body, radius, center=center, plane_point=plane_point, plane_normal=plane_normal,
                         surface_velocity=surface_velocity, normal=normal, name=name or f"rolling sphere {body}")
        self._offset_in_world = -self.radius * self.normal

    def _offset(self, R_WB, omega):
        # d = −r n is fixed in the world: ḋ = 0.
        return self._offset_in_world, None


class RollingDisc(_RollingOnPlane):
    """A thin disc (a coin, a wheel) of radius ``r`` rolls without slipping on a plane.

    The disc's axis is ``axis`` (body frame) through ``center``. The contact point lies at
    ``d = −r ê`` with ``ê`` the unit vector of the disc's plane closest to the plane normal,
    ``ê = (n − (n·a) a)/|n − (n·a) a|`` (``a`` the axis in world axes), so ``ḋ`` follows the disc's
    rotation. Rows and multipliers as :class:`RollingSphere`; a disc lying flat (``a ∥ n``) has no
    defined contact point.
    """

    undefined = "the disc lies flat on the plane; its contact point is undefined"

    def __init__(self, body, radius, *, axis=(0.0, 1.0, 0.0), center=None, plane_point=(0.0, 0.0, 0.0),
                 plane_normal=(0.0, 0.0, 1.0), surface_velocity=None, normal=True, name=None):
        super().__init__(body, radius, center=center, plane_point=plane_point, plane_normal=plane_normal,
                         surface_velocity=surface_velocity, normal=normal, name=name or f"rolling disc {body}")
        axis = np.asarray(axis, dtype=float)
        if axis.shape != (3,) or not np.linalg.norm(axis) > 0:
            raise ValueError(f"disc axis must be a non-zero 3-vector, got {axis!r}")
        self.axis = axis / np.linalg.norm(axis)

    def _axis(self):
        return list(self.placement[:3, :3] @ self.axis)

    def _offset(self, R_WB, omega):
        n = self.normal
        a = matvec(R_WB, self.placement[:3, :3] @ self.axis)
        a_dot = spatial.cross(omega, a)
        n_a = (a @ n)[..., None]
        u = n - n_a * a
        length = np.linalg.norm(u, axis=-1, keepdims=True)
        if np.any(length < 1e-9):
            raise ValueError(f"{self.name}: the disc lies flat on the plane; its contact point is undefined")
        e = u / length
        # u̇ = −(n·ȧ) a − (n·a) ȧ ;  ė = (u̇ − e (e·u̇)) / |u|
        u_dot = -(a_dot @ n)[..., None] * a - n_a * a_dot
        e_dot = (u_dot - e * np.sum(e * u_dot, axis=-1, keepdims=True)) / length
        return -self.radius * e, -self.radius * e_dot


class KnifeEdge(OnBody, CompiledRows):
    """A blade (or a non-slipping wheel seen from above) cannot move sideways on a plane.

    The point ``point`` of ``body`` has no velocity along ``w = n × e``, with ``e`` the blade's
    direction (body frame ``direction``, in world axes) and ``n`` the plane normal: one row,
    ``wᵀ ẋ = 0``. The multiplier is the sideways force of the blade on the body (N) along ``w``.
    This is the Chaplygin sleigh and the unicycle constraint.
    """

    undefined = "the blade is perpendicular to the plane"

    def __init__(self, body, *, point=None, direction=(1.0, 0.0, 0.0), plane_normal=(0.0, 0.0, 1.0), name=None):
        super().__init__(body, point, name or f"knife edge {body}")
        direction = np.asarray(direction, dtype=float)
        if direction.shape != (3,) or not np.linalg.norm(direction) > 0:
            raise ValueError(f"blade direction must be a non-zero 3-vector, got {direction.tolist()}")
        self.direction = direction / np.linalg.norm(direction)
        self.normal, _ = _plane_frame(plane_normal)

    def rows(self, system):
        return 1

    def program_entry(self, model, frame_index):
        return compiled.KNIFE_EDGE, [*self.normal, *self.direction], frame_index(self.body, self.placement), 0

    def _sideways(self, R_WB):
        w = spatial.cross(self.normal, R_WB @ self.direction)
        length = np.linalg.norm(w)
        if length < 1e-9:
            raise ValueError(f"{self.name}: the blade is perpendicular to the plane")
        return w / length, length

    position = Constraint.position  # no position level

    def body_forces(self, system, q, lam, t=0.0):
        (R_WB, x, _, _), = self._frame_terms(system, q)
        return self._load(system, q, self._sideways(R_WB)[0] * lam[0], x)
