"""Speed of multibody against Pinocchio (measured in the same run), single calls and batches.

For each robot and algorithm it reports multibody's single-call time, its time per state for
batches of N states (on every thread, and for the largest N on one thread too), Pinocchio's time
per call from Python, and their ratios; then the peak memory of a large batched CRBA, one
constrained-dynamics step of the rolling ball and the wall time of simulating it for 10 s with
1 kHz output (adaptive DOP853 with dense output, and fixed-step RK4), and a Panda under a PD
controller simulated for 3 s by RK4 at 1 kHz on one thread (mb.PD, a numba.njit controller and a Python callable),
next to the same loop written on Pinocchio and MuJoCo's RK4 mj_step in C on the same ODE; one constrained
evaluation of a closed chain of 40 parallelograms near its singular flat configuration; 4096
double-pendulum and Panda trajectories by batched RK4 for 1 s at 1 kHz, against batched forward dynamics, and
4096 Panda trajectories under mb.PD against mujoco.rollout on the same threads;
with Dask installed, the overhead of chunks of 1e5 states on two local worker processes; on a CUDA GPU, Panda
RNEA, CRBA and ABA states/s and batched RK4 trajectory-steps/s under mb.PD against the CPU (or one line saying no GPU
was found); and the time to load gymnasium's MJCF humanoid against MuJoCo's own compiler.
The table is printed and saved as JSON and Markdown. Simulation with contact, beside MuJoCo, is measured by
benchmarks/contact.py.

    python benchmarks/run.py                      # the full table (several minutes)
    python benchmarks/run.py --quick              # small sizes, a smoke run
    python benchmarks/run.py --robots panda ur5 --sizes 1 4096
    python benchmarks/run.py --gpu                # the GPU lines alone

Times are the fastest of repeated samples (µs; see ``best_time``). The machine is shared and noisy:
compare ratios within one run, not absolute numbers across runs.
"""

from __future__ import annotations

import argparse
import json
import os
import site
import sys
import time
import tracemalloc

import numpy as np

import multibody as mb
from multibody.check import to_pinocchio_configuration

ROBOTS = {
    # name: (path below example-robot-data/robots, free-flyer base, end-effector body)
    "double_pendulum": ("double_pendulum_description/urdf/double_pendulum.urdf", False, "link2"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False, "tool0"),
    "panda": ("panda_description/urdf/panda.urdf", False, "panda_hand"),
    "solo12": ("solo_description/robots/solo12.urdf", True, "FL_FOOT"),
    "talos_reduced": ("talos_data/robots/talos_reduced.urdf", True, "arm_left_7_link"),
}
ALGORITHMS = ("rnea", "crba", "aba", "coriolis", "bias", "jacobian", "rnea_derivatives", "aba_derivatives")


def example_robot_data():
    for directory in site.getsitepackages() + [site.getusersitepackages()]:
        path = os.path.join(directory, "cmeel.prefix", "share", "example-robot-data", "robots")
        if os.path.isdir(path):
            return path
    return None


def load(path, floating_base=False):
    """An example-robot-data robot with its ``package://`` meshes resolved (from the folder that holds
    example-robot-data's share directory), so that loading it warns of nothing."""
    share = os.path.dirname(os.path.dirname(example_robot_data()))
    return mb.load_urdf(path, floating_base=floating_base, package_dirs=[share])


def best_time(fn, budget=0.3, min_runs=3):
    """Wall time (s) of one ``fn()``: the fastest of repeated samples filling about ``budget`` seconds.

    A sample times a loop of calls lasting at least 2 ms, so that the timer's own cost does not count
    for fast calls. The minimum is the estimate least disturbed by other load on a shared machine
    (the advice of Python's ``timeit``); both libraries are measured this way.
    """
    fn()
    t0 = time.perf_counter()
    fn()
    number = max(1, int(2e-3 / max(time.perf_counter() - t0, 1e-9)))
    samples = []
    start = time.perf_counter()
    while len(samples) < min_runs or time.perf_counter() - start < budget:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number)
        if len(samples) >= 10000:
            break
    return float(min(samples))


def ours(model, algorithm, q, v, a, body):
    return {
        "rnea": lambda: mb.inverse_dynamics(model, q, v, a),
        "crba": lambda: mb.mass_matrix(model, q),
        "aba": lambda: mb.forward_dynamics(model, q, v, a),
        "coriolis": lambda: mb.coriolis_matrix(model, q, v),
        "bias": lambda: mb.bias_forces(model, q, v),
        "jacobian": lambda: mb.jacobian(model, q, body),
        "rnea_derivatives": lambda: mb.inverse_dynamics_derivatives(model, q, v, a),
        "aba_derivatives": lambda: mb.forward_dynamics_derivatives(model, q, v, a),
    }[algorithm]


