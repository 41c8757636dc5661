"""Figures of a simulated :class:`~multibody.trajectory.Trajectory`, every axis with its unit.

:func:`plot_trajectory` writes them as PNG files; :func:`trajectory_figures` returns them as
``matplotlib.figure.Figure`` objects, to show in a notebook or restyle. The figures are built
object-oriented, never through ``pyplot``, so importing or using this module leaves the user's
matplotlib backend as it was (a notebook keeps its inline backend, a script its window backend).

Given the system that was simulated, the coordinates are drawn per joint (``docs/conventions.md``):

=====================  ========================================  ==============================================
joint                  coordinates drawn                         velocities drawn
=====================  ========================================  ==============================================
revolute, continuous   angle (rad)                               rate (rad/s)
prismatic              displacement (m)                          rate (m/s)
translation            x, y, z (m)                               vx, vy, vz (m/s)
planar                 x, y (m), θ (rad) from (cos θ, sin θ)     vx, vy (m/s) in the joint frame, ω (rad/s)
spherical              roll, pitch, yaw (rad)                    ωx, ωy, ωz (rad/s) in the joint frame
free-flyer             x, y, z (m), roll, pitch, yaw (rad)       vx, vy, vz (m/s), ωx, ωy, ωz (rad/s), joint frame
=====================  ========================================  ==============================================

Roll, pitch and yaw are URDF's, ``R = Rz(yaw) Ry(pitch) Rx(roll)``, rather than the four quaternion
components, which are hard to read. Angles are unwrapped in time: a spinning body's angle grows
instead of jumping by 2π. Coordinates and velocities are drawn in separate panels, one row of
panels per unit (lengths, angles), each curve named after its joint.

A multiplier's unit is that of its row: a force (N) for rows on a point's position or velocity, a
moment (N·m) for rows on an angle. For a user constraint the library cannot know it: ``λ φ̇`` is a
power, so its unit is J per unit of ``φ`` (or W per unit of ``A v + b``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

#: The quantity each unit measures, for axis labels.
QUANTITIES = {"m": "position", "rad": "angle", "m/s": "velocity", "rad/s": "angular velocity",
              "N": "force", "N·m": "moment", "J": "energy"}
#: Position-level and velocity-level units of a constraint row, by the unit of its multiplier.
ROW_LEVEL_UNITS = {"N": ("m", "m/s"), "N·m": ("rad", "rad/s")}


@dataclass(frozen=True)
class Curve:
    """One drawn quantity: its ``name``, its ``unit`` (``""`` when unknown) and ``values (n,)``."""

    name: str
    unit: str
    values: np.ndarray


def new_figure(figsize=(7.0, 4.0)):
    """A ``matplotlib.figure.Figure`` (``figsize`` in inches) with constrained layout, made without
    ``pyplot``: no backend is chosen or changed, and nothing needs closing."""
    return Figure(figsize=figsize, layout="constrained")


def save_figure(figure, out_dir, name, dpi=110):
    """Write ``figure`` to ``<out_dir>/<name>.png`` (the folder created when missing) and return the path."""
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"{name}.png")
    figure.savefig(path, dpi=dpi)
    return path


# ----------------------------------------------------------------------------- what is drawn

def roll_pitch_yaw(quat):
    """URDF roll, pitch, yaw (rad) of unit quaternions ``[x, y, z, w] (n, 4)``: ``(n, 3)`` with
    ``R = Rz(yaw) Ry(pitch) Rx(roll)``, roll and yaw unwrapped along the first axis (time)."""
    from .spatial import quat_to_rotation

    R = quat_to_rotation(quat)
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return np.stack([np.unwrap(roll), pitch, np.unwrap(yaw)], axis=-1)


def _joint_curves(kind, name, q, v):
    """``(coordinate curves, velocity curves)`` of one joint of ``kind`` with coordinates ``q (n, nq)``
    and velocities ``v (n, nv)``, named ``"<joint> <component>"``."""
    def named(components, values, unit):
        return [Curve(f"{name} {c}", unit, values[:, k]) for k, c in enumerate(components)]

    if kind in ("revolute", "continuous"):
        return [Curve(name, "rad", q[:, 0])], [Curve(name, "rad/s", v[:, 0])]
    if kind == "prismatic":
        return [Curve(name, "m", q[:, 0])], [Curve(name, "m/s", v[:, 0])]
    if kind == "translation":
        return named("xyz", q, "m"), named(("vx", "vy", "vz"), v, "m/s")
    if kind == "planar":
        theta = np.unwrap(np.arctan2(q[:, 3], q[:, 2]))[:, None]
        return (named("xy", q, "m") + named("θ", theta, "rad"),
                named(("vx", "vy"), v, "m/s") + named("ω", v[:, 2:], "rad/s"))
    if kind == "spherical":
        return named(("roll", "pitch", "yaw"), roll_pitch_yaw(q), "rad"), named(("ωx", "ωy", "ωz"), v, "rad/s")
    if kind == "free-flyer":
        return (named("xyz", q, "m") + named(("roll", "pitch", "yaw"), roll_pitch_yaw(q[:, 3:7]), "rad"),
                named(("vx", "vy", "vz"), v, "m/s") + named(("ωx", "ωy", "ωz"), v[:, 3:], "rad/s"))
    # a kind this table does not know: its raw columns, units unknown
    return (named([f"q[{k}]" for k in range(q.shape[1])], q, ""),
            named([f"v[{k}]" for k in range(v.shape[1])], v, ""))


def _parts(system):
    """``(model or None, mechanical system or None, constraints)`` of a ``Model``, a
    ``ConstrainedSystem``, any mechanical system (``LagrangianSystem.numeric()``), or ``None``."""
    from .model import Model

    if system is None or isinstance(system, Model):
        return system, system, ()
    mechanical = getattr(system, "system", system)  # a ConstrainedSystem wraps its mechanical system
    model = mechanical if isinstance(mechanical, Model) else getattr(mechanical, "model", None)
    return model, mechanical, tuple(getattr(system, "constraints", ()))


def _states(trajectory):
    """``(q (n, nq), v (n, nv))`` of one trajectory; a clear error for anything else."""
    q, v = np.asarray(trajectory.q, dtype=float), np.asarray(trajectory.v, dtype=float)
    if q.ndim != 2 or v.ndim != 2:
        raise ValueError(f"plot one trajectory at a time: q and v must be (n, nq) and (n, nv), got shapes "
                         f"{q.shape} and {v.shape}")
    return q, v


def state_curves(trajectory, system=None, *, coordinate_labels=None, coordinate_units=None):
    """The curves of a trajectory's coordinates and velocities: ``(q curves, v curves)``.

    Args:
        trajectory: a :class:`~multibody.trajectory.Trajectory` with ``q (n, nq)``, ``v (n, nv)``.
        system: what was simulated: a ``Model``, a ``ConstrainedSystem``, or a mechanical system such as
            ``LagrangianSystem.numeric()`` (its ``coordinate_names``). A model's joints give names,
            units and the drawn form of rotations (table in the module docstring). ``None``: the raw
            columns, units unknown, named after the trajectory's joints (``trajectory.joint_names``)
            when each has one coordinate, else ``q[k]``, ``v[k]``.
        coordinate_labels: names that replace the derived ones: one per velocity coordinate (``nv``),
            naming both the coordinate curve and the velocity curve of each degree of freedom; without
            a ``system``, one per column of ``q`` (``nq``), naming the coordinate curves only.
        coordinate_units: one unit per velocity coordinate (``nv``), e.g. ``["m", "rad"]`` for a
            Lagrangian system whose coordinates the library cannot know; rates get ``"/s"``.
    """
    q, v = _states(trajectory)
    model, mechanical, _ = _parts(system)
    nq, nv = q.shape[1], v.shape[1]
    if system is not None and (mechanical.nq, mechanical.nv) != (nq, nv):
        raise ValueError(f"the trajectory has nq = {nq}, nv = {nv} but the system has nq = {mechanical.nq}, "
                         f"nv = {mechanical.nv}: pass the system that was simulated")
    if model is not None:
        q_curves, v_curves = [], []
        for joint, name, iq, iv in zip(model.joints, model.joint_names, model.idx_q, model.idx_v):
            curves = _joint_curves(joint.kind, name, q[:, iq : iq + joint.nq], v[:, iv : iv + joint.nv])
            q_curves += curves[0]
            v_curves += curves[1]
    else:
        names = getattr(mechanical, "coordinate_names", None)
        if system is None:
            # the joints the trajectory records name its columns when each joint has one coordinate
            joints = list(getattr(trajectory, "joint_names", None) or ())
            names = joints if len(joints) == nq == nv else None
        q_curves = [Curve(names[k] if names else f"q[{k}]", "", q[:, k]) for k in range(nq)]
        v_curves = [Curve(names[k] if names else f"v[{k}]", "", v[:, k]) for k in range(nv)]

    def renamed(curves, names):
        return [Curve(name, c.unit, c.values) for name, c in zip(names, curves)]

    if coordinate_labels is not None:
        # without a system the labels name the columns of q; with one, each degree of freedom
        size, what = (nq, "column of q") if system is None else (nv, "degree of freedom")
        if len(coordinate_labels) != size or len(q_curves) != size:
            raise ValueError(f"coordinate_labels must give one name per {what} ({size}), got {len(coordinate_labels)}")
        q_curves = renamed(q_curves, coordinate_labels)
        if system is not None or nq == nv:
            v_curves = renamed(v_curves, coordinate_labels)
    if coordinate_units is not None:
        if len(coordinate_units) != nv or len(q_curves) != nv:
            raise ValueError(f"coordinate_units must give one unit per degree of freedom (nv = {nv}), "
                             f"got {len(coordinate_units)}")
        q_curves = [Curve(c.name, unit, c.values) for unit, c in zip(coordinate_units, q_curves)]
        v_curves = [Curve(c.name, f"{unit}/s" if unit else "", c.values) for unit, c in zip(coordinate_units, v_curves)]
    return q_curves, v_curves


def row_units(system, rows):
    """The unit of each of ``rows`` constraint multipliers of ``system``: ``"N"``, ``"N·m"``, or ``""``
    when the constraint does not fix it (user constraints, a surface ``f(x) = 0`` of any scaling)."""
    from .constraints import Distance, JointCoupling, LoopClosure, PointOnCurve
    from .rolling import KnifeEdge, RollingDisc, RollingSphere

    model, mechanical, constraints = _parts(system)
    units = []
    for constraint in constraints:
        m = constraint.rows(mechanical)
        if isinstance(constraint, (PointOnCurve, Distance, KnifeEdge, RollingSphere, RollingDisc)):
            units += ["N"] * m
        elif isinstance(constraint, LoopClosure):
            # position rows: a force on B's origin; orientation rows: a moment
            units += ["N"] * len(constraint.position_axes) + ["N·m"] * len(constraint.aligned_axes)
        elif isinstance(constraint, JointCoupling) and model is not None:
            kind = model.joints[model.joint_index(constraint.joint_b)].kind
            units += [{"prismatic": "N", "revolute": "N·m", "continuous": "N·m"}.get(kind, "")]
        else:
            units += [""] * m
    return units if len(units) == rows else [""] * rows


# ----------------------------------------------------------------------------- figures

def _legend(ax, curves):
    if len(curves) <= 12:
        ax.legend(fontsize="small", ncol=2 if len(curves) > 4 else 1)


def state_figure(trajectory, system=None, **labels):
    """Coordinates (left) and velocities (right) against time, one row of panels per unit
    (lengths, angles); ``labels``: :func:`state_curves`' ``coordinate_labels``, ``coordinate_units``."""
    q_curves, v_curves = state_curves(trajectory, system, **labels)
    # one row per coordinate unit; a velocity joins the row of the unit it is the rate of
    units = list(dict.fromkeys(c.unit for c in q_curves))
    rows = {unit: ([c for c in q_curves if c.unit == unit], [c for c in v_curves if c.unit == (f"{unit}/s" if unit else "")])
            for unit in units}
    t = trajectory.t
    # where units are unknown, the axis says which argument gives them
    missing = "pass system=" if system is None else "pass coordinate_units="
    figure = new_figure((10.0, 0.6 + 2.6 * len(rows)))
    axes = figure.subplots(len(rows), 2, sharex=True, squeeze=False)
    for (unit, (qs, vs)), (ax_q, ax_v) in zip(rows.items(), axes):
        for ax, curves, axis_unit, unknown in ((ax_q, qs, unit, f"q (units unknown: {missing})"),
                                               (ax_v, vs, f"{unit}/s" if unit else "", f"v (units unknown: {missing})")):
            for curve in curves:
                ax.plot(t, curve.values, label=curve.name)
            ax.set_ylabel(f"{QUANTITIES.get(axis_unit, 'value')} ({axis_unit})" if axis_unit else unknown)
            _legend(ax, curves)
    axes[0, 0].set_title("configuration")
    # free-flyer, planar and spherical velocities are in the moving joint frame (docs/conventions.md)
    axes[0, 1].set_title("velocity (in the joint frames)" if _parts(system)[0] is not None else "velocity")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    return figure


