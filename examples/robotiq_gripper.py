"""gym-hil's Robotiq 2F-85 gripper closing on an object-free stroke, and the forces that close its loops.

The gripper comes from gym-hil's ``panda.xml`` (``pip install --no-deps gym-hil``): its subtree, from
``base_mount`` down, is written out as an MJCF document of its own with the file's ``2f85`` default
class, meshes and materials and its three equalities (:func:`gripper_mjcf`), hung from the world with
the fingers pointing down, and read by ``mb.load_mjcf``. Each finger is a five-bar loop: the driver
and the spring link turn on the base, the coupler on the driver and the follower (which holds the pad)
on the spring link; a ``connect`` equality pins the follower to the coupler (a point loop closure,
three rows of rank two, as the loop is planar), and a ``joint`` equality makes the left driver follow
the right one. Eight joints less five independent rows leave three degrees of freedom, as in MuJoCo.

The model leaves out what is not rigid-body dynamics. The spring links' springs (``stiffness``
towards ``springref``) are added back as joint torques, ``τ = −k (q − q_spring)``, as MuJoCo compiles
them from the file (:func:`joint_springs`). Those springs press each coupler onto the upper end of its range (MuJoCo's own
simulation of this stroke has both coupler limits active from its second 0.1 ms step to the end), which
keeps the finger's pad parallel until it touches something; the model enforces no limits, so the stroke
holds each coupler there with a ``mb.JointCoupling(None, coupler, offset=upper)``, whose multiplier is
the torque of the stop (N·m). That leaves one degree of freedom, the drivers' angle, which a PD
controller on the right driver joint (a Python callable ``tau(t, q, v)``) takes from open (0 rad) to
closed along a minimum-jerk ramp; the joint equality carries the left finger's share to it, and its
multiplier is that torque (N·m, on the right driver joint). Joint damping and armature are the file's.

The figure (``robotiq_gripper.png``) shows, against time: the opening between the pads and the driver
angle (with MuJoCo's simulation of the same stroke when ``mujoco`` is installed: the same torques,
applied through ``qfrc_applied``, with its soft equalities and limits); the reaction force on each
coupler at its pin (the ``connect`` multipliers, N, in the follower's axes); and the coupling's torque
and the stops' torques (N·m).
Run: python examples/robotiq_gripper.py [output_folder]
"""

from __future__ import annotations

import copy
import importlib.util
import os
import sys
import warnings
import xml.etree.ElementTree as ET

import numpy as np

import multibody as mb
from multibody.plotting import new_figure, save_figure

#: The gripper's root body in gym-hil's panda.xml, and the default class of its elements.
GRIPPER_ROOT, GRIPPER_CLASS = "base_mount", "2f85"
#: Where the gripper hangs: 0.3 m above the world's origin, turned by π about x so that its fingers point down.
MOUNT = {"pos": "0 0 0.3", "quat": "0 1 0 0"}
FINGERS = ("right", "left")
#: The PD controller of the right driver joint: stiffness (N·m/rad) and damping (N·m·s/rad), with the joints'
#: own damping (0.2 N·m·s/rad on the drivers' one coordinate) close to critical for its inertia, about
#: 0.0102 kg·m²; the closed angle (rad), short of the driver's upper limit (0.8 rad) by more than the
#: springs' pull leaves the controller behind (their torque over GAIN), since no stop holds it here; and the
#: duration of the minimum-jerk ramp from open to closed (s).
GAIN, DAMPING, CLOSED, RAMP = 20.0, 0.7, 0.78, 0.5


def panda_xml():
    """The path of gym-hil's ``panda.xml``, found without importing ``gym_hil`` (its dependencies are not
    needed here); ``None`` when gym-hil is not installed."""
    spec = importlib.util.find_spec("gym_hil")
    if spec is None:
        return None
    path = os.path.join(spec.submodule_search_locations[0], "assets", "panda.xml")
    return path if os.path.isfile(path) else None


def gripper_mjcf(panda_path):
    """The gripper of ``panda_path`` as an MJCF document of its own (a string): the compiler settings, the
    ``2f85`` default class, the gripper's meshes (``meshdir`` the folder of ``panda_path``, absolute, so
    that the string loads from anywhere) and the materials, the subtree from ``base_mount`` placed at
    :data:`MOUNT`, and the equalities; contacts are disabled (an object-free stroke), and the actuator,
    tendon and sensors are left out (the example applies its own joint torques)."""
    root = ET.parse(panda_path).getroot()
    out = ET.Element("mujoco", model="robotiq_2f85")
    compiler = copy.deepcopy(root.find("compiler"))
    compiler.set("meshdir", os.path.dirname(os.path.abspath(panda_path)))
    out.append(compiler)
    option = ET.SubElement(out, "option")
    ET.SubElement(option, "flag", contact="disable")
    # the main class with the gripper's class, its only child kept
    defaults = copy.deepcopy(root.find("default"))
    for child in defaults.findall("default"):
        if child.get("class") != GRIPPER_CLASS:
            defaults.remove(child)
    out.append(defaults)
    asset = ET.SubElement(out, "asset")
    asset.extend(copy.deepcopy(mesh) for mesh in root.iter("mesh")
                 if mesh.get("class") == GRIPPER_CLASS and mesh.get("file"))
    asset.extend(copy.deepcopy(material) for material in root.iter("material"))
    mount = next((body for body in root.iter("body") if body.get("name") == GRIPPER_ROOT), None)
    if mount is None:
        raise ValueError(f"{panda_path}: no body {GRIPPER_ROOT!r}")
    mount = copy.deepcopy(mount)
    mount.attrib.update(MOUNT)
    mount.set("childclass", GRIPPER_CLASS)
    ET.SubElement(out, "worldbody").append(mount)
    out.append(copy.deepcopy(root.find("equality")))
    return ET.tostring(out, encoding="unicode")


