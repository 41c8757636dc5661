"""multibody: rigid multibody dynamics in pure Python, from Lagrangian mechanics.

Public names are listed in ``docs/api.md``; conventions (vector ordering, frames, signs) in
``docs/conventions.md``.
"""

from importlib import import_module as _import_module

from . import inertia, joints, robots, spatial
from .driver import get_num_threads, set_num_threads
from .contact import ContactPair, Ground, JointLimits
from .constrained import ConstrainedSystem, ConstraintError, KKTDerivatives, KKTSolution, RankDeficientWarning
from .constraints import (
    Distance,
    Holonomic,
    JointCoupling,
    LoopClosure,
    Pfaffian,
    PointOnCurve,
    PointOnSurface,
    mimic_constraints,
)
from .derivatives import forward_dynamics_derivatives, gravity_derivatives, inverse_dynamics_derivatives
from .dynamics import (
    bias_forces,
    coriolis_matrix,
    forward_dynamics,
    generalized_gravity,
    inverse_dynamics,
    inverse_mass_matrix,
    joint_reaction_forces,
    kinetic_energy,
    mass_matrix,
    potential_energy,
)
from .inertia import Inertia
from .kinematics import (
    forward_kinematics,
    frame_placement,
    frame_velocity,
    jacobian,
    jacobian_time_variation,
    point_acceleration,
    point_velocity,
)
from .ik import InverseKinematicsResult, inverse_kinematics
from .model import Geometry, Mimic, Model, ModelBuilder
from .robotics import (
    center_of_mass,
    center_of_mass_acceleration,
    center_of_mass_jacobian,
    center_of_mass_velocity,
    centroidal_momentum,
    centroidal_momentum_matrix,
    centroidal_momentum_matrix_derivative,
)
from .rolling import KnifeEdge, RollingDisc, RollingSphere
from .shooting import StepDerivatives, rk4_step, rk4_step_derivatives
from .linearization import Linearization, linearize
from .integrators import PD
from .runs import JointLimitWarning, SimulationError
from .simulation import simulate
from .trajectory import Trajectory
from . import variational


def __getattr__(name):
    # The symbolic front-end (and SymPy with it) is imported on first use only.
    if name in ("LagrangianSystem", "generalized_forces", "symbolic"):
        symbolic = _import_module("multibody.symbolic")
        return symbolic if name == "symbolic" else getattr(symbolic, name)
    # Figures (and matplotlib with them) likewise; and batches on a Dask cluster (the [dask] extra).
    if name in ("plotting", "distributed"):
        return _import_module(f"multibody.{name}")
    # The 3-D viewer (and Viser with it) too; mb.view raises an ImportError naming the [viz] extra
    # when Viser is missing.
    if name in ("view", "viewer"):
        viewer = _import_module("multibody.viewer")
        return viewer if name == "viewer" else viewer.view
    raise AttributeError(f"module 'multibody' has no attribute {name!r}")
from .urdf import URDFError, load_urdf
from .mjcf import MJCFError, from_mujoco, load_mjcf, to_mujoco

__version__ = "0.1.0"

__all__ = [
    "ConstrainedSystem",
    "ConstraintError",
    "ContactPair",
    "Ground",
    "JointLimits",
    "Distance",
    "Holonomic",
    "JointCoupling",
    "KnifeEdge",
    "LagrangianSystem",
    "KKTDerivatives",
    "KKTSolution",
    "LoopClosure",
    "Pfaffian",
    "PointOnCurve",
    "PointOnSurface",
    "RankDeficientWarning",
    "RollingDisc",
    "RollingSphere",
    "JointLimitWarning",
    "SimulationError",
    "Trajectory",
    "mimic_constraints",
    "simulate",
    "PD",
    "StepDerivatives",
    "rk4_step",
    "rk4_step_derivatives",
    "Linearization",
    "linearize",
    "bias_forces",
    "coriolis_matrix",
    "forward_dynamics",
    "forward_dynamics_derivatives",
    "gravity_derivatives",
    "inverse_dynamics_derivatives",
    "generalized_gravity",
    "inverse_dynamics",
    "inverse_mass_matrix",
    "inverse_kinematics",
    "InverseKinematicsResult",
    "joint_reaction_forces",
    "kinetic_energy",
    "mass_matrix",
    "potential_energy",
    "Geometry",
    "Inertia",
    "Mimic",
    "Model",
    "ModelBuilder",
    "URDFError",
    "forward_kinematics",
    "frame_placement",
    "frame_velocity",
    "center_of_mass",
    "center_of_mass_acceleration",
    "center_of_mass_jacobian",
    "center_of_mass_velocity",
    "centroidal_momentum",
    "centroidal_momentum_matrix",
    "centroidal_momentum_matrix_derivative",
    "get_num_threads",
    "set_num_threads",
    "generalized_forces",
    "inertia",
    "jacobian",
    "jacobian_time_variation",
    "joints",
    "load_urdf",
    "load_mjcf",
    "to_mujoco",
    "from_mujoco",
    "MJCFError",
    "point_acceleration",
    "point_velocity",
    "robots",
    "spatial",
    "variational",
]
