"""Centre of mass and centroidal dynamics, batched over leading axes.

Each function validates its inputs and hands them to a compiled kernel of
:mod:`multibody.kernels.centroidal` through the batch driver.

What is counted, as in Pinocchio: the bodies moved by joints, each with the links fixed to it; links
fixed to the world (Panda's ``panda_link0``, a ground body) are left out, so ``M`` is the moving mass,
``model.total_mass`` less the world-fixed links' masses. Vectors are in world axes; the centroidal
momentum and its matrix have rows ``[linear; angular]`` with the angular momentum taken about the
centre of mass (D. E. Orin, A. Goswami and S.-H. Lee, "Centroidal dynamics of a humanoid robot",
*Autonomous Robots* 35 (2013) 161–176). A model whose moving bodies have no mass has no centre of mass:
its results are NaN.
"""

from __future__ import annotations

from . import driver, spatial
from .kernels import centroidal as kernels


def _center_of_mass(model, inputs, order):
    """Rows ``c``, ``ċ``, ``c̈`` up to ``order`` (1 to 3) of the kernel: ``(..., order, 3)``."""
    batch = spatial.batch_shape(*(x.shape[:-1] for x in inputs))
    return driver.evaluate(kernels.center_of_mass, model.tree, inputs, (order, 3), batch)


def center_of_mass(model, q):
    """World position of the centre of mass of the moving bodies: ``(..., 3)``, m.

    ``c = Σᵢ mᵢ cᵢ / M`` over the bodies moved by joints (module docstring). ``q (..., nq)``.
    Pinocchio counterpart: ``centerOfMass(model, data, q)`` (``data.com[0]``).
    """
    return _center_of_mass(model, (model.check_configuration(q),), 1)[..., 0, :]


def center_of_mass_velocity(model, q, v):
    """Velocity ``ċ`` of the centre of mass of the moving bodies: ``(..., 3)``, m/s, world axes.

    ``q (..., nq)``, ``v (..., nv)``. Pinocchio counterpart: ``centerOfMass(model, data, q, v)``
    (``data.vcom[0]``).
    """
    return _center_of_mass(model, (model.check_configuration(q), model.check_velocity(v)), 2)[..., 1, :]


def center_of_mass_acceleration(model, q, v, a):
    """Acceleration ``c̈`` of the centre of mass of the moving bodies: ``(..., 3)``, m/s², world axes.

    ``c̈ = J_c a + J̇_c v`` for the joint accelerations ``a (..., nv)``; gravity plays no part (this is
    kinematics). Pinocchio counterpart: ``centerOfMass(model, data, q, v, a)`` (``data.acom[0]``).
    """
    inputs = (model.check_configuration(q), model.check_velocity(v), model.check_velocity(a, "a"))
    return _center_of_mass(model, inputs, 3)[..., 2, :]


def center_of_mass_jacobian(model, q, *, out=None):
    """Jacobian ``J_c (..., 3, nv)`` of the centre of mass of the moving bodies: ``ċ = J_c v``.

    ``J_c = A_G,linear / M``, the linear rows of :func:`centroidal_momentum_matrix` over the moving
    mass. ``out``: a C-contiguous float64 array of the result's shape that receives it and is returned.
    Pinocchio counterpart: ``jacobianCenterOfMass``.
    """
    q = model.check_configuration(q)
    return driver.evaluate(kernels.centroidal_map, model.tree, (q,), (3, model.nv), q.shape[:-1], out=out)


def centroidal_momentum_matrix(model, q, *, out=None):
    """Centroidal momentum matrix ``A_G (..., 6, nv)``: ``h_G = A_G v``.

    Rows ``[linear; angular]``: the moving bodies' linear momentum (kg m/s) and angular momentum about
    their centre of mass (kg m²/s), world axes, per unit of each velocity coordinate (Orin, Goswami and
    Lee 2013). ``out`` as :func:`center_of_mass_jacobian`. Pinocchio counterpart: ``computeCentroidalMap``
    (same row order).
    """
    q = model.check_configuration(q)
    return driver.evaluate(kernels.centroidal_map, model.tree, (q,), (6, model.nv), q.shape[:-1], out=out)


def centroidal_momentum(model, q, v, *, out=None):
    """Centroidal momentum ``h_G = [M ċ; k_G] (..., 6)``: linear momentum (kg m/s) and angular momentum
    about the centre of mass (kg m²/s) of the moving bodies, world axes; equal to ``A_G v``. ``out`` as
    :func:`center_of_mass_jacobian`.

    Pinocchio counterpart: ``computeCentroidalMomentum`` (``data.hg``, linear first).
    """
    q, v = model.check_configuration(q), model.check_velocity(v)
    return driver.evaluate(kernels.centroidal_momentum, model.tree, (q, v), (1, 6),
                           spatial.batch_shape(q.shape[:-1], v.shape[:-1]), out=out, shape=(6,))


def centroidal_momentum_matrix_derivative(model, q, v, *, out=None):
    """Time derivative ``Ȧ_G (..., 6, nv)`` of :func:`centroidal_momentum_matrix` along the motion ``v``:
    ``ḣ_G = A_G a + Ȧ_G v`` (world axes, angular rows about the moving centre of mass). ``out`` as
    :func:`center_of_mass_jacobian`.

    Pinocchio counterpart: ``computeCentroidalMapTimeVariation`` (``data.dAg``).
    """
    q, v = model.check_configuration(q), model.check_velocity(v)
    return driver.evaluate(kernels.centroidal_map_time_variation, model.tree, (q, v), (6, model.nv),
                           spatial.batch_shape(q.shape[:-1], v.shape[:-1]), out=out)