def theirs(pin, model, data, algorithm, q, v, a, frame):
    def jacobian():
        pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)

    return {
        "rnea": lambda: pin.rnea(model, data, q, v, a),
        "crba": lambda: pin.crba(model, data, q),
        "aba": lambda: pin.aba(model, data, q, v, a),
        "coriolis": lambda: pin.computeCoriolisMatrix(model, data, q, v),
        "bias": lambda: pin.nonLinearEffects(model, data, q, v),
        "jacobian": jacobian,
        "rnea_derivatives": lambda: pin.computeRNEADerivatives(model, data, q, v, a),
        "aba_derivatives": lambda: pin.computeABADerivatives(model, data, q, v, a),
    }[algorithm]


def rne_python_time(robot_name):
    """roboticstoolbox-python's pure-Python RNE on its own model of the robot, if installed (µs)."""
    try:
        import roboticstoolbox as rtb
    except ImportError:
        return None
    models = {"panda": "Panda", "ur5": "UR5"}
    if robot_name not in models:
        return None
    robot = getattr(rtb.models.DH, models[robot_name])()
    q = np.zeros(robot.n)
    return best_time(lambda: robot.rne_python(q, q, q)) * 1e6


def benchmark_robot(name, sizes, budget, rng):
    relative, floating, body = ROBOTS[name]
    root = example_robot_data()
    path = os.path.join(root, relative)
    model = load(path, floating)
    rows = []
    try:
        import pinocchio as pin
    except ImportError:
        pin = None
    if pin is not None:
        reference = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
        data = reference.createData()
        frame = reference.getFrameId(body)
    q1 = model.random_configuration(rng)
    v1, a1 = rng.standard_normal((2, model.nv))
    for algorithm in ALGORITHMS:
        row = {"robot": name, "algorithm": algorithm, "nv": model.nv}
        row["single_us"] = best_time(ours(model, algorithm, q1, v1, a1, body), budget) * 1e6
        for n in sizes:
            q = model.random_configuration(rng, (n,))
            v, a = rng.standard_normal((2, n, model.nv))
            row[f"batch_{n}_us_per_state"] = best_time(ours(model, algorithm, q, v, a, body), budget, min_runs=1) * 1e6 / n
        threads = mb.get_num_threads()
        if threads > 1:
            mb.set_num_threads(1)
            try:
                row["batch_1_thread_us_per_state"] = best_time(ours(model, algorithm, q, v, a, body), budget,
                                                               min_runs=1) * 1e6 / n
            finally:
                mb.set_num_threads(threads)
            row["thread_scaling"] = row[f"batch_{n}_us_per_state"] / row["batch_1_thread_us_per_state"]
        if pin is not None:
            q_pin = to_pinocchio_configuration(model, q1)
            row["pinocchio_us"] = best_time(theirs(pin, reference, data, algorithm, q_pin, v1, a1, frame), budget) * 1e6
            largest = max(sizes)
            row[f"ratio_batch_{largest}_vs_pinocchio"] = row[f"batch_{largest}_us_per_state"] / row["pinocchio_us"]
            row["ratio_single_vs_pinocchio"] = row["single_us"] / row["pinocchio_us"]
        rows.append(row)
    if "rnea" in ALGORITHMS:
        rows[0]["rne_python_us"] = rne_python_time(name)
    return rows


def crba_peak_memory(n, rng):
    """Peak memory (MB) traced by Python while computing the batched CRBA of the Panda for n states."""
    model = load(os.path.join(example_robot_data(), ROBOTS["panda"][0]))
    q = model.random_configuration(rng, (n,))
    tracemalloc.start()
    mb.mass_matrix(model, q)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 1e6


def rolling_ball(duration, rate, budget, adaptive=("DOP853", 1e-10)):
    """The rolling ball on a plane tilted by 0.1 rad: one constrained (KKT) step (µs), and the wall time
    (s) of simulating ``duration`` s with output at ``rate`` Hz, both by the adaptive ``(method, rtol)``
    (dense output between its own steps; best of three runs) and by fixed-step RK4 with step ``1/rate``; for each, the
    largest constraint residual of the output and the largest drift of the energy (J) from its start.
    """
    ball = mb.load_urdf(mb.robots.path("ball"), floating_base=True)
    system = mb.ConstrainedSystem(ball, [mb.RollingSphere("ball", 0.1, plane_normal=(np.sin(0.1), 0.0, np.cos(0.1)))])
    q0 = ball.neutral()
    q0[:3] = 0.1 * np.array([np.sin(0.1), 0.0, np.cos(0.1)])
    q0, v0 = system.project(q0, np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]))
    result = {"kkt_step_us": best_time(lambda: system.forward_dynamics(q0, v0), budget) * 1e6,
              "sim_duration_s": duration, "rate_hz": rate}
    method, rtol = adaptive
    # (runs, options): the best wall time of a few adaptive runs, as every other timing here is a
    # best time (a shared machine's noise only adds); one run of the minute-long RK4.
    runs = {"adaptive": (3, dict(method=method, rtol=rtol, atol=1e-2 * rtol)), "rk4": (1, dict(method="RK4"))}
    for name, (repeats, options) in runs.items():
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            trajectory = mb.simulate(system, q0, v0, duration, dt=1.0 / rate, **options)
            times.append(time.perf_counter() - start)
        result[f"{name}_simulate_s"] = min(times)
        result[f"{name}_max_residual"] = float(trajectory.residual.max())
        result[f"{name}_energy_drift_j"] = float(np.abs(trajectory.energy - trajectory.energy[0]).max())
    # one step of the variational integrator (its Newton solve; Lie-group form on the free flyer) against
    # one step of RK4, both through simulate at the same step, over at most the first second
    steps = max(10, int(rate * min(1.0, duration)))
    for name, options in (("variational", dict(method="variational")), ("rk4", dict(method="RK4"))):
        mb.simulate(system, q0, v0, 3.0 / rate, dt=1.0 / rate, **options)  # compiled (or loaded) before timing
        start = time.perf_counter()
        mb.simulate(system, q0, v0, steps / rate, dt=1.0 / rate, **options)
        result[f"{name}_step_us"] = (time.perf_counter() - start) / steps * 1e6
    result["adaptive_method"], result["adaptive_rtol"] = method, rtol
    result["max_residual"] = max(result["adaptive_max_residual"], result["rk4_max_residual"])
    return result


