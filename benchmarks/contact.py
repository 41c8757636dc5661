"""Contact simulation of multibody against MuJoCo (measured in the same run): no creep, and speed.

1. **No creep.** A box (0.2 × 0.2 × 0.1 m, 1 kg) resting on a plane tilted by α = 20° with friction μ = 0.6 > tan α,
   2 s at dt = 1e-3 from rest: the largest speed of the box over the steps and its mean speed down the slope over
   the last second (the creep), ours (``mb.Ground`` with the plane's normal) beside MuJoCo's on the same scene
   (:data:`INCLINE_MJCF`: a box geom on a tilted plane, the default solver, condim 3, the same μ).
2. **Speed.** Go1 (example-robot-data ``go1_description/urdf/go1.urdf``, 38 collision primitives) standing on the
   ground under a joint-space PD, dt = 1e-3: the time per step of one trajectory on one thread, ``mb.simulate``
   against MuJoCo's ``mj_step`` (default solver) on the same model (:func:`mujoco_go1`: MuJoCo's URDF import of the
   same file, with a floor); and a batch of standing quadrupeds on every thread, ``mb.simulate`` with ``q0 (N, nq)``
   against ``mujoco.rollout`` with one ``MjData`` per thread.

The table is printed and saved as Markdown and JSON (``contact.md``, ``contact.json`` in ``--out``).

    python benchmarks/contact.py             # the full table (about a minute on two cores, compiled)
    python benchmarks/contact.py --quick     # small sizes, a smoke run

Times are the fastest of repeated runs. The machine is shared and noisy: compare ratios within one run, not absolute
numbers across runs.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from run import example_robot_data, load  # (the benchmarks' shared helpers, beside this script)

import multibody as mb
from multibody import inertia
from multibody.joints import FreeFlyer

G = 9.81
#: The incline of the no-creep scene: slope α (rad), friction μ, box edge lengths (m) and mass (kg).
ALPHA, MU = np.radians(20.0), 0.6
BOX_SIZE, BOX_MASS = (0.2, 0.2, 0.1), 1.0
#: Go1's standing pose: hip, thigh and calf angles (rad) of each leg, and the PD gains holding it (N·m/rad, N·m·s/rad)
#: on its 12 joints (none on the free flyer), with the friction of its feet on the ground.
GO1 = "go1_description/urdf/go1.urdf"
GO1_LEG = (0.0, 0.9, -1.8)
GO1_GAINS = (50.0, 2.0)
GO1_FRICTION = 0.8

#: MuJoCo's scene of the incline (``{alpha}`` in rad, ``{mu}``, box half-extents ``{hx} {hy} {hz}`` m, ``{mass}``
#: kg, ``{dt}`` s): a free box geom resting on a plane through the origin whose normal is ``(sin α, 0, cos α)``,
#: MuJoCo's default solver (Newton), cone (pyramidal) and condim (3), the same μ on both geoms (MuJoCo takes the
#: larger of the two).
INCLINE_MJCF = """
<mujoco model="incline">
  <compiler angle="radian"/>
  <option timestep="{dt}" gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="incline" type="plane" size="0 0 1" euler="0 {alpha} 0" friction="{mu} 0.005 0.0001"/>
    <body name="box" pos="{x} 0 {z}" euler="0 {alpha} 0">
      <freejoint/>
      <geom type="box" size="{hx} {hy} {hz}" mass="{mass}" condim="3" friction="{mu} 0.005 0.0001"/>
    </body>
  </worldbody>
</mujoco>
"""


def incline_state(alpha):
    """The box resting on the incline: ``q (7,)`` (its centre at half its height along the plane's normal, turned by
    ``alpha`` about y; quaternion ``[x, y, z, w]``) and the plane's unit normal ``(3,)``."""
    normal = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    return np.r_[0.5 * BOX_SIZE[2] * normal, 0.0, np.sin(alpha / 2), 0.0, np.cos(alpha / 2)], normal