def energy_figure(trajectory):
    """The change of mechanical energy from the start, ``E − E₀`` (J), against time; ``None`` when the
    system defines no energy (all NaN)."""
    energy = np.asarray(trajectory.energy, dtype=float)
    if not np.isfinite(energy).any():
        return None
    figure = new_figure((7.0, 3.0))
    ax = figure.subplots()
    change = energy - energy[0]
    ax.plot(trajectory.t, change)
    ax.set_ylabel("E − E₀ (J)")
    ax.set_xlabel("t (s)")
    scale = np.nanmax(np.abs(energy))
    if scale > 0.0:
        ax.set_title(f"largest relative change max|E − E₀| / max|E| = {np.nanmax(np.abs(change)) / scale:.2e}",
                     fontsize="medium")
    return figure


def _row_level_units(units):
    """``(position unit, velocity unit)`` of constraint rows whose multipliers have ``units``."""
    levels = {ROW_LEVEL_UNITS.get(unit) for unit in units}
    if None in levels or not levels:
        return "units of φ", "of A v + b"
    if len(levels) == 1:
        return levels.pop()
    return "m or rad", "m/s or rad/s"


def residual_figure(trajectory, system=None, tolerance=None, *, multiplier_units=None):
    """The largest constraint violation ``max(|φ|, |A v + b|)`` against time, on a log scale, with the
    projection tolerance drawn when known (``tolerance``, else the trajectory's
    ``projection_tolerance``); ``None`` without constraint rows. The rows' units (m and m/s, rad and
    rad/s) follow from their multipliers' (``multiplier_units``, else the constraints')."""
    rows = np.shape(trajectory.lam)[-1]
    if not rows:
        return None
    residual = np.asarray(trajectory.residual, dtype=float)
    tolerance = getattr(trajectory, "projection_tolerance", None) if tolerance is None else tolerance
    # A log scale has no zero: exact zeros are drawn a decade below the smallest positive value (two
    # below the tolerance when all are zero), and the legend says so.
    positive = residual[np.isfinite(residual) & (residual > 0.0)]
    floor = positive.min() / 10.0 if positive.size else (tolerance / 100.0 if tolerance else 1e-17)
    figure = new_figure((7.0, 3.0))
    ax = figure.subplots()
    zeros = bool(np.any(residual == 0.0))
    ax.semilogy(trajectory.t, np.where(residual > 0.0, residual, floor),
                label=f"residual (exact zeros drawn at {floor:.0e})" if zeros else "residual")
    if tolerance:
        ax.axhline(tolerance, color="tab:red", linestyle="--", linewidth=1.0, label=f"projection tolerance {tolerance:.0e}")
    if tolerance or zeros:
        ax.legend(fontsize="small")
    units = row_units(system, rows) if multiplier_units is None else multiplier_units
    position, velocity = _row_level_units(units)
    ax.set_ylabel(f"max(|φ|, |A v + b|) ({position}, {velocity})")
    ax.set_xlabel("t (s)")
    return figure