#: The Panda's joint-space PD of the controller benchmarks: gains stiff and damped enough to track, within RK4's
#: stability at 1 kHz for the fingers' small masses, towards the neutral pose + 0.3 rad (m for the fingers).
PD_GAINS = (50.0, 2.0)


def mujoco_panda(path, gains, rate):
    """MuJoCo's model of example-robot-data's Panda URDF (``MjModel`` from the file's text without its ``<visual>``
    and ``<collision>`` meshes: contacts are off) for the ODE that ``mb.simulate`` integrates: the PD as one affine
    actuator per joint (``τ = k_p ctrl − k_p q − k_d v`` with ``ctrl = q_ref``, so that ``mj_step``'s loop runs in C),
    joint damping (MuJoCo reads the URDF's; ``simulate`` applies it only with ``joint_damping=True``) set to zero,
    the URDF's effort limits on the actuators' force lifted, contacts, joint limits and the fingers' mimic equality
    disabled, RK4 with step ``1/rate``. ``None`` without MuJoCo."""
    try:
        import mujoco
    except ImportError:
        return None
    import re

    with open(path) as handle:
        text = handle.read()
    text = re.sub(r"<(visual|collision)>.*?</\1>", "", text, flags=re.S)
    spec = mujoco.MjSpec.from_string(text)
    kp, kd = gains
    for joint in spec.joints:
        actuator = spec.add_actuator()
        actuator.trntype, actuator.target = mujoco.mjtTrn.mjTRN_JOINT, joint.name
        actuator.gaintype, actuator.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        actuator.gainprm[0] = kp
        actuator.biasprm[:3] = (0.0, -kp, -kd)
    model = spec.compile()
    # (MuJoCo reads the URDF's effort limits as limits of the actuators' force at each joint; simulate applies none)
    model.jnt_actfrclimited[:] = 0
    model.dof_damping[:] = 0.0
    # (the fingers' URDF <mimic> is an equality constraint in MuJoCo; simulate's model keeps them independent)
    model.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                               | mujoco.mjtDisableBit.mjDSBL_EQUALITY)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    model.opt.timestep = 1.0 / rate
    return model