def incline_creep(alpha=ALPHA, mu=MU, duration=2.0, dt=1e-3):
    """The no-creep scene, ours and MuJoCo's: for each, the largest speed (m/s) of the box's centre over the steps
    and its mean speed down the slope over the last second (or the last half of a shorter run), m/s, with the slope's
    residual ``tan α`` against ``μ``. MuJoCo's entries are absent without MuJoCo."""
    q0, normal = incline_state(alpha)
    builder = mb.ModelBuilder("box")
    builder.add_body("box", joint=FreeFlyer(), inertia=inertia.box(BOX_MASS, BOX_SIZE))
    builder.add_collision("box", "box", BOX_SIZE)
    system = mb.ConstrainedSystem(builder.build(), [mb.Ground(normal=normal, friction=mu)])
    trajectory = mb.simulate(system, q0, np.zeros(6), duration, dt=dt)
    downhill = np.array([np.cos(alpha), 0.0, -np.sin(alpha)])
    steps = len(trajectory.t) - 1
    window = min(round(1.0 / dt), steps // 2)
    # v[:3] is the velocity of the box's centre in its own axes: its norm is the speed
    result = {"alpha_deg": float(np.degrees(alpha)), "mu": mu, "duration_s": duration, "dt": dt,
              "ours_max_speed": float(np.linalg.norm(trajectory.v[:, :3], axis=1).max()),
              "ours_creep_speed": float(abs((trajectory.q[-1, :3] - trajectory.q[-1 - window, :3]) @ downhill)
                                        / (window * dt)),
              "ours_complementarity": float(trajectory.complementarity.max()), "ours_status": trajectory.status}
    try:
        import mujoco
    except ImportError:
        return result
    scene = INCLINE_MJCF.format(alpha=alpha, mu=mu, hx=BOX_SIZE[0] / 2, hy=BOX_SIZE[1] / 2, hz=BOX_SIZE[2] / 2,
                                mass=BOX_MASS, dt=dt, x=q0[0], z=q0[2])
    model = mujoco.MjModel.from_xml_string(scene)
    data = mujoco.MjData(model)
    positions, speeds = np.empty((steps + 1, 3)), np.empty(steps + 1)
    positions[0], speeds[0] = data.qpos[:3], 0.0
    for k in range(1, steps + 1):
        mujoco.mj_step(model, data)
        # a free joint's qvel[:3] is the velocity of its body's origin (here the box's centre) in world axes
        positions[k], speeds[k] = data.qpos[:3], np.linalg.norm(data.qvel[:3])
    result["mujoco_max_speed"] = float(speeds.max())
    result["mujoco_creep_speed"] = float(abs((positions[-1] - positions[-1 - window]) @ downhill) / (window * dt))
    result["mujoco_slid_m"] = float((positions[-1] - positions[0]) @ downhill)
    return result


def go1_model():
    """Our Go1 (free-flyer base) from example-robot-data, and its path."""
    path = os.path.join(example_robot_data(), GO1)
    return load(path, floating_base=True), path


def go1_standing(model):
    """Go1 standing on the ground: ``q (nq,)`` with each leg at :data:`GO1_LEG` and the trunk level, high enough that
    its lowest foot sphere touches the plane z = 0 (the feet are the collision spheres of the URDF)."""
    q = model.neutral()
    q[7:] = np.tile(GO1_LEG, 4)
    radius = max(g.size[0] for g in model.collision_geometries if g.shape == "sphere")
    feet = [mb.frame_placement(model, q, f"{leg}_foot")[2, 3] for leg in ("FL", "FR", "RL", "RR")]
    q[2] = radius - min(feet)
    return q


def go1_pd(model, q_ref):
    """The standing PD of :data:`GO1_GAINS` on Go1's 12 joints (the free flyer unactuated) towards ``q_ref``."""
    kp, kd = GO1_GAINS
    actuated = np.r_[np.zeros(6), np.ones(model.nv - 6)]
    return mb.PD(kp * actuated, kd * actuated, q_ref)


def mujoco_go1(path, model, q_ref, dt):
    """MuJoCo's Go1 for the same dynamics as ``mb.simulate`` on ``mb.ConstrainedSystem(model, [mb.Ground(friction=
    GO1_FRICTION)])`` under :func:`go1_pd`, or ``None`` without MuJoCo.

    Built by MuJoCo's URDF import (``MjSpec.from_string``) of the same file's text with three edits: the ``<visual>``
    meshes removed (Collada files, which MuJoCo does not read), the fixed joint ``floating_base`` between the
    massless ``base`` link and the trunk made ``floating`` (a free joint), and ``base``'s inertial (1e-6 kg, an
    inertia with zero eigenvalues, which MuJoCo refuses) removed. Then: a ground plane z = 0; every geom's friction
    μ = :data:`GO1_FRICTION` (MuJoCo takes the larger of two geoms'), the robot's geoms colliding with the plane only
    (``conaffinity`` 0, as ``mb.Ground`` makes no contact between the robot's bodies); the PD as one affine actuator
    per joint (``τ = k_p ctrl − k_p q − k_d v`` with ``ctrl`` the joint's reference); the URDF's joint damping,
    Coulomb joint friction, effort limits and joint limits off (``mb.simulate`` applies none of them here); the
    default solver, cone and condim; step ``dt``.

    Returns ``(mujoco model, qpos index (nq,), qvel index (nv,), ctrl (12,))``: MuJoCo's addresses of our ``q`` and
    ``v`` coordinates in our order (MuJoCo orders the legs as the file does, we as Pinocchio does), and the actuators'
    references."""
    try:
        import mujoco
    except ImportError:
        return None
    with open(path) as handle:
        text = handle.read()
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.DOTALL)
    text = re.sub(r'(<link name="base">\s*)<inertial>.*?</inertial>', r"\1", text, flags=re.DOTALL)
    text = text.replace('<joint name="floating_base" type="fixed">', '<joint name="floating_base" type="floating">')
    spec = mujoco.MjSpec.from_string(text)
    for geom in spec.geoms:
        geom.friction[0], geom.conaffinity = GO1_FRICTION, 0
    floor = spec.worldbody.add_geom()
    floor.type, floor.size = mujoco.mjtGeom.mjGEOM_PLANE, [0.0, 0.0, 1.0]
    floor.friction[0], floor.contype, floor.conaffinity = GO1_FRICTION, 0, 1
    kp, kd = GO1_GAINS
    names = model.joint_names[1:]
    for name in names:
        actuator = spec.add_actuator()
        actuator.trntype, actuator.target = mujoco.mjtTrn.mjTRN_JOINT, name
        actuator.gaintype, actuator.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        actuator.gainprm[0] = kp
        actuator.biasprm[:3] = (0.0, -kp, -kd)
    compiled = spec.compile()
    compiled.jnt_actfrclimited[:] = 0
    compiled.dof_damping[:] = 0.0
    compiled.dof_frictionloss[:] = 0.0
    compiled.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_LIMIT
    compiled.opt.timestep = dt
    qpos, qvel = [], []
    for j, joint in enumerate(model.joints):
        mj = compiled.joint("floating_base" if j == 0 else model.joint_names[j]).id
        qpos += range(compiled.jnt_qposadr[mj], compiled.jnt_qposadr[mj] + joint.nq)
        qvel += range(compiled.jnt_dofadr[mj], compiled.jnt_dofadr[mj] + joint.nv)
    qpos, qvel = np.array(qpos), np.array(qvel)
    # the actuators were added in our joint order: their references are our q_ref's joint angles
    return compiled, qpos, qvel, q_ref[7:].copy()


