"""The dynamics on CUDA arrays (:mod:`multibody.gpu`), with no GPU.

* Under Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, in a subprocess so that the rest of the
  suite keeps the real ``numba.cuda``): RNEA, CRBA and ABA on device arrays of a few states of the
  double pendulum and of a random tree equal the CPU results to 1e-12, and come back as device arrays.
  The simulator runs the launchers as Python and the per-state arithmetic as the CPU kernels, so this
  checks the launch: threads, rows, broadcasting, workspaces, shapes, routing.
* (The launchers' lowering to PTX for the CUDA target is in ``test_cuda_target.py``.)
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))

SIMULATED = textwrap.dedent(r"""
    import os, sys
    os.environ["NUMBA_ENABLE_CUDASIM"] = "1"
    sys.path.insert(0, TESTS)
    import numpy as np
    from numba import cuda
    import multibody as mb
    from multibody import gpu
    from multibody.inertia import point_mass
    from multibody.joints import Revolute
    from multibody.spatial import pose_from_xyz_rpy
    from conftest import random_state, random_tree_model

    from numba import config
    assert config.ENABLE_CUDASIM
    b = mb.ModelBuilder("double_pendulum")
    b.add_body("link1", joint=Revolute([0, 1, 0]), inertia=point_mass(1.0, [0, 0, -1]))
    b.add_body("link2", parent="link1", joint=Revolute([0, 1, 0]), placement=pose_from_xyz_rpy([0, 0, -1]),
               inertia=point_mass(1.0, [0, 0, -1]))
    rng = np.random.default_rng(7)

    def close(device, host, what):
        assert gpu.is_device_array(device), (what, type(device))
        got = device.copy_to_host()
        assert got.shape == host.shape, (what, got.shape, host.shape)
        err = np.max(np.abs(got - host)) if host.size else 0.0
        assert err <= 1e-12 * max(1.0, np.max(np.abs(host))), (what, err)

    for model, n in ((b.build(), 3), (random_tree_model(1), 4)):
        states = [random_state(model, rng) for _ in range(n)]
        q, v, a = (np.array([s[k] for s in states]) for k in range(3))
        f = rng.standard_normal((n, model.njoints, 6))
        dq, dv, da, df = (cuda.to_device(x) for x in (q, v, a, f))
        close(mb.inverse_dynamics(model, dq, dv, da), mb.inverse_dynamics(model, q, v, a), "rnea")
        close(mb.inverse_dynamics(model, dq, dv, da, f_ext=df), mb.inverse_dynamics(model, q, v, a, f_ext=f),
              "rnea f_ext")
        # one row of v serves every state; a host array is copied over
        close(mb.inverse_dynamics(model, dq, cuda.to_device(v[0]), a), mb.inverse_dynamics(model, q, v[0], a),
              "rnea broadcast")
        close(mb.generalized_gravity(model, dq), mb.generalized_gravity(model, q), "gravity")
        close(mb.bias_forces(model, dq, dv), mb.bias_forces(model, q, v), "bias")
        close(mb.mass_matrix(model, dq), mb.mass_matrix(model, q), "crba")
        tau = mb.inverse_dynamics(model, q, v, a)
        close(mb.forward_dynamics(model, dq, dv, cuda.to_device(tau)), mb.forward_dynamics(model, q, v, tau), "aba")
        close(mb.forward_dynamics(model, dq, dv, cuda.to_device(tau), f_ext=df),
              mb.forward_dynamics(model, q, v, tau, f_ext=f), "aba f_ext")
        # one state with no batch axis, and batch axes of two dimensions
        close(mb.mass_matrix(model, cuda.to_device(q[0])), mb.mass_matrix(model, q[0]), "crba one state")
        q2 = np.stack([q, q[::-1]])
        close(mb.mass_matrix(model, cuda.to_device(q2)), mb.mass_matrix(model, q2), "crba (2, n)")
        # the device copy of the tree is made once per model
        assert gpu.device_tree(model) is gpu.device_tree(model)
    try:
        mb.mass_matrix(model, cuda.to_device(np.ascontiguousarray(q[:, :-1])))
    except ValueError as e:
        assert "must have shape" in str(e), e
    else:
        raise AssertionError("a wrong size was accepted")
    print("GPU-SIMULATED-OK")
""")


def run_python(source, env_extra=None, timeout=240):
    """``source`` in a fresh Python process of this repository (``TESTS``: this folder), with ``env_extra`` added to
    its environment."""
    env = dict(os.environ, **(env_extra or {}))
    env.pop("NUMBA_DISABLE_JIT", None)
    return subprocess.run([sys.executable, "-c", f"TESTS = {HERE!r}\n" + source], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=os.path.dirname(HERE))


def test_device_arrays_match_cpu_kernels_under_the_cuda_simulator():
    result = run_python(SIMULATED, {"NUMBA_ENABLE_CUDASIM": "1"})
    if "No module named 'numba.cuda" in result.stderr:
        pytest.skip("numba.cuda is not installed")
    assert "GPU-SIMULATED-OK" in result.stdout, result.stdout + result.stderr


def test_is_device_array_is_false_on_host_arrays():
    import numpy as np

    from multibody import gpu

    assert not gpu.is_device_array(np.zeros(3))
    assert not gpu.is_device_array([0.0, 1.0])
    assert not gpu.is_device_array(None)

    class Raises:  # a CPU PyTorch tensor's __cuda_array_interface__ raises TypeError
        @property
        def __cuda_array_interface__(self):
            raise TypeError("not on a CUDA device")

    assert not gpu.is_device_array(Raises())