def panda_pd_loop(duration=3.0, rate=1000.0, repeats=5):
    """A Panda under the joint-space PD ``τ = K_p (q_ref − q) − K_d v`` for ``duration`` s by RK4 at ``rate`` Hz on
    one thread: the wall time (s, best of ``repeats`` interleaved rounds) of ``mb.simulate`` with ``mb.PD`` (the
    controller inside the compiled step), with the same law as a ``numba.njit`` function and as a Python callable;
    of the same RK4 loop written in Python on Pinocchio's ``aba`` (its final state must equal ours to 1e-10); and of
    MuJoCo's ``mj_step`` in C on the same ODE (:func:`mujoco_panda`), with the accelerations of both at a random
    state and the final states compared. Ratios: ours against MuJoCo's C loop (targets ≤ 0.5 with the PD, ≤ 0.6 with
    the njit controller) and the Python callable against the Pinocchio loop (≤ 1)."""
    import numba

    path = os.path.join(example_robot_data(), ROBOTS["panda"][0])
    model = load(path)
    q_ref = model.neutral() + 0.3
    kp, kd = PD_GAINS

    def controller(t, q, v):
        return kp * (q_ref - q) - kd * v

    @numba.njit
    def compiled(t, q, v, out):
        for c in range(q.shape[0]):
            out[c] = kp * (q_ref[c] - q[c]) - kd * v[c]

    q0, v0, dt = model.neutral(), np.zeros(model.nv), 1.0 / rate
    steps = int(round(duration * rate))
    runs = {"pd": mb.PD(kp, kd, q_ref), "njit": compiled, "python": controller}
    # the Pinocchio loop checks no joint limits (and the neutral pose is outside joint 4's): neither do these
    options = dict(dt=dt, method="RK4", limits="ignore")
    timings, finals = {name: [] for name in (*runs, "pinocchio", "mujoco")}, {}
    try:
        import pinocchio as pin
    except ImportError:
        pin = None
    if pin is not None:
        reference = pin.buildModelFromUrdf(path)
        data = reference.createData()

        def pinocchio_loop():
            def derivative(q, v):
                return v, pin.aba(reference, data, q, v, controller(0.0, q, v))

            q, v = q0.copy(), v0.copy()
            for _ in range(steps):
                k1q, k1v = derivative(q, v)
                k2q, k2v = derivative(q + 0.5 * dt * k1q, v + 0.5 * dt * k1v)
                k3q, k3v = derivative(q + 0.5 * dt * k2q, v + 0.5 * dt * k2v)
                k4q, k4v = derivative(q + dt * k3q, v + dt * k3v)
                q = q + dt / 6.0 * (k1q + 2.0 * k2q + 2.0 * k3q + k4q)
                v = v + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
            return q, v
    mujoco_model = mujoco_panda(path, PD_GAINS, rate)
    if mujoco_model is not None:
        import mujoco

        mujoco_data = mujoco.MjData(mujoco_model)

        def mujoco_loop():
            mujoco.mj_resetData(mujoco_model, mujoco_data)
            mujoco_data.qpos[:], mujoco_data.qvel[:], mujoco_data.ctrl[:] = q0, v0, q_ref
            mujoco.mj_step(mujoco_model, mujoco_data, nstep=steps)
            return mujoco_data.qpos.copy(), mujoco_data.qvel.copy()
    threads = mb.get_num_threads()
    mb.set_num_threads(1)
    try:
        for name, tau in runs.items():  # compiled (or loaded) before timing
            mb.simulate(model, q0, v0, 3 * dt, tau=tau, **options)
        for _ in range(repeats):
            for name, tau in runs.items():
                start = time.perf_counter()
                trajectory = mb.simulate(model, q0, v0, duration, tau=tau, **options)
                timings[name].append(time.perf_counter() - start)
                finals[name] = trajectory.q[-1], trajectory.v[-1]
            if pin is not None:
                start = time.perf_counter()
                finals["pinocchio"] = pinocchio_loop()
                timings["pinocchio"].append(time.perf_counter() - start)
            if mujoco_model is not None:
                start = time.perf_counter()
                finals["mujoco"] = mujoco_loop()
                timings["mujoco"].append(time.perf_counter() - start)
    finally:
        mb.set_num_threads(threads)
    result = {f"{name}_s": min(values) for name, values in timings.items() if values}
    q_pd, v_pd = finals["pd"]
    result["controllers_final_difference"] = float(max(
        np.abs(np.concatenate(finals[name]) - np.concatenate(finals["pd"])).max() for name in runs))
    if pin is not None:
        result["ratio"] = result["python_s"] / result["pinocchio_s"]
        result["final_state_difference"] = float(max(np.abs(finals["pinocchio"][0] - q_pd).max(),
                                                     np.abs(finals["pinocchio"][1] - v_pd).max()))
    if mujoco_model is not None:
        result["pd_vs_mujoco"] = result["pd_s"] / result["mujoco_s"]
        result["njit_vs_mujoco"] = result["njit_s"] / result["mujoco_s"]
        result["mujoco_final_difference"] = float(max(np.abs(finals["mujoco"][0] - q_pd).max(),
                                                      np.abs(finals["mujoco"][1] - v_pd).max()))
        # the same ODE: MuJoCo's accelerations (the actuators' forces included) against ours at a random state
        state = model.random_configuration(np.random.default_rng(5)), np.random.default_rng(6).standard_normal(model.nv)
        mujoco.mj_resetData(mujoco_model, mujoco_data)
        mujoco_data.qpos[:], mujoco_data.qvel[:], mujoco_data.ctrl[:] = state[0], state[1], q_ref
        mujoco.mj_forward(mujoco_model, mujoco_data)
        ours = mb.forward_dynamics(model, *state, controller(0.0, *state))
        result["mujoco_acceleration_difference"] = float(np.abs(mujoco_data.qacc - ours).max())
    return result


def panda_pd_lines(pd, duration):
    """The benchmark lines of :func:`panda_pd_loop`'s result ``pd``."""
    nan = float("nan")
    return [
        f"Panda with a PD controller, {duration:g} s by RK4 at 1 kHz, one thread: mb.simulate with mb.PD "
        f"{pd['pd_s'] * 1e3:.1f} ms, with a numba.njit controller {pd['njit_s'] * 1e3:.1f} ms, with a Python callable "
        f"{pd['python_s'] * 1e3:.1f} ms (final states of the three agree to {pd['controllers_final_difference']:.1e})",
        f"  against MuJoCo's RK4 mj_step loop in C on the same ODE {pd.get('mujoco_s', nan) * 1e3:.1f} ms: mb.PD "
        f"{pd.get('pd_vs_mujoco', nan):.2f}× (target ≤ 0.5), njit {pd.get('njit_vs_mujoco', nan):.2f}× (target ≤ 0.6); "
        f"accelerations agree to {pd.get('mujoco_acceleration_difference', nan):.1e}, final states to "
        f"{pd.get('mujoco_final_difference', nan):.1e}",
        f"  against the same RK4 loop in Python on Pinocchio {pd.get('pinocchio_s', nan) * 1e3:.1f} ms: the Python "
        f"callable {pd.get('ratio', nan):.2f}× (target ≤ 1.0); final states differ by "
        f"{pd.get('final_state_difference', nan):.1e} (required ≤ 1e-10)",
    ]


