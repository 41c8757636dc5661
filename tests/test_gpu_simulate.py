"""``mb.simulate`` on CUDA arrays (:func:`multibody.gpu.advance_batch`), with no GPU.

* Under Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, in a subprocess so that the rest of the suite keeps
  the real ``numba.cuda``): a batch simulated from device arrays ``q0``, ``v0`` equals the CPU's batched run to
  1e-12 in every array of the ``Trajectory`` (``q``, ``v``, ``λ``, energy, residual, statuses), for Panda under RK4
  and ``mb.PD`` (gains and references per trajectory, URDF joint damping), a four-bar linkage closed by a built-in
  loop closure under semi-implicit Euler and a ``numba.njit`` controller, and a double pendulum under explicit Euler
  with constant joint forces and with a compiled controller that stops one trajectory; parallelogram chains whose
  steps near their flat configuration the device run leaves to the host; also with two threads for
  five trajectories, and for an empty batch. Each device run takes its steps in one launch of the GPU run (counted)
  and none in the CPU's compiled run. The simulator runs the launcher as Python, one thread per trajectory, and the
  arithmetic as the CPU's compiled ``advance``: this checks the launch (rows, threads, workspaces, transfers) and
  the routing. What the GPU path does not run (a Python callable, adaptive and variational methods, user
  constraints, one state) raises ``ValueError`` saying so.
* (The run's launcher lowering to PTX for the CUDA target is in ``test_cuda_target.py``.)
"""

from __future__ import annotations

import textwrap

import pytest

from test_gpu import run_python