def joint_springs(reference):
    """``(stiffness (nv,), spring reference (nv,))`` of the joints of ``reference``, MuJoCo's compiled model
    (``mujoco.MjModel``) of the gripper's MJCF document (N·m/rad, rad): its ``jnt_stiffness`` and
    ``qpos_spring`` (each joint's ``stiffness`` and ``springref``, its default classes resolved); the loader
    leaves the springs out. The gripper's joints are hinges, so MuJoCo's joint order is the model's velocity
    order."""
    return reference.jnt_stiffness.copy(), reference.qpos_spring.copy()


def load_gripper(panda_path):
    """``(model, xml)``: the gripper's :class:`~multibody.model.Model` and its MJCF document. The loader's
    warning that the springs are left out is expected (:func:`joint_springs` adds them back)."""
    xml = gripper_mjcf(panda_path)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*joint springs \(stiffness, springdamper\) are not modelled")
        model = mb.load_mjcf(xml)
    return model, xml


def stops(model):
    """Each coupler held at the upper end of its range, where the springs press it during a free stroke."""
    return [mb.JointCoupling(None, f"{side}_coupler_joint", offset=model.upper[model.idx_q[
        model.joint_index(f"{side}_coupler_joint")]], name=f"{side} coupler stop") for side in FINGERS]


def minimum_jerk(t, start, end, duration):
    """``(q, v)`` of the minimum-jerk path from ``start`` to ``end`` in ``duration`` (s), held after it:
    ``q = start + (end − start) (10 s³ − 15 s⁴ + 6 s⁵)``, ``s = t / duration`` (Flash and Hogan,
    J. Neurosci. 5 (1985), eq. 2)."""
    s = min(max(t / duration, 0.0), 1.0)
    shape = s**3 * (10.0 - 15.0 * s + 6.0 * s * s)
    rate = 30.0 * s * s * (1.0 - s) ** 2 / duration
    return start + (end - start) * shape, (end - start) * rate


def stroke_torques(model, xml, closed=CLOSED):
    """The joint torques of the stroke, a callable ``tau(t, q, v) -> (nv,)`` (N·m): the springs of
    :func:`joint_springs`, and on the right driver joint a PD controller (:data:`GAIN`, :data:`DAMPING`)
    following :func:`minimum_jerk` from 0 to ``closed`` (rad)."""
    import mujoco

    stiffness, reference = joint_springs(mujoco.MjModel.from_xml_string(xml))
    driver = model.idx_v[model.joint_index("right_driver_joint")]

    def tau(t, q, v):
        torque = -stiffness * (q - reference)
        target, rate = minimum_jerk(t, 0.0, closed, RAMP)
        torque[driver] += GAIN * (target - q[driver]) + DAMPING * (rate - v[driver])
        return torque

    return tau


def close_gripper(model, xml, duration=1.0, dt=0.005):
    """The stroke of the gripper ``model`` (of the MJCF document ``xml``): ``(system, trajectory, tau)``, its
    equalities and :func:`stops`, simulated from rest with the drivers open for ``duration`` s (output
    every ``dt`` s) under :func:`stroke_torques` and the joints' damping."""
    system = mb.ConstrainedSystem(model, [*model.equality_constraints, *stops(model)])
    tau = stroke_torques(model, xml)
    with warnings.catch_warnings():
        # the planar loops' point closures repeat a row each (9 rows of rank 7), by design
        warnings.simplefilter("ignore", mb.RankDeficientWarning)
        q0, v0 = system.project(np.zeros(model.nq), np.zeros(model.nv))
        trajectory = mb.simulate(system, q0, v0, duration, dt=dt, method="DOP853", tau=tau, rtol=1e-10,
                                 atol=1e-12, joint_damping=True, limits="ignore")
    return system, trajectory, tau


def opening(model, q):
    """Distance between the two pads' frames (m) at the configurations ``q (..., nq)``."""
    poses = mb.forward_kinematics(model, q)
    pads = [model.body_index(f"{side}_pad") for side in FINGERS]
    return np.linalg.norm(poses[..., pads[0], :3, 3] - poses[..., pads[1], :3, 3], axis=-1)