def batched_pd_line(n=4096, duration=1.0, rate=1000.0, repeats=2):
    """The benchmark line of ``n`` Panda trajectories under the PD of :func:`panda_pd_loop` (random starts within
    0.3 of the neutral pose, at rest) for ``duration`` s by RK4 at ``rate`` Hz on every thread: one ``mb.simulate``
    call with ``mb.PD`` against ``mujoco.rollout`` of :func:`mujoco_panda` with one ``MjData`` per thread, each
    its wall time (best of ``repeats``) per trajectory-step, and the largest difference of their final states."""
    path = os.path.join(example_robot_data(), ROBOTS["panda"][0])
    model = load(path)
    q_ref = model.neutral() + 0.3
    rng = np.random.default_rng(7)
    q0 = model.neutral() + rng.uniform(-0.3, 0.3, (n, model.nq))
    v0 = np.zeros((n, model.nv))
    steps = int(round(duration * rate))
    tau = mb.PD(*PD_GAINS, q_ref)
    options = dict(dt=1.0 / rate, method="RK4", tau=tau, limits="ignore")
    mb.simulate(model, q0[:2], v0[:2], 3.0 / rate, **options)  # compiled (or loaded) before timing
    ours = []
    for _ in range(repeats):
        start = time.perf_counter()
        trajectory = mb.simulate(model, q0, v0, duration, **options)
        ours.append((time.perf_counter() - start) / (n * steps))
    threads = mb.get_num_threads()
    line = (f"batched PD, {n} Panda trajectories for {duration:g} s by RK4 at {rate:g} Hz on {threads} threads: "
            f"mb.simulate {min(ours) * 1e6:.2f} µs per trajectory-step ({int(trajectory.completed.sum())} of {n} "
            "completed)")
    mujoco_model = mujoco_panda(path, PD_GAINS, rate)
    if mujoco_model is None:
        return line + "; MuJoCo not installed"
    import mujoco
    from mujoco import rollout

    datas = [mujoco.MjData(mujoco_model) for _ in range(threads)]
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.zeros((n, mujoco.mj_stateSize(mujoco_model, full)))
    for r in range(n):
        mujoco.mj_resetData(mujoco_model, datas[0])
        datas[0].qpos[:], datas[0].qvel[:] = q0[r], v0[r]
        mujoco.mj_getState(mujoco_model, datas[0], initial[r], full)
    control = np.broadcast_to(q_ref, (1, 1, mujoco_model.nu))
    theirs = []
    for _ in range(repeats):
        start = time.perf_counter()
        states, _ = rollout.rollout(mujoco_model, datas, initial, control, nstep=steps)
        theirs.append((time.perf_counter() - start) / (n * steps))
    # the state's layout: time, qpos, qvel, ...
    final = states[:, -1, 1 : 1 + model.nq]
    difference = float(np.abs(final - trajectory.q[:, -1]).max())
    return (line + f"; mujoco.rollout {min(theirs) * 1e6:.2f} µs per trajectory-step; ratio "
            f"{min(ours) / min(theirs):.2f}; final positions agree to {difference:.1e}")


def inverse_kinematics_line(n=1000, poses=20):
    """The benchmark line of ``mb.inverse_kinematics`` on Panda hand poses, the forward kinematics of random
    configurations within the joint limits, solved to 1e-10 from the default start: the median over
    ``poses`` poses of one pose's time, and the time per pose of a batch of ``n``."""
    model = load(os.path.join(example_robot_data(), ROBOTS["panda"][0]))
    frame = "panda_hand_tcp"
    targets = mb.frame_placement(model, model.random_configuration(np.random.default_rng(1), (n,)), frame)
    single = np.median([best_time(lambda X=X: mb.inverse_kinematics(model, {frame: X}), 0.05) for X in targets[:poses]])
    batch = best_time(lambda: mb.inverse_kinematics(model, {frame: targets}), 0.5, min_runs=3)
    converged = int(mb.inverse_kinematics(model, {frame: targets}).converged.sum())
    return (f"inverse kinematics, Panda: one pose {single * 1e3:.2f} ms (median of {poses}), {n} poses "
            f"{batch / n * 1e6:.1f} µs/pose ({converged} of {n} converged)")