def multiplier_figure(trajectory, system=None, *, multiplier_labels=None, multiplier_units=None):
    """The constraint multipliers ``λ`` against time, one panel per unit (N, N·m); ``None`` without
    constraint rows. ``multiplier_labels``: a name per row (default the trajectory's ``row_names``);
    ``multiplier_units``: a unit per row, for rows whose unit the constraint does not fix."""
    lam = np.asarray(trajectory.lam, dtype=float)
    rows = lam.shape[-1]
    if not rows:
        return None
    names = list(multiplier_labels if multiplier_labels is not None else trajectory.row_names) or \
        [f"λ[{k}]" for k in range(rows)]
    units = list(multiplier_units) if multiplier_units is not None else row_units(system, rows)
    for what, values in (("multiplier_labels", names), ("multiplier_units", units)):
        if len(values) != rows:
            raise ValueError(f"{what} must give one entry per constraint row ({rows}), got {len(values)}")
    panels = list(dict.fromkeys(units))
    figure = new_figure((7.0, 0.6 + 2.8 * len(panels)))
    axes = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for unit, ax in zip(panels, axes):
        members = [k for k in range(rows) if units[k] == unit]
        for k in members:
            ax.plot(trajectory.t, lam[:, k], label=names[k])
        ax.set_ylabel(f"λ ({unit})" if unit else "λ (J per unit of φ)")
        _legend(ax, members)
    axes[-1].set_xlabel("t (s)")
    return figure