def mujoco_state(model, q, v, qpos_index, qvel_index, nq, nv):
    """MuJoCo's ``qpos (nq,)``, ``qvel (nv,)`` of our state ``q``, ``v`` (:func:`multibody.to_mujoco`'s conventions,
    placed at MuJoCo's addresses)."""
    qpos, qvel = np.zeros(nq), np.zeros(nv)
    qpos[qpos_index], qvel[qvel_index] = mb.to_mujoco(model, q, v)
    return qpos, qvel


def go1_single(duration=1.0, dt=1e-3, repeats=3):
    """Go1 standing for ``duration`` s at step ``dt`` on one thread: the wall time per step (µs, best of ``repeats``
    interleaved runs) of ``mb.simulate`` (end to end) and of MuJoCo's ``mj_step`` loop in C, the trunk's final
    height in each (m; MuJoCo's soft contact sinks the feet into the ground), the largest complementarity residual of
    our steps (m/s), and the largest difference of the joints' free accelerations (no contact, zero velocity) at the
    standing pose, which checks that the two models are the same."""
    model, path = go1_model()
    q0, v0 = go1_standing(model), np.zeros(model.nv)
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=GO1_FRICTION)])
    pd = go1_pd(model, q0)
    steps = round(duration / dt)
    built = mujoco_go1(path, model, q0, dt)
    threads = mb.get_num_threads()
    mb.set_num_threads(1)
    ours, theirs = [], []
    try:
        mb.simulate(system, q0, v0, 3 * dt, dt=dt, tau=pd)  # compiled (or loaded) before timing
        for _ in range(repeats):
            start = time.perf_counter()
            trajectory = mb.simulate(system, q0, v0, duration, dt=dt, tau=pd)
            ours.append((time.perf_counter() - start) / steps)
            if built is not None:
                import mujoco

                mj_model, qpos_index, qvel_index, ctrl = built
                data = mujoco.MjData(mj_model)
                data.qpos[:], data.qvel[:] = mujoco_state(model, q0, v0, qpos_index, qvel_index, mj_model.nq,
                                                          mj_model.nv)
                data.ctrl[:] = ctrl
                start = time.perf_counter()
                mujoco.mj_step(mj_model, data, nstep=steps)
                theirs.append((time.perf_counter() - start) / steps)
    finally:
        mb.set_num_threads(threads)
    result = {"duration_s": duration, "dt": dt, "nv": model.nv, "geometries": len(model.collision_geometries),
              "ours_step_us": min(ours) * 1e6, "ours_trunk_height_m": float(trajectory.q[-1, 2]),
              "ours_complementarity": float(trajectory.complementarity.max()), "ours_status": trajectory.status,
              "ours_contacts": len(trajectory.contacts[-1])}
    if built is not None:
        result["mujoco_step_us"] = min(theirs) * 1e6
        result["mujoco_trunk_height_m"] = float(data.qpos[qpos_index[2]])
        result["mujoco_contacts"] = int(data.ncon)
        result["ratio"] = result["ours_step_us"] / result["mujoco_step_us"]
        # the same model: free joint accelerations at the standing pose, contacts and actuators off
        mj_model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_ACTUATION
        mujoco.mj_resetData(mj_model, data)
        data.qpos[:], data.qvel[:] = mujoco_state(model, q0, v0, qpos_index, qvel_index, mj_model.nq, mj_model.nv)
        mujoco.mj_forward(mj_model, data)
        a = mb.forward_dynamics(model, q0, v0, np.zeros(model.nv))
        result["joint_acceleration_difference"] = float(np.abs(data.qacc[qvel_index[6:]] - a[6:]).max())
    return result