def closed_chain_line(cells=40, budget=0.5):
    """The benchmark line of one constrained evaluation of a large closed chain: the ``cells`` parallelograms
    of the singular-passage tests (``tests/test_singular_chains.py``: ``2 cells + 1`` bars, ``2 cells``
    planar closure rows), moving 1e-6 rad from their flat configuration, where the rows are nearly
    dependent; ``ConstrainedSystem.forward_dynamics`` is one compiled call (CRBA, RNEA, the rows, the
    Cholesky factor of ``M`` and the one-sided Jacobi SVD of ``A L⁻ᵀ``). The mechanism is built by the
    tests' helpers (``tests/constraint_helpers.py``, which need no test runner)."""
    tests = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")
    if tests not in sys.path:
        sys.path.insert(0, tests)
    from constraint_helpers import crank_state, parallelogram_chain, planar_closures
    model = parallelogram_chain(cells)
    system = mb.ConstrainedSystem(model, planar_closures(cells))
    q, v = crank_state(cells, 1e-6, 3.0)
    step = best_time(lambda: system.forward_dynamics(q, v), budget)
    return (f"closed chain of {cells} parallelograms ({model.nv} bars, {system.num_rows} rows), 1e-6 rad from flat: "
            f"one constrained evaluation {step * 1e3:.2f} ms")


def batched_rk4_line(n=4096, duration=1.0, rate=1000.0, budget=0.5):
    """The benchmark line of batched RK4: ``n`` double-pendulum and Panda trajectories (random configurations,
    small random velocities, no joint forces) for ``duration`` s at ``rate`` Hz by one ``mb.simulate`` call
    each, its wall time per trajectory-step against the per-state time of one batched forward-dynamics call
    on ``n`` states. RK4 evaluates the dynamics four times a step, so the ratio is at least 4."""
    rng = np.random.default_rng(2)
    parts = []
    for name in ("double_pendulum", "panda"):
        model = load(os.path.join(example_robot_data(), ROBOTS[name][0]))
        q0, v0 = model.random_configuration(rng, (n,)), 0.1 * rng.standard_normal((n, model.nv))
        tau = np.zeros(model.nv)
        per_state = best_time(lambda: mb.forward_dynamics(model, q0, v0, tau), budget) / n
        steps = int(round(duration * rate))
        start = time.perf_counter()
        trajectory = mb.simulate(model, q0, v0, duration, dt=1.0 / rate, method="RK4", limits="ignore")
        step = (time.perf_counter() - start) / (n * steps)
        parts.append(f"{name} {step * 1e6:.2f} µs per trajectory-step, {step / per_state:.1f}× the "
                     f"{per_state * 1e6:.2f} µs/state of forward dynamics ({int(trajectory.completed.sum())} of {n} "
                     "completed)")
    return f"batched RK4, {n} trajectories for {duration:g} s at {rate:g} Hz (outputs included): " + "; ".join(parts)


def dask_line(chunk=100_000, chunks=4, budget=1.0):
    """The benchmark line of ``mb.distributed.map_states`` on a ``LocalCluster`` of two worker processes (one
    thread each): Panda forward dynamics and mass matrices of ``chunks`` chunks of ``chunk`` states, the time
    per state against the same batch in this process (every thread), and the difference as a share of it."""
    try:
        import distributed
    except ImportError:
        return "Dask: not installed (pip install 'multibody[dask]')"
    model = load(os.path.join(example_robot_data(), ROBOTS["panda"][0]))
    rng = np.random.default_rng(3)
    n = chunk * chunks
    q = model.random_configuration(rng, (n,))
    v, tau = rng.standard_normal((n, model.nv)), rng.standard_normal((n, model.nv))
    parts = []
    cases = (("forward dynamics", mb.forward_dynamics, (q, v, tau)), ("CRBA", mb.mass_matrix, (q,)))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        for name, fn, arrays in cases:
            here = best_time(lambda: fn(model, *arrays), budget, min_runs=2) / n
            there = best_time(lambda: mb.distributed.map_states(fn, model, *arrays, chunks=chunk, client=client),
                              budget, min_runs=2) / n
            parts.append(f"{name} {there * 1e6:.2f} µs/state against {here * 1e6:.2f} in one process "
                         f"(overhead {(there - here) / here:+.0%})")
    return f"Dask, 2 local worker processes, {chunks} chunks of {chunk} Panda states: " + "; ".join(parts)


