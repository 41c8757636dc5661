"""Rigid-body inertia: mass, centre of mass and rotational inertia, with primitive shapes.

An :class:`Inertia` is expressed in a body frame B: ``com`` is the centre of mass in B
(metres) and ``rotational`` the 3×3 inertia tensor about the centre of mass, in B's axes (kg m²).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import spatial


@dataclass(frozen=True, eq=False)
class Inertia:
    """Mass properties of a rigid body in a body frame B.

    Attributes:
        mass: kg, ``≥ 0``.
        com: centre of mass in B, ``(3,)`` m.
        rotational: inertia tensor about the centre of mass in B's axes, ``(3, 3)`` kg m².
    """

    mass: float
    com: np.ndarray
    rotational: np.ndarray

    def __post_init__(self):
        com = np.array(self.com, dtype=float)
        rotational = np.array(self.rotational, dtype=float)
        if com.shape != (3,):
            raise ValueError(f"Inertia.com must have shape (3,), got {com.shape}")
        if rotational.shape != (3, 3):
            raise ValueError(f"Inertia.rotational must have shape (3, 3), got {rotational.shape}")
        com.setflags(write=False)
        rotational.setflags(write=False)
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "com", com)
        object.__setattr__(self, "rotational", rotational)

    @classmethod
    def zero(cls) -> "Inertia":
        """A massless body."""
        return cls(0.0, np.zeros(3), np.zeros((3, 3)))

    @property
    def spatial(self) -> np.ndarray:
        """6×6 spatial inertia about B's origin, linear-first (see :func:`spatial.spatial_inertia`)."""
        return spatial.spatial_inertia(self.mass, self.com, self.rotational)

    def transformed(self, X_AB) -> "Inertia":
        """The same body expressed in frame A, given the 4×4 pose ``X_AB`` of B in A.

        ``c_A = R c_B + p``, ``I_A = R I_B Rᵀ`` (the tensor about the centre of mass only rotates).
        """
        X_AB = np.asarray(X_AB, dtype=float)
        R, p = X_AB[:3, :3], X_AB[:3, 3]
        return Inertia(self.mass, R @ self.com + p, R @ self.rotational @ R.T)

    def __add__(self, other: "Inertia") -> "Inertia":
        """Two bodies rigidly joined, both expressed in the same frame (parallel-axis theorem)."""
        mass = self.mass + other.mass
        if mass == 0.0:
            return Inertia(0.0, np.zeros(3), self.rotational + other.rotational)
        com = (self.mass * self.com + other.mass * other.com) / mass

        # I_about_new_com = I_c + m ([d]×ᵀ[d]×) with d the offset of each part's com from the new com.
        def shifted(part):
            d = spatial.skew(part.com - com)
            return part.rotational - part.mass * (d @ d)

        return Inertia(mass, com, shifted(self) + shifted(other))

    def problems(self) -> list[str]:
        """Physical-validity problems, as human-readable strings (empty when the inertia is valid).

        Checks: negative or non-finite mass; a tensor that is not symmetric, not positive
        semi-definite, or whose principal moments violate the triangle inequality
        ``I₁ + I₂ ≥ I₃`` (which every real mass distribution satisfies).
        """
        out = []
        if not np.isfinite(self.mass) or not np.all(np.isfinite(self.com)) or not np.all(np.isfinite(self.rotational)):
            return ["non-finite mass, centre of mass or inertia"]
        if self.mass < 0.0:
            out.append(f"negative mass {self.mass:g} kg")
        # Relative tolerance for rounding in the published digits, with a floor of 1e-12 kg m²
        # (a thousandth of a 1 g, 1 mm part's inertia) so that numerical noise around zero passes.
        tolerance = max(1e-9 * np.abs(self.rotational).max(), 1e-12)
        if not np.allclose(self.rotational, self.rotational.T, rtol=0.0, atol=tolerance):
            out.append("inertia tensor is not symmetric")
            return out
        moments = np.linalg.eigvalsh(self.rotational)
        if moments[0] < -tolerance:
            out.append(f"inertia tensor is not positive semi-definite (principal moments {np.round(moments, 12).tolist()})")
        elif moments[0] + moments[1] < moments[2] - tolerance:
            out.append(
                "principal moments violate the triangle inequality I1 + I2 >= I3 "
                f"({moments[0]:.6g} + {moments[1]:.6g} < {moments[2]:.6g})"
            )
        return out

    def __repr__(self) -> str:
        return f"Inertia(mass={self.mass:g}, com={self.com.tolist()}, rotational={self.rotational.tolist()})"


# ----------------------------------------------------------------------------- primitives

def point_mass(mass: float, position=(0.0, 0.0, 0.0)) -> Inertia:
    """A particle of ``mass`` kg at ``position`` (m, body frame): no rotational inertia about its centre."""
    return Inertia(mass, position, np.zeros((3, 3)))


def sphere(mass: float, radius: float, center=(0.0, 0.0, 0.0)) -> Inertia:
    """A solid homogeneous sphere: ``I = (2/5) m r²`` about every axis through its centre."""
    _require_positive(radius=radius)
    return Inertia(mass, center, 0.4 * mass * radius**2 * np.eye(3))


def hollow_sphere(mass: float, radius: float, center=(0.0, 0.0, 0.0)) -> Inertia:
    """A thin spherical shell: ``I = (2/3) m r²`` about every axis through its centre."""
    _require_positive(radius=radius)
    return Inertia(mass, center, (2.0 / 3.0) * mass * radius**2 * np.eye(3))


def box(mass: float, size, center=(0.0, 0.0, 0.0)) -> Inertia:
    """A solid homogeneous box with edge lengths ``size = (a, b, c)`` (m) along the body axes.

    ``I_xx = m (b² + c²) / 12`` and cyclically.
    """
    a, b, c = np.asarray(size, dtype=float)
    _require_positive(a=a, b=b, c=c)
    return Inertia(mass, center, mass / 12.0 * np.diag([b**2 + c**2, a**2 + c**2, a**2 + b**2]))


def cylinder(mass: float, radius: float, length: float, axis="z", center=(0.0, 0.0, 0.0)) -> Inertia:
    """A solid homogeneous cylinder along body axis ``"x"``, ``"y"`` or ``"z"``.

    ``I_axial = m r² / 2``, ``I_transverse = m (3 r² + L²) / 12``.
    """
    _require_positive(radius=radius, length=length)
    if axis not in ("x", "y", "z"):
        raise ValueError(f"cylinder axis must be 'x', 'y' or 'z', got {axis!r}")
    transverse = mass * (3.0 * radius**2 + length**2) / 12.0
    moments = np.full(3, transverse)
    moments["xyz".index(axis)] = 0.5 * mass * radius**2
    return Inertia(mass, center, np.diag(moments))


def from_mesh(mesh, density: float) -> Inertia:
    """Mass properties of a closed ``trimesh.Trimesh`` of uniform ``density`` (kg/m³), in the mesh frame.

    Uses trimesh's own volume integration (``trimesh.triangles.mass_properties``); its inertia
    tensor is about the centre of mass, in the mesh axes.
    """
    import trimesh

    _require_positive(density=density)
    if not mesh.is_watertight:
        raise ValueError("from_mesh needs a closed (watertight) mesh to define a volume")
    properties = trimesh.triangles.mass_properties(mesh.triangles, density=density)
    return Inertia(float(properties.mass), properties.center_mass, properties.inertia)


def _require_positive(**values):
    for name, value in values.items():
        if not np.isfinite(value) or value <= 0.0:
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