def go1_batch(n=4096, duration=0.1, dt=1e-3, repeats=2):
    """``n`` Go1 standing (each at its own place on the ground and heading: x, y uniform in [−1, 1] m, yaw uniform)
    for ``duration`` s at step ``dt`` on every thread: the wall time per trajectory-step (µs, best of ``repeats``) of
    one ``mb.simulate`` call with ``q0 (n, nq)`` and of ``mujoco.rollout`` with one ``MjData`` per thread, the
    trajectories completed, and the mean final trunk height of each (m)."""
    model, path = go1_model()
    standing = go1_standing(model)
    rng = np.random.default_rng(8)
    q0 = np.tile(standing, (n, 1))
    q0[:, :2] = rng.uniform(-1.0, 1.0, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    q0[:, 3:7] = np.c_[np.zeros((n, 2)), np.sin(yaw / 2), np.cos(yaw / 2)]
    v0 = np.zeros((n, model.nv))
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=GO1_FRICTION)])
    # the joints' PD (its free-flyer gains are zero, so the one reference serves every place and heading)
    pd = go1_pd(model, standing)
    steps = round(duration / dt)
    options = {"dt": dt, "tau": pd, "progress": False}
    mb.simulate(system, q0[:2], v0[:2], 3 * dt, **options)  # compiled (or loaded) before timing
    ours = []
    for _ in range(repeats):
        start = time.perf_counter()
        trajectory = mb.simulate(system, q0, v0, duration, **options)
        ours.append((time.perf_counter() - start) / (n * steps))
    threads = mb.get_num_threads()
    result = {"n": n, "duration_s": duration, "dt": dt, "threads": threads, "ours_us": min(ours) * 1e6,
              "ours_completed": int(sum(status == "completed" for status in trajectory.status)),
              "ours_trunk_height_m": float(np.mean(trajectory.q[:, -1, 2]))}
    built = mujoco_go1(path, model, standing, dt)
    if built is None:
        return result
    import mujoco
    from mujoco import rollout

    mj_model, qpos_index, qvel_index, ctrl = built
    datas = [mujoco.MjData(mj_model) for _ in range(threads)]
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.zeros((n, mujoco.mj_stateSize(mj_model, full)))
    for r in range(n):
        mujoco.mj_resetData(mj_model, datas[0])
        datas[0].qpos[:], datas[0].qvel[:] = mujoco_state(model, q0[r], v0[r], qpos_index, qvel_index, mj_model.nq,
                                                          mj_model.nv)
        mujoco.mj_getState(mj_model, datas[0], initial[r], full)
    control = np.broadcast_to(ctrl, (1, 1, mj_model.nu))
    theirs = []
    for _ in range(repeats):
        start = time.perf_counter()
        states, _ = rollout.rollout(mj_model, datas, initial, control, nstep=steps)
        theirs.append((time.perf_counter() - start) / (n * steps))
    # the state's layout: time, qpos, qvel, ...
    result["mujoco_us"] = min(theirs) * 1e6
    result["mujoco_trunk_height_m"] = float(np.mean(states[:, -1, 1 + qpos_index[2]]))
    result["ratio"] = result["ours_us"] / result["mujoco_us"]
    return result