def mujoco_stroke(xml, model, tau, times):
    """MuJoCo's simulation of the same stroke, if ``mujoco`` is installed: the torques ``tau`` less the
    springs (MuJoCo has its own) in ``qfrc_applied``, its own limits, soft equalities and damping, at a
    step of 0.1 ms; ``qpos (len(times), nq)`` at ``times``, or ``None``."""
    try:
        import mujoco
    except ImportError:
        return None
    reference = mujoco.MjModel.from_xml_string(xml)
    reference.opt.timestep = 1e-4
    data = mujoco.MjData(reference)
    stiffness, spring = joint_springs(reference)
    out = []
    for time in times:
        while data.time < time - 0.5 * reference.opt.timestep:
            q, v = mb.from_mujoco(model, data.qpos, data.qvel)
            data.qfrc_applied[:] = tau(data.time, q, v) + stiffness * (q - spring)
            mujoco.mj_step(reference, data)
        out.append(data.qpos.copy())
    return np.array(out)


def multipliers(system, trajectory):
    """``{constraint name: λ (n, rows)}``: the trajectory's multipliers, constraint by constraint."""
    ends = np.cumsum([0] + [c.rows(system.system) for c in system.constraints])
    return {c.name: trajectory.lam[:, ends[k] : ends[k + 1]] for k, c in enumerate(system.constraints)}


def main(out="output", panda_path=None):
    panda_path = panda_path or panda_xml()
    if panda_path is None:
        sys.exit("gym-hil is not installed: pip install --no-deps gym-hil")
    model, xml = load_gripper(panda_path)
    system, trajectory, tau = close_gripper(model, xml)
    t, lam = trajectory.t, multipliers(system, trajectory)
    driver = model.idx_v[model.joint_index("right_driver_joint")]
    pins = [c for c in system.constraints if isinstance(c, mb.LoopClosure)]
    coupling, *held = [c for c in system.constraints if isinstance(c, mb.JointCoupling)]
    width = opening(model, trajectory.q)
    print(f"{model.nv} joints, {system.num_rows} rows of rank {system.rank(trajectory.q[0])}: "
          f"{model.nv - system.rank(trajectory.q[0])} degree(s) of freedom in the stroke")
    print(f"opening {1e3 * width[0]:.1f} mm -> {1e3 * width[-1]:.1f} mm, driver {trajectory.q[-1, driver]:.4f} rad, "
          f"largest closure residual {trajectory.residual.max():.1e}")
    for c in pins:
        print(f"{c.body_a.split('_')[0]} pin ({c.name}): force up to {np.linalg.norm(lam[c.name], axis=1).max():.3f} N")
    print(f"drivers' coupling ({coupling.name}): torque up to {np.abs(lam[coupling.name]).max():.4f} N·m")
    for c in held:
        print(f"{c.name}: torque up to {np.abs(lam[c.name]).max():.4f} N·m")

    figure = new_figure((7.0, 8.5))
    top, middle, bottom = figure.subplots(3, 1, sharex=True)
    top.plot(t, 1e3 * width, label="opening between the pads")
    qpos = mujoco_stroke(xml, model, tau, t)
    if qpos is not None:
        q_mujoco, _ = mb.from_mujoco(model, qpos, np.zeros((len(t), model.nv)))
        top.plot(t, 1e3 * opening(model, q_mujoco), "k--", lw=1, label="MuJoCo (soft constraints and limits)")
        print(f"MuJoCo's opening differs by {1e3 * np.abs(opening(model, q_mujoco) - width).max():.2f} mm at most")
    top.set_ylabel("opening (mm)")
    angle = top.twinx()
    angle.plot(t, trajectory.q[:, driver], color="C1", label="driver angle")
    angle.set_ylabel("driver angle (rad)")
    lines = top.get_lines() + angle.get_lines()
    top.legend(lines, [line.get_label() for line in lines], loc="center right", fontsize="small")
    top.set_title("Robotiq 2F-85 (gym-hil): an object-free stroke")
    for k, c in enumerate(pins):
        side, force = c.body_a.split("_")[0], lam[c.name]
        # the loop turns about the follower's x axis: the pin's force lies along its y and z (λ_x is zero)
        middle.plot(t, np.linalg.norm(force, axis=1), color=f"C{k}", lw=2.5 - k, label=f"{side} pin |λ|")
        for axis, style in ((1, ":"), (2, "--")):
            middle.plot(t, force[:, axis], style, color=f"C{k}", lw=2.5 - k, label=f"{side} pin λ_{'xyz'[axis]}")
    middle.set_ylabel("connect force on the coupler (N)")
    middle.legend(fontsize="small", ncol=3, loc="center right")
    bottom.plot(t, lam[coupling.name][:, 0], color="C2", label="drivers' coupling (on the right driver)")
    for k, c in enumerate(held):
        bottom.plot(t, lam[c.name][:, 0], color=f"C{k + 3}", lw=2.5 - k, label=c.name)
    bottom.set_ylabel("torque (N·m)")
    bottom.set_xlabel("t (s)")
    bottom.legend(fontsize="small")
    for ax in (top, middle, bottom):
        ax.grid(True, alpha=0.3)
    print("wrote", save_figure(figure, out, "robotiq_gripper"))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "output")