SIMULATED = textwrap.dedent(r"""
    import os, sys, warnings
    os.environ["NUMBA_ENABLE_CUDASIM"] = "1"
    sys.path.insert(0, TESTS)
    import numba
    import numpy as np
    from numba import config, cuda
    import multibody as mb
    from multibody import gpu
    from multibody.integrators import CompiledRun
    assert config.ENABLE_CUDASIM

    # count the device runs and the CPU's compiled runs
    calls = {"device": 0, "cpu": 0}
    device_run, cpu_run = gpu.advance_batch, CompiledRun.advance_batch
    def counted_device(*args):
        calls["device"] += 1
        return device_run(*args)
    def counted_cpu(self, *args, **kwargs):
        calls["cpu"] += 1
        return cpu_run(self, *args, **kwargs)
    gpu.advance_batch, CompiledRun.advance_batch = counted_device, counted_cpu

    def same(system, q0, v0, t_final, handed=False, **options):
        # the run from device arrays against the CPU's; handed: the device run leaves steps to the host
        calls.update(device=0, cpu=0)
        device = mb.simulate(system, *(cuda.to_device(np.ascontiguousarray(x)) for x in (q0, v0)), t_final, **options)
        assert calls["device"] == 1 and (calls["cpu"] >= 1 if handed else calls["cpu"] == 0), calls
        host = mb.simulate(system, q0, v0, t_final, **options)
        assert calls["cpu"] >= 1 or not len(q0), calls
        assert type(device.q) is np.ndarray and device.q.shape == host.q.shape, (type(device.q), device.q.shape)
        assert device.status == host.status, (device.status, host.status)
        for name in ("t", "q", "v", "lam", "energy", "residual"):
            a, b = getattr(device, name), getattr(host, name)
            assert a.shape == b.shape, (name, a.shape, b.shape)
            scale = max(1.0, float(np.nanmax(np.abs(b)))) if b.size else 1.0
            err = float(np.nanmax(np.abs(a - b))) if a.size else 0.0
            assert np.array_equal(np.isnan(a), np.isnan(b)) and err <= 1e-12 * scale, (name, err)
        return device

    rng = np.random.default_rng(5)
    # Panda, RK4, a PD law with gains and references per trajectory, and the URDF's joint damping
    panda = mb.robots.load("panda")
    n = 3
    q0 = panda.random_configuration(rng, (n,))
    v0 = 0.1 * rng.standard_normal((n, panda.nv))
    pd = mb.PD(kp=50.0 + 10.0 * rng.random((n, panda.nv)), kd=5.0, q_ref=panda.random_configuration(rng, (n,)))
    run = same(panda, q0, v0, 0.004, dt=0.001, method="RK4", tau=pd, joint_damping=True, limits="ignore")
    assert run.q.shape == (n, 5, panda.nq) and all(run.completed), run.status
    print("PANDA-PD-OK")

    # a four-bar linkage closed by a built-in loop closure, semi-implicit Euler, a numba.njit controller
    model = mb.robots.load("four_bar")
    in_plane = mb.spatial.pose_from_xyz_rpy(rpy=(np.pi / 2, 0.0, 0.0))
    four_bar = mb.ConstrainedSystem(model, [mb.LoopClosure("coupler_tip", "rocker_tip", frame_a=in_plane,
                                                           kind="planar")])
    guess = np.array([-np.pi / 3, 0.9, -1.4]) + 0.05 * rng.standard_normal((4, 3))
    q0, v0 = four_bar.project(guess, rng.standard_normal((4, 3)))

    @numba.njit
    def spring(t, q, v, out):
        for c in range(out.shape[0]):
            out[c] = -2.0 * (q[c] + 0.5) - 0.3 * v[c] + np.sin(3.0 * t)

    run = same(four_bar, q0, v0, 0.05, dt=0.01, method="semi-implicit Euler", tau=spring)
    assert run.lam.shape == (4, 6, 2) and np.all(np.isfinite(run.lam)) and all(run.completed), run.status
    print("FOUR-BAR-NJIT-OK")

    # two-cell parallelogram chains, one far from its flat configuration, two near it: the steps that start near flat
    # run on the host, and those trajectories' steps after them
    from constraint_helpers import crank_state, parallelogram_chain, planar_closures
    chain = mb.ConstrainedSystem(parallelogram_chain(2), planar_closures(2))
    q0, v0 = (np.array(x) for x in zip(*[crank_state(2, angle, rate) for angle, rate in ((0.5, 0.0), (0.05, -1.0),
                                                                                        (0.01, 2.0))]))
    run = same(chain, q0, v0, 0.2, handed=True, dt=0.01, method="RK4")
    assert all(run.completed), run.status
    print("PARALLELOGRAMS-OK")

    # a double pendulum, explicit Euler: constant joint forces per trajectory (a device array), one initial velocity
    # (a host array) for all; then a numba.njit controller whose joint forces are NaN past q[0] = 1.5, which stops
    # trajectory 2 alone with the CPU's status
    pendulum = mb.robots.load("double_pendulum")
    q0 = np.clip(0.3 * rng.standard_normal((5, 2)), -1.0, 1.0)
    v0 = rng.standard_normal(2)
    calls.update(device=0, cpu=0)
    tau = rng.standard_normal((5, 2))
    device = mb.simulate(pendulum, cuda.to_device(q0), v0, 0.03, dt=0.01, method="Euler", tau=cuda.to_device(tau),
                         limits="ignore")
    assert calls == {"device": 1, "cpu": 0}, calls
    host = mb.simulate(pendulum, q0, v0, 0.03, dt=0.01, method="Euler", tau=tau, limits="ignore")
    assert np.array_equal(device.q, host.q) and np.array_equal(device.v, host.v)
    same(pendulum, q0, np.broadcast_to(v0, (5, 2)).copy(), 0.03, dt=0.01, method="Euler",
         tau=rng.standard_normal((5, 2)), limits="ignore")

    @numba.njit
    def fails_past(t, q, v, out):
        out[0] = np.nan if q[0] > 1.5 else -q[0]

    q0[2, 0] = 2.0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = same(pendulum, q0, np.zeros((5, 2)), 0.03, dt=0.01, method="Euler", tau=fails_past, limits="ignore")
    assert list(run.completed) == [True, True, False, True, True] and "joint forces" in run.status[2], run.status
    assert sum("1 of 5 trajectories stopped early" in str(w.message) for w in caught) == 2, caught
    print("PENDULUM-EULER-OK")

    # two threads for five trajectories (each thread runs several, in its one workspace row), and an empty batch
    limits = gpu.MAX_THREADS, gpu.THREADS_PER_BLOCK
    gpu.MAX_THREADS = gpu.THREADS_PER_BLOCK = 2
    try:
        same(pendulum, q0, np.zeros((5, 2)), 0.03, dt=0.01, method="RK4", tau=rng.standard_normal((5, 2)),
             limits="ignore")
    finally:
        gpu.MAX_THREADS, gpu.THREADS_PER_BLOCK = limits
    empty = same(pendulum, np.zeros((0, 2)), np.zeros((0, 2)), 0.03, dt=0.01, method="RK4")
    assert empty.q.shape == (0, 4, 2), empty.q.shape
    print("THREADS-OK")

    # what the GPU does not run
    dq, dv = cuda.to_device(np.zeros((2, 2))), cuda.to_device(np.zeros((2, 2)))
    refused = [
        (dict(method="RK4", tau=lambda t, q, v: np.zeros((2, 2))), "a Python callable runs on the host"),
        (dict(method="RK45"), "method='RK45' is not one"),
        (dict(method="variational", dt=0.01), "method='variational' is not one"),
    ]
    for options, words in refused:
        try:
            mb.simulate(pendulum, dq, dv, 0.1, **options)
        except ValueError as error:
            assert words in str(error) and "CUDA arrays" in str(error), error
        else:
            raise AssertionError(f"{options} ran on the GPU")
    ball = mb.robots.load("double_pendulum")
    user = mb.ConstrainedSystem(ball, [mb.Holonomic(lambda q, t: q[:1] - 0.1, name="pinned")])
    for system, q, v, words in ((user, dq, dv, "user constraints"),
                                (pendulum, cuda.to_device(np.zeros(2)), cuda.to_device(np.zeros(2)), "got one state")):
        try:
            mb.simulate(system, q, v, 0.1, method="RK4")
        except ValueError as error:
            assert words in str(error) and "CUDA arrays" in str(error), error
        else:
            raise AssertionError(f"{words}: ran on the GPU")
    print("GPU-SIMULATE-OK")
""")