def markdown(creep, single, batch):
    """The benchmark's table: one row per measurement, ours beside MuJoCo's ("not measured" where MuJoCo is
    missing)."""
    def cell(value, form):
        return "not measured" if value is None else format(value, form)

    rows = [
        (f"box held on a {creep['alpha_deg']:g}° incline (μ = {creep['mu']:g}), {creep['duration_s']:g} s at "
         f"dt = {creep['dt']:g}: largest speed over the steps (m/s)",
         cell(creep["ours_max_speed"], ".1e"), cell(creep.get("mujoco_max_speed"), ".1e"), ""),
        ("the same: creep, mean speed down the slope over the last second (m/s)",
         cell(creep["ours_creep_speed"], ".1e"), cell(creep.get("mujoco_creep_speed"), ".1e"), ""),
        (f"Go1 standing ({single['nv']} dof, {single['geometries']} collision shapes), dt = {single['dt']:g}, one "
         f"thread: time per step (µs)", cell(single["ours_step_us"], ".1f"), cell(single.get("mujoco_step_us"), ".1f"),
         cell(single.get("ratio"), ".2f")),
        (f"{batch['n']} Go1 standing for {batch['duration_s']:g} s, {batch['threads']} threads: time per "
         "trajectory-step (µs)", cell(batch["ours_us"], ".2f"), cell(batch.get("mujoco_us"), ".2f"),
         cell(batch.get("ratio"), ".2f")),
    ]
    lines = ["| contact | multibody | MuJoCo | ratio |", "|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def notes(creep, single, batch):
    """The lines below the table: what each run ended with (statuses, residuals, heights, the models' check)."""
    nan = float("nan")
    return [
        f"incline: our steps' largest complementarity residual {creep['ours_complementarity']:.1e} m/s "
        f"({creep['ours_status']}); MuJoCo's box slid {creep.get('mujoco_slid_m', nan):.2e} m in "
        f"{creep['duration_s']:g} s",
        f"Go1, one thread, {single['duration_s']:g} s: trunk height at the end {single['ours_trunk_height_m']:.4f} m "
        f"(ours; {single['ours_contacts']} contact points, residual {single['ours_complementarity']:.1e} m/s, "
        f"{single['ours_status']}) and {single.get('mujoco_trunk_height_m', nan):.4f} m (MuJoCo, "
        f"{single.get('mujoco_contacts', 0)} contacts); free joint accelerations of the two models agree to "
        f"{single.get('joint_acceleration_difference', nan):.1e}",
        f"Go1 batch: {batch['ours_completed']} of {batch['n']} completed; mean trunk height at the end "
        f"{batch['ours_trunk_height_m']:.4f} m (ours) and {batch.get('mujoco_trunk_height_m', nan):.4f} m (MuJoCo)",
    ]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run)")
    parser.add_argument("--batch", type=int, default=4096, help="quadrupeds in the batch")
    parser.add_argument("--batch-duration", type=float, default=0.1, help="seconds simulated by the batch")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results"))
    args = parser.parse_args(argv)
    if example_robot_data() is None:
        print("example-robot-data is not installed: pip install example-robot-data", file=sys.stderr)
        return 2
    creep = incline_creep()
    if args.quick:
        single = go1_single(0.01, repeats=1)
        batch = go1_batch(4, 0.005)
    else:
        single = go1_single(1.0, repeats=3)
        batch = go1_batch(args.batch, args.batch_duration)
    table = markdown(creep, single, batch)
    lines = notes(creep, single, batch)
    print(table)
    print()
    print("\n".join(lines))
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "contact.json"), "w") as handle:
        json.dump({"incline": creep, "go1": single, "go1_batch": batch}, handle, indent=1)
    with open(os.path.join(args.out, "contact.md"), "w") as handle:
        handle.write(table + "\n\n" + "\n".join(f"- {line}" for line in lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
