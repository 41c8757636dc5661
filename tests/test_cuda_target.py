"""The kernels lower to PTX for sm_90 with Numba's built-in CUDA target (``numba.cuda.compile_ptx``, through libNVVM,
no device needed), all in one subprocess so that the suite pays Numba's CUDA compilation of the shared helpers once:

* the launchers of :mod:`multibody.gpu` for the dynamics kernels (RNEA, CRBA, ABA, inverse mass matrix, Coriolis,
  frame Jacobian, kinetic energy, ABA derivatives);
* contact detection (:func:`~multibody.kernels.collision.halfspace_contacts`,
  :func:`~multibody.kernels.collision.pair_contacts`, every shape's branch);
* the contact solver (:func:`multibody.kernels.complementarity.solve`);
* the contact step's own functions (detection of a plan's items, contact rows, the offsets, the warm start, the
  position correction with its solve) and the whole contact run :func:`multibody.kernels.timestepping.run`, one
  trajectory per thread with a ``numba.njit`` controller as a device function;
* the whole fixed-step run, :func:`multibody.gpu.run_source` launching :func:`multibody.kernels.stepping.advance`
  with a ``numba.njit`` controller.

Skipped where libNVVM (the CUDA toolkit) or ``numba.cuda`` is not found, and unless ``MULTIBODY_TEST_PTX=1``: the
CUDA compilation of all of it takes about 20 minutes of one core on a loaded two-core machine, longer than the rest
of the suite, so it is a check to run before a release or on a GPU machine (``MULTIBODY_TEST_PTX=1 python -m pytest
tests/test_cuda_target.py``), not on every push.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

PTX = textwrap.dedent(r"""
    import time
    import types
    import numba
    from numba import cuda
    from numba import types as nt
    def probe(x):
        x[0] = 1.0
    try:  # the toolchain (libNVVM) on a trivial kernel
        cuda.compile_ptx(probe, (nt.float64[::1],), cc=(9, 0))
    except Exception as e:
        print("NO-NVVM", type(e).__name__, str(e)[:200])
        raise SystemExit(0)
    # Device functions are compiled for the current device's compute capability: without a device, name one
    # (compile_ptx takes cc for the kernel itself).
    import numba.cuda.dispatcher as dispatcher
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(9, 0))
    from multibody import gpu
    from multibody.kernels import (aba, collision, complementarity, coriolis, crba, derivatives, energy, kinematics,
                                   rnea, stepping)
    from multibody.kernels import timestepping as ts

    rows, vector, ints = nt.float64[:, ::1], nt.float64[::1], nt.int64[:, ::1]
    cube = nt.float64[:, :, ::1]
    start = time.perf_counter()

    def lower(name, function, signature):
        ptx, _ = cuda.compile_ptx(function, signature, cc=(9, 0))
        assert ".entry" in ptx, ptx[:500]
        print(name, len(ptx), f"{time.perf_counter() - start:.0f} s", flush=True)

    # the launchers' kernels, and the others: none allocates or returns a bare array (kernels.jit)
    for kernel in (rnea.inverse_dynamics, crba.mass_matrix, aba.forward_dynamics, crba.inverse_mass_matrix,
                   coriolis.coriolis_matrix, kinematics.frame_jacobian, energy.kinetic_energy,
                   derivatives.forward_dynamics_derivatives):
        lower(kernel.__name__, gpu._launch_source(kernel), (ints, rows, rows, rows, rows, rows, rows, cube, rows))

    def detection(shapes, sizes, vertices, R, p, normal, out, ws, counts):
        i = cuda.grid(1)
        if i < out.shape[0]:
            counts[i, 0] = collision.halfspace_contacts(shapes[i], sizes[i], vertices, R[i], p[i], normal, 0.0, 1e-3,
                                                        out[i], ws[i])
            counts[i, 1] = collision.pair_contacts(shapes[i], sizes[i], vertices, R[i], p[i], shapes[0], sizes[0],
                                                   vertices, R[0], p[0], 1e-3, out[i], ws[i])

    lower("detection", detection, (nt.int64[::1], rows, rows, cube, rows, vector, cube, rows, ints))

    def solver(G, c, kinds, starts, mu, out, x, u, ws):
        i = cuda.grid(1)
        if i < G.shape[0]:
            status, iterations, residual = complementarity.solve(G[i], c[i], kinds[i], starts[i], mu[i], 1e-12, 100,
                                                                 x[i], u[i], ws[i])
            out[i, 0], out[i, 1], out[i, 2] = status, iterations, residual

    lower("complementarity.solve", solver, (cube, rows, ints, ints, rows, rows, rows, rows, rows))

    def step_parts(joints, reals, plan, geometry, vertices, pose, vel, contacts, out, cws, R, p, J, J6, W, Y, previous,
                   vectors, blocks, q):
        i = cuda.grid(1)
        if i == 0:
            found = ts.detect(plan, geometry, vertices, pose, vel, 1e-3, contacts, out, cws, R, p, R, p, vectors[0])
            for k in range(found):
                ts.contact_rows(joints, reals, pose, contacts[k], J, 3 * k, J6)
                vectors[1, k] = ts.lower_bound(contacts[k, ts.C_GAP], 1e-3, vectors[2, k], vectors[3, k], 0.5)
            ts.warm_start(plan, J, contacts, found, 0, 0, vectors[4], 0, previous, vectors[5], 1e-3, vectors[6])
            ts.separate(joints, plan, W, blocks[2], Y, vectors[7], vectors[8], found, vectors[16], vectors[9],
                        vectors[10], vectors[11], vectors[12], blocks[0], blocks[1], vectors[13], q.shape[0], J.shape[1],
                        q, vectors[14], vectors[15])

    lower("the contact step's parts", step_parts, (ints, rows, vector, rows, rows, rows, rows, rows, rows, vector, rows,
                                                   vector, rows, rows, rows, rows, rows, rows, ints, vector))

    @numba.njit
    def controller(t, q, v, out):
        for c in range(out.shape[0]):
            out[c] = -q[c] - 0.1 * v[c] * t

    def contact_run(joints, reals, frames, program, geometry, vertices, plan, control, times, states, records,
                    summaries, io, trajectories, WS, IWS):
        thread = cuda.grid(1)
        for j in range(thread, trajectories.shape[0], cuda.gridsize(1)):
            r = trajectories[j]
            ts.run(controller, joints, reals, frames, program, geometry, vertices, plan,
                   control[r if control.shape[0] > 1 else 0], times, states[r], records[r], summaries[r], io[r],
                   WS[thread], IWS[thread])

    lower("timestepping.run", contact_run, (ints, rows, rows, vector, rows, rows, vector, rows, vector, cube,
                                            nt.float64[:, :, :, ::1], cube, rows, nt.int64[::1], rows, ints))

    lower("stepping.advance", gpu.run_source(stepping.advance, controller),
          (ints, rows, rows, vector, vector, vector, rows, cube, rows, nt.int64[::1], rows))
    print("PTX-OK", f"{time.perf_counter() - start:.0f} s")
""")


def test_the_kernels_and_runs_lower_to_ptx_for_sm_90():
    """Every kernel, the contact detection and solver, the contact step and run, and the fixed-step run lower to PTX
    (no allocation, no Python objects, no builtin ``max``/``min`` of floats: the CUDA target has none)."""
    if os.environ.get("MULTIBODY_TEST_PTX") != "1":
        pytest.skip("the CUDA compilation of every kernel takes about 20 minutes: set MULTIBODY_TEST_PTX=1 to run it")
    env = dict(os.environ)
    env.pop("NUMBA_DISABLE_JIT", None)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    result = subprocess.run([sys.executable, "-c", PTX], capture_output=True, text=True, timeout=1800, env=env,
                            cwd=root, check=False)
    if "NO-NVVM" in result.stdout or "No module named 'numba.cuda" in result.stderr:
        pytest.skip("no CUDA compiler toolchain (libNVVM): " + result.stdout.strip())
    assert "PTX-OK" in result.stdout, result.stdout + result.stderr[-3000:]