def test_simulate_on_device_arrays_equals_the_cpu_batch_under_the_cuda_simulator():
    result = run_python(SIMULATED, {"NUMBA_ENABLE_CUDASIM": "1"}, timeout=900)
    if "No module named 'numba.cuda" in result.stderr:
        pytest.skip("numba.cuda is not installed")
    assert "GPU-SIMULATE-OK" in result.stdout, result.stdout + result.stderr


CONTACT_SIMULATED = textwrap.dedent(r"""
    import os, sys
    os.environ["NUMBA_ENABLE_CUDASIM"] = "1"
    sys.path.insert(0, TESTS)
    import numba
    import numpy as np
    from numba import config, cuda
    import multibody as mb
    from multibody import gpu
    from test_contact import ball_model, box_model
    assert config.ENABLE_CUDASIM

    launches = []
    device_batch = gpu.contact_batch
    def counted(*args):
        launches.append(args[4].shape[0])
        return device_batch(*args)
    gpu.contact_batch = counted

    def same(system, q0, v0, t_final, **options):
        launches.clear()
        device = mb.simulate(system, *(cuda.to_device(np.ascontiguousarray(x)) for x in (q0, v0)), t_final, **options)
        assert launches and launches[0] == len(q0), launches  # (then the trajectories whose records widen)
        count = len(launches)
        host = mb.simulate(system, q0, v0, t_final, **options)
        assert len(launches) == count, launches
        assert device.status == host.status, (device.status, host.status)
        assert device.contacts == host.contacts
        for name in ("t", "q", "v", "energy", "complementarity"):
            a, b = getattr(device, name), getattr(host, name)
            assert type(a) is np.ndarray and a.shape == b.shape, (name, a.shape, b.shape)
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, err_msg=name)

    ball = mb.ConstrainedSystem(ball_model(), [mb.Ground(friction=0.4, restitution=0.5)])
    q0 = np.array([[0.1 * r, 0, 0.2 + 0.1 * r, 0, 0, 0, 1] for r in range(3)])
    v0 = np.array([[0.3 * r, -0.2, 0, 0, 10.0 * r, -r] for r in range(3)], dtype=float)
    same(ball, q0, v0, 0.25, dt=1e-3)

    box = mb.ConstrainedSystem(box_model(), [mb.Ground(friction=0.5)])
    q0 = np.array([[0, 0, 0.05, 0, 0, 0, 1]] * 2, dtype=float)
    pushes = np.array([[2.0, 0, 0, 0, 0, 0], [4.0, 0, 0, 0, 0, 0]])
    same(box, q0, np.zeros((2, 6)), 0.1, dt=1e-3, tau=pushes)

    @numba.njit
    def push(t, q, v, out):
        out[0] = 3.0 * (1.0 + t)

    same(box, q0, np.zeros((2, 6)), 0.1, dt=1e-3, tau=push)
    print("GPU-CONTACT-OK")
""")


def test_contact_simulate_on_device_arrays_equals_the_cpu_batch_under_the_cuda_simulator():
    """A contact batch (Moreau–Jean steps) simulated from device arrays runs in one launch of the contact run, one
    trajectory per thread, and equals the CPU's batch to 1e-12 in every array and status: a ball bouncing and
    spinning on the ground, a box pushed with joint forces per trajectory and with a ``numba.njit`` controller."""
    result = run_python(CONTACT_SIMULATED, {"NUMBA_ENABLE_CUDASIM": "1"}, timeout=900)
    if "No module named 'numba.cuda" in result.stderr:
        pytest.skip("numba.cuda is not installed")
    assert "GPU-CONTACT-OK" in result.stdout, result.stdout + result.stderr