def gpu_lines(n=1_000_000, trajectories=65536, duration=0.1, rate=1000.0, budget=1.0):
    """The benchmark lines of the GPU (:mod:`multibody.gpu`), or one line saying why there are none.

    Panda float64: RNEA, CRBA and ABA in states per second on ``n`` states already on the device (synchronised; the
    first, compiling call not timed), beside the same batch of host arrays on every CPU thread; and ``trajectories``
    batched RK4 trajectories under the PD of :func:`panda_pd_loop` for ``duration`` s at ``rate`` Hz from device
    arrays, in trajectory-steps per second: ``mb.simulate`` end to end (the copies to and from the device and the
    outputs' energies on the host included), the device run alone (the launch of :func:`multibody.gpu.launch`,
    synchronised) and the CPU's batched ``mb.simulate`` on every thread, with the largest difference of their
    final positions."""
    try:
        from numba import cuda
    except ImportError:
        return ["GPU: numba.cuda not installed (pip install 'multibody[gpu]'); nothing measured on a GPU"]
    if not cuda.is_available():
        return ["GPU: no CUDA device found (numba.cuda.is_available() is False); RNEA, CRBA, ABA and batched RK4 "
                "not measured on a GPU"]
    from multibody import gpu

    model = load(os.path.join(example_robot_data(), ROBOTS["panda"][0]))
    rng = np.random.default_rng(4)
    host = (model.random_configuration(rng, (n,)), rng.standard_normal((n, model.nv)), rng.standard_normal((n, model.nv)))
    device = [cuda.to_device(x) for x in host]
    threads = mb.get_num_threads()
    parts = []
    for name, fn, count in (("RNEA", mb.inverse_dynamics, 3), ("CRBA", mb.mass_matrix, 1),
                            ("ABA", mb.forward_dynamics, 3)):
        fn(model, *device[:count])
        cuda.synchronize()

        def run():
            fn(model, *device[:count])
            cuda.synchronize()
        on_gpu = n / best_time(run, budget)
        on_cpu = n / best_time(lambda: fn(model, *host[:count]), budget)
        parts.append(f"{name} {on_gpu:.3g} states/s (CPU {on_cpu:.3g}, {on_gpu / on_cpu:.3g}×)")
    device_name = getattr(cuda.current_context().device, "name", "the CUDA simulator")
    device_name = device_name.decode() if isinstance(device_name, bytes) else device_name
    lines = [f"GPU ({device_name}), Panda float64 at batch {n:.0e}, CPU on {threads} threads beside: " + "; ".join(parts)]

    q_ref = model.neutral() + 0.3
    q0 = model.neutral() + rng.uniform(-0.3, 0.3, (trajectories, model.nq))
    v0 = np.zeros((trajectories, model.nv))
    steps = int(round(duration * rate))
    options = dict(dt=1.0 / rate, method="RK4", tau=mb.PD(*PD_GAINS, q_ref), limits="ignore", progress=False)
    launch, launched = gpu.launch, []

    def timed_launch(*args):
        cuda.synchronize()
        start = time.perf_counter()
        launch(*args)
        cuda.synchronize()
        launched.append(time.perf_counter() - start)

    gpu.launch = timed_launch  # (simulate's device run calls multibody.gpu.launch)
    try:
        try:
            mb.simulate(model, cuda.to_device(q0[:2]), cuda.to_device(v0[:2]), 3.0 / rate, **options)  # compiles
        except Exception as error:  # e.g. Numba's built-in CUDA target, which the kernels' max() defeats
            return lines + [f"batched RK4 on the GPU: the run did not compile or launch ({type(error).__name__}: "
                            f"{str(error)[:200]}); the [gpu] extra's numba-cuda compiles it"]
        launched.clear()
        start = time.perf_counter()
        on_device = mb.simulate(model, cuda.to_device(q0), cuda.to_device(v0), duration, **options)
        end_to_end = time.perf_counter() - start
    finally:
        gpu.launch = launch
    start = time.perf_counter()
    on_host = mb.simulate(model, q0, v0, duration, **options)
    cpu = time.perf_counter() - start
    work = trajectories * steps
    difference = float(np.nanmax(np.abs(on_device.q[:, -1] - on_host.q[:, -1])))
    lines.append(f"GPU batched RK4, {trajectories} Panda trajectories under mb.PD for {duration:g} s at {rate:g} Hz, "
                 f"float64: mb.simulate from device arrays {work / end_to_end:.3g} trajectory-steps/s end to end, the "
                 f"device run alone {work / sum(launched):.3g}; CPU mb.simulate on {threads} threads "
                 f"{work / cpu:.3g} ({cpu / sum(launched):.3g}× for the device run); final positions "
                 f"agree to {difference:.1e} ({int(on_device.completed.sum())} of {trajectories} completed)")
    return lines


def mjcf_load_line(budget=0.5):
    """The benchmark line of ``mb.load_mjcf`` on gymnasium's humanoid against MuJoCo's ``MjModel.from_xml_path``
    on the same file (each the fastest of repeated loads, interleaved in rounds so that both meet the same
    load on a shared machine), and their ratio (target ≤ 2)."""
    import importlib.util
    import warnings

    spec = importlib.util.find_spec("gymnasium")
    try:
        import mujoco
    except ImportError:
        return "MJCF loading: MuJoCo not installed (pip install mujoco)"
    if spec is None:
        return "MJCF loading: gymnasium not installed (its models are the benchmark's)"
    path = os.path.join(os.path.dirname(spec.origin), "envs", "mujoco", "assets", "humanoid.xml")
    ours, theirs = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (actuators, tendons and springs that the model leaves out)
        for _ in range(5):
            ours.append(best_time(lambda: mb.load_mjcf(path), budget / 10))
            theirs.append(best_time(lambda: mujoco.MjModel.from_xml_path(path), budget / 10))
    return (f"loading gymnasium's humanoid.xml: mb.load_mjcf {min(ours) * 1e3:.2f} ms, MuJoCo's "
            f"MjModel.from_xml_path {min(theirs) * 1e3:.2f} ms (ratio {min(ours) / min(theirs):.2f}; target ≤ 2)")