def trajectory_figures(trajectory, system=None, *, coordinate_labels=None, coordinate_units=None,
                       multiplier_labels=None, multiplier_units=None, tolerance=None):
    """The figures of a trajectory, by name: ``"state"``; ``"energy"`` when the system has an energy;
    ``"residual"`` and ``"multipliers"`` when it has constraint rows. Arguments as in :func:`plot_trajectory`."""
    figures = {
        "state": state_figure(trajectory, system, coordinate_labels=coordinate_labels, coordinate_units=coordinate_units),
        "energy": energy_figure(trajectory),
        "residual": residual_figure(trajectory, system, tolerance, multiplier_units=multiplier_units),
        "multipliers": multiplier_figure(trajectory, system, multiplier_labels=multiplier_labels,
                                         multiplier_units=multiplier_units),
    }
    return {name: figure for name, figure in figures.items() if figure is not None}


def plot_trajectory(trajectory, out_dir, name, system=None, *, coordinate_labels=None, coordinate_units=None,
                    multiplier_labels=None, multiplier_units=None, tolerance=None, dpi=110):
    """Write the figures of a trajectory as PNG files and return their paths.

    ``<name>_state.png`` (coordinates and velocities, per unit), ``<name>_energy.png`` (``E − E₀``, J),
    ``<name>_residual.png`` (largest constraint violation, log scale, with the projection tolerance)
    and ``<name>_multipliers.png`` (one curve per constraint row, N and N·m apart): the energy figure
    when the system has an energy, the last two when it has constraint rows.

    Args:
        trajectory: a :class:`~multibody.trajectory.Trajectory`.
        out_dir: folder for the files (created when missing).
        name: the files' common prefix.
        system: what was simulated (``Model``, ``ConstrainedSystem``, or a mechanical system such as
            ``LagrangianSystem.numeric()``): its joints name the curves and give their units, and its
            constraints the multipliers' units. Without it, the raw columns, named after the
            trajectory's joints when each has one coordinate, on axes that say their units are unknown.
        coordinate_labels, coordinate_units: see :func:`state_curves`.
        multiplier_labels, multiplier_units: see :func:`multiplier_figure`.
        tolerance: residual bound to draw (default the trajectory's ``projection_tolerance``).
        dpi: resolution of the files.
    """
    figures = trajectory_figures(trajectory, system, coordinate_labels=coordinate_labels,
                                 coordinate_units=coordinate_units, multiplier_labels=multiplier_labels,
                                 multiplier_units=multiplier_units, tolerance=tolerance)
    return [save_figure(figure, out_dir, f"{name}_{suffix}", dpi) for suffix, figure in figures.items()]


def plot_path(xy, out_dir, name, title, labels=("x (m)", "y (m)"), dpi=110):
    """Write ``<name>_path.png``: a path ``xy (n, 2)`` seen from above, equal axes, its start marked.
    Returns the file path."""
    figure = new_figure((6.0, 5.0))
    ax = figure.subplots()
    ax.plot(xy[:, 0], xy[:, 1], label="path")
    ax.plot(xy[:1, 0], xy[:1, 1], "o", color="tab:green", label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title, fontsize="medium")
    ax.legend(fontsize="small")
    return save_figure(figure, out_dir, f"{name}_path", dpi)