def markdown(rows, sizes):
    largest = max(sizes)
    header = ["robot", "algorithm", "nv", "single µs"] + [f"N={n} µs/state" for n in sizes] + \
        [f"N={largest}, 1 thread", "pin µs/call", f"N={largest} / pin", "single / pin"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [row["robot"], row["algorithm"], str(row["nv"]), f"{row['single_us']:.0f}"]
        cells += [f"{row[f'batch_{n}_us_per_state']:.2f}" for n in sizes]
        cells += [f"{row.get('batch_1_thread_us_per_state', float('nan')):.2f}",
                  f"{row.get('pinocchio_us', float('nan')):.2f}",
                  f"{row.get(f'ratio_batch_{largest}_vs_pinocchio', float('nan')):.2f}",
                  f"{row.get('ratio_single_vs_pinocchio', float('nan')):.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="*", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument("--sizes", nargs="*", type=int, default=[1, 64, 1024, 4096])
    parser.add_argument("--budget", type=float, default=0.5, help="seconds of repetitions per measurement")
    parser.add_argument("--memory-states", type=int, default=16384)
    parser.add_argument("--sim-duration", type=float, default=10.0)
    parser.add_argument("--quick", action="store_true", help="tiny sizes and budgets (a smoke run)")
    parser.add_argument("--gpu", action="store_true", help="print the GPU lines alone (gpu_lines), nothing saved")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results"))
    args = parser.parse_args(argv)
    if args.quick:
        args.sizes, args.budget, args.memory_states, args.sim_duration = [1, 8], 0.01, 64, 0.05
        args.robots = args.robots[:1]
    if example_robot_data() is None:
        print("example-robot-data is not installed: pip install example-robot-data", file=sys.stderr)
        return 2
    if args.gpu:
        print("\n".join(gpu_lines(1000 if args.quick else 1_000_000, 64 if args.quick else 65536,
                                   0.005 if args.quick else 0.1, budget=0.01 if args.quick else 1.0)))
        return 0
    rng = np.random.default_rng(0)
    rows = [row for name in args.robots for row in benchmark_robot(name, args.sizes, args.budget, rng)]
    table = markdown(rows, args.sizes)
    memory = crba_peak_memory(args.memory_states, rng)
    ball = rolling_ball(args.sim_duration, 1000.0, args.budget)
    pd_duration = 3.0 if not args.quick else 0.01
    pd = panda_pd_loop(pd_duration, repeats=5 if not args.quick else 1)
    rne = {row["robot"]: row.get("rne_python_us") for row in rows if row["algorithm"] == "rnea"}
    extra = [
        f"peak memory of the batched Panda CRBA at N = {args.memory_states}: {memory:.0f} MB",
        f"rolling ball: one constrained step {ball['kkt_step_us']:.0f} µs; simulating {ball['sim_duration_s']:g} s "
        f"with 1 kHz output: {ball['adaptive_method']} (rtol {ball['adaptive_rtol']:g}, dense output) "
        f"{ball['adaptive_simulate_s']:.2f} s wall, best of 3 (max residual {ball['adaptive_max_residual']:.1e}, "
        f"energy drift {ball['adaptive_energy_drift_j']:.1e} J); fixed-step RK4 at 1 kHz "
        f"{ball['rk4_simulate_s']:.2f} s wall (max residual {ball['rk4_max_residual']:.1e}, "
        f"energy drift {ball['rk4_energy_drift_j']:.1e} J)",
        f"rolling ball, one step through simulate at 1 kHz: variational {ball['variational_step_us']:.0f} µs, "
        f"RK4 {ball['rk4_step_us']:.0f} µs ({ball['variational_step_us'] / ball['rk4_step_us']:.1f}×; target ≤ 3×)",
        *panda_pd_lines(pd, pd_duration),
        inverse_kinematics_line(16 if args.quick else 1000, 2 if args.quick else 20),
        closed_chain_line(4 if args.quick else 40, 0.01 if args.quick else args.budget),
        batched_rk4_line(64 if args.quick else 4096, 0.005 if args.quick else 1.0),
        batched_pd_line(64 if args.quick else 4096, 0.005 if args.quick else 1.0, repeats=1 if args.quick else 2),
        dask_line(1000 if args.quick else 100_000, 2 if args.quick else 4, 0.01 if args.quick else 1.0),
        *gpu_lines(1000 if args.quick else 1_000_000, 64 if args.quick else 65536, 0.005 if args.quick else 0.1,
                   budget=0.01 if args.quick else 1.0),
        mjcf_load_line(0.05 if args.quick else args.budget),
        f"threads: {mb.get_num_threads()}",
        "roboticstoolbox rne_python (µs): " + ", ".join(
            f"{k}: {'not installed / no model' if t is None else f'{t:.0f}'}" for k, t in rne.items()),
    ]
    print(table)
    print()
    print("\n".join(extra))
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "results.json"), "w") as handle:
        json.dump({"rows": rows, "crba_peak_memory_mb": memory, "rolling_ball": ball, "panda_pd": pd, "sizes": args.sizes,
                   "threads": mb.get_num_threads()}, handle, indent=1)
    with open(os.path.join(args.out, "results.md"), "w") as handle:
        handle.write(table + "\n\n" + "\n".join(f"- {line}" for line in extra) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
