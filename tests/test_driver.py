"""The batch driver (:mod:`multibody.driver`): the identities of ``shared/design/KERNELS.md``.

* One state equals a row of the batch: a single call (the kernel called directly) and the batch
  (the kernel run by the parallel loop) give the same numbers, on the random trees with every joint kind.
* One thread equals many: a batch gives bitwise the same numbers on any number of threads.
* Broadcasting of leading batch axes, and empty batches.
* Under ``NUMBA_DISABLE_JIT=1`` the kernels run as plain Python with the compiled numbers.
* The RNEA kernel launched as a CUDA kernel, one thread per state, under Numba's CUDA simulator.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import multibody as mb

from conftest import erd_urdf, random_tree_model

TESTS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TESTS)
N_STATES = 37
N_THREADED = 257
#: plain Python against compiled code: LLVM's and the C library's ``sin``/``cos`` may differ in the last bit
TOL_PLAIN = 1e-14
TOL_CUDASIM = 1e-12


def _states(model, n, seed=0):
    """``n`` random states: ``q, v, a, tau (n, ·)``, ``f_ext (n, nj, 6)``, a body point ``(n, 3)``."""
    rng = np.random.default_rng(seed)
    return dict(q=model.random_configuration(rng, (n,)), v=rng.standard_normal((n, model.nv)),
                a=rng.standard_normal((n, model.nv)), tau=rng.standard_normal((n, model.nv)),
                f_ext=rng.standard_normal((n, model.njoints, 6)), point=rng.uniform(-0.3, 0.3, (n, 3)))


def _bodies(model):
    """The body moved by the last joint, and the first moving body placed away from its joint's frame
    (a fixed attachment on the random trees)."""
    last = max(range(model.nbodies), key=lambda b: model.body_joints[b])
    fixed = [b for b in range(model.nbodies)
             if model.body_joints[b] >= 0 and not np.allclose(model.body_placements[b], np.eye(4))]
    return [model.body_names[last]] + [model.body_names[b] for b in fixed[:1] if b != last]


def _functions(model):
    """``name -> f(q, v, a, tau, f_ext, point)``: every public function that runs a kernel through the driver."""
    functions = {
        "inverse_dynamics": lambda q, v, a, tau, f, p: mb.inverse_dynamics(model, q, v, a),
        "inverse_dynamics_f_ext": lambda q, v, a, tau, f, p: mb.inverse_dynamics(model, q, v, a, f_ext=f),
        "joint_reaction_forces": lambda q, v, a, tau, f, p: mb.joint_reaction_forces(model, q, v, a, f_ext=f),
        "bias_forces": lambda q, v, a, tau, f, p: mb.bias_forces(model, q, v),
        "mass_matrix": lambda q, v, a, tau, f, p: mb.mass_matrix(model, q),
        "forward_dynamics": lambda q, v, a, tau, f, p: mb.forward_dynamics(model, q, v, tau),
        "forward_dynamics_f_ext": lambda q, v, a, tau, f, p: mb.forward_dynamics(model, q, v, tau, f_ext=f),
        "coriolis_matrix": lambda q, v, a, tau, f, p: mb.coriolis_matrix(model, q, v),
        "inverse_mass_matrix": lambda q, v, a, tau, f, p: mb.inverse_mass_matrix(model, q),
        "forward_kinematics": lambda q, v, a, tau, f, p: mb.forward_kinematics(model, q),
        "kinetic_energy": lambda q, v, a, tau, f, p: mb.kinetic_energy(model, q, v),
        "potential_energy": lambda q, v, a, tau, f, p: mb.potential_energy(model, q),
    }
    for body in _bodies(model):
        functions[f"jacobian[{body}]"] = lambda q, v, a, tau, f, p, body=body: mb.jacobian(model, q, body)
        functions[f"jacobian_point[{body}]"] = lambda q, v, a, tau, f, p, body=body: mb.jacobian(model, q, body, p)
        functions[f"jacobian_time_variation[{body}]"] = (
            lambda q, v, a, tau, f, p, body=body: mb.jacobian_time_variation(model, q, v, body, p))
    return functions


def _run_all(model, states):
    args = [states[k] for k in ("q", "v", "a", "tau", "f_ext", "point")]
    return {name: f(*args) for name, f in _functions(model).items()}


# ============================================================================= one state, one row

def test_one_state_equals_a_row_of_the_batch(random_tree):
    model = random_tree
    states = _states(model, N_STATES, seed=1)
    args = [states[k] for k in ("q", "v", "a", "tau", "f_ext", "point")]
    for name, f in _functions(model).items():
        batch = f(*args)
        singles = np.stack([f(*(x[s] for x in args)) for s in range(N_STATES)])
        assert batch.shape == singles.shape, name
        assert np.all(np.isfinite(batch)), name
        # the same compiled arithmetic, called directly or from the parallel loop
        np.testing.assert_array_equal(batch, singles, err_msg=name)


def test_a_row_of_one_state_serves_every_state():
    """An input without batch axes (or with one row) is read by every state of the batch."""
    model = random_tree_model(0)
    states = _states(model, N_STATES, seed=2)
    q, v, a = states["q"], states["v"][0], states["a"][0]
    tau = mb.inverse_dynamics(model, q, v, a)
    np.testing.assert_array_equal(tau, np.stack([mb.inverse_dynamics(model, q[s], v, a) for s in range(N_STATES)]))
    tau = mb.inverse_dynamics(model, q[0], states["v"], a[None])
    np.testing.assert_array_equal(tau, np.stack([mb.inverse_dynamics(model, q[0], x, a) for x in states["v"]]))


def test_single_calls_take_read_only_and_strided_vectors():
    """A single call runs one compiled signature whatever the writability of its vectors; a strided one
    (which that signature's machine code cannot read) goes through the general path, with the same numbers."""
    from multibody.kernels import rnea

    model = random_tree_model(0)
    states = _states(model, 1, seed=3)
    q, v, a = states["q"][0], states["v"][0], states["a"][0]
    expected = mb.inverse_dynamics(model, q, v, a)
    signatures = list(getattr(rnea.inverse_dynamics, "signatures", []))
    frozen = [x.copy() for x in (q, v, a)]
    for x in frozen:
        x.setflags(write=False)
    np.testing.assert_array_equal(mb.inverse_dynamics(model, *frozen), expected)
    strided = [np.repeat(x, 2)[::2] for x in (q, v, a)]
    assert not strided[0].flags.c_contiguous
    np.testing.assert_array_equal(mb.inverse_dynamics(model, *strided), expected)
    # no new machine code for the read-only vectors: the single call's types are fixed (driver._SINGLE_CALL_TYPES)
    assert list(getattr(rnea.inverse_dynamics, "signatures", [])) == signatures


# ============================================================================= one thread, many

def test_one_thread_equals_many():
    import numba

    original = mb.get_num_threads()
    counts = sorted({original, numba.config.NUMBA_NUM_THREADS, min(3, numba.config.NUMBA_NUM_THREADS)} - {1})
    if not counts:
        pytest.skip("Numba has one thread only (NUMBA_NUM_THREADS=1): nothing to compare")
    model = random_tree_model(1)
    states = _states(model, N_THREADED, seed=3)
    try:
        mb.set_num_threads(1)
        assert mb.get_num_threads() == 1
        one = _run_all(model, states)
        for n in counts:
            mb.set_num_threads(n)
            assert mb.get_num_threads() == n
            many = _run_all(model, states)
            for name in one:
                assert np.all(np.isfinite(one[name])), name
                np.testing.assert_array_equal(many[name], one[name], err_msg=f"{name}: {n} threads vs 1")
    finally:
        mb.set_num_threads(original)
    assert mb.get_num_threads() == original


_MANY_THREADS = textwrap.dedent("""
    import sys
    import numpy as np
    import multibody as mb
    sys.path.insert(0, {tests!r})
    from conftest import random_tree_model
    model = random_tree_model(2)
    data = np.load(sys.argv[1])
    q, v, tau = data["q"], data["v"], data["tau"]
    out = {{}}
    for n in range(1, mb.get_num_threads() + 1):
        mb.set_num_threads(n)
        out[f"a{{n}}"] = mb.forward_dynamics(model, q, v, tau)
        out[f"M{{n}}"] = mb.mass_matrix(model, q)
    np.savez(sys.argv[2], **out)
""")


def test_more_threads_than_cores_and_uneven_shares(tmp_path):
    """Every thread count from 1 to 5 (more threads than this machine may have cores; 257 states split
    unevenly) gives bitwise the numbers of one thread."""
    model = random_tree_model(2)
    states = _states(model, N_THREADED, seed=4)
    np.savez(tmp_path / "in.npz", q=states["q"], v=states["v"], tau=states["tau"])
    script = tmp_path / "threads.py"
    script.write_text(_MANY_THREADS.format(tests=TESTS))
    env = {**os.environ, "NUMBA_NUM_THREADS": "5"}
    env.pop("MULTIBODY_NUM_THREADS", None)
    subprocess.run([sys.executable, str(script), str(tmp_path / "in.npz"), str(tmp_path / "out.npz")], check=True,
                   env=env, cwd=ROOT, timeout=300)
    out = np.load(tmp_path / "out.npz")
    assert sorted(out.files) == sorted([f"{x}{n}" for x in "aM" for n in range(1, 6)])
    a = mb.forward_dynamics(model, states["q"], states["v"], states["tau"])
    M = mb.mass_matrix(model, states["q"])
    for n in range(1, 6):
        np.testing.assert_array_equal(out[f"a{n}"], a, err_msg=f"forward dynamics, {n} threads")
        np.testing.assert_array_equal(out[f"M{n}"], M, err_msg=f"mass matrix, {n} threads")


# ============================================================================= broadcasting

def test_leading_axes_broadcast():
    model = random_tree_model(0)
    nq, nv = model.nq, model.nv
    rng = np.random.default_rng(5)
    q = model.random_configuration(rng, (5, 1))
    v = rng.standard_normal((3, nv))
    a = rng.standard_normal(nv)
    f_ext = rng.standard_normal((1, 3, model.njoints, 6))
    assert q.shape == (5, 1, nq)
    Q, V = np.broadcast_to(q, (5, 3, nq)), np.broadcast_to(v, (5, 3, nv))
    A, F = np.broadcast_to(a, (5, 3, nv)), np.broadcast_to(f_ext, (5, 3, model.njoints, 6))
    cases = {
        "inverse_dynamics": (mb.inverse_dynamics(model, q, v, a, f_ext=f_ext),
                             mb.inverse_dynamics(model, Q, V, A, f_ext=F), (5, 3, nv)),
        "bias_forces": (mb.bias_forces(model, q, v), mb.bias_forces(model, Q, V), (5, 3, nv)),
        "forward_dynamics": (mb.forward_dynamics(model, q, v, a), mb.forward_dynamics(model, Q, V, A), (5, 3, nv)),
        "coriolis_matrix": (mb.coriolis_matrix(model, q, v), mb.coriolis_matrix(model, Q, V), (5, 3, nv, nv)),
        "kinetic_energy": (mb.kinetic_energy(model, q, v), mb.kinetic_energy(model, Q, V), (5, 3)),
        "jacobian_time_variation": (mb.jacobian_time_variation(model, q, v, "extra_5"),
                                    mb.jacobian_time_variation(model, Q, V, "extra_5"), (5, 3, 6, nv)),
        "mass_matrix": (mb.mass_matrix(model, q), mb.mass_matrix(model, Q[:, :1]), (5, 1, nv, nv)),
    }
    for name, (broadcast, explicit, shape) in cases.items():
        assert broadcast.shape == shape, name
        assert np.all(np.isfinite(broadcast)), name
        np.testing.assert_array_equal(broadcast, explicit, err_msg=name)
    # each state of the broadcast batch is its own single call
    np.testing.assert_array_equal(cases["inverse_dynamics"][0][4, 2],
                                  mb.inverse_dynamics(model, q[4, 0], v[2], a, f_ext=f_ext[0, 2]))
    # a Jacobian point with its own batch axes broadcasts against q
    points = rng.uniform(-0.2, 0.2, (3, 3))
    J = mb.jacobian(model, q, "revolute_0", points)
    assert J.shape == (5, 3, 6, nv)
    np.testing.assert_array_equal(J, mb.jacobian(model, Q, "revolute_0", np.broadcast_to(points, (5, 3, 3))))


def test_empty_batches():
    model = random_tree_model(0)
    nq, nv = model.nq, model.nv
    q0 = np.zeros((0, nq))
    v = np.ones(nv)
    assert mb.inverse_dynamics(model, q0, v, v).shape == (0, nv)
    assert mb.inverse_dynamics(model, q0, np.zeros((0, nv)), v).shape == (0, nv)
    assert mb.generalized_gravity(model, q0).shape == (0, nv)
    assert mb.forward_dynamics(model, q0, v, v).shape == (0, nv)
    assert mb.mass_matrix(model, q0).shape == (0, nv, nv)
    assert mb.inverse_mass_matrix(model, q0).shape == (0, nv, nv)
    assert mb.coriolis_matrix(model, q0, v).shape == (0, nv, nv)
    assert mb.kinetic_energy(model, q0, v).shape == (0,)
    assert mb.forward_kinematics(model, q0).shape == (0, model.nbodies, 4, 4)
    assert mb.jacobian(model, q0, "extra_5").shape == (0, 6, nv)
    # an empty axis among others
    assert mb.inverse_dynamics(model, np.zeros((2, 0, nq)), v, v).shape == (2, 0, nv)
    assert mb.mass_matrix(model, np.zeros((0, 3, nq))).shape == (0, 3, nv, nv)


# ============================================================================= plain Python

_ALGORITHMS = ("inverse_dynamics", "mass_matrix", "forward_dynamics", "coriolis_matrix", "jacobian",
               "jacobian_time_variation", "frame_kinematics", "inverse_mass_matrix", "kinetic_energy",
               "potential_energy", "forward_kinematics")


def _algorithms(model, states, single):
    """RNEA (with external forces), CRBA, ABA, Coriolis, Jacobian and more, on the states, batched or
    one state at a time."""
    body = _bodies(model)[0]

    def run(q, v, a, tau, f, p):
        return {"inverse_dynamics": mb.inverse_dynamics(model, q, v, a, f_ext=f),
                "mass_matrix": mb.mass_matrix(model, q),
                "forward_dynamics": mb.forward_dynamics(model, q, v, tau, f_ext=f),
                "coriolis_matrix": mb.coriolis_matrix(model, q, v),
                "jacobian": mb.jacobian(model, q, body, p),
                "jacobian_time_variation": mb.jacobian_time_variation(model, q, v, body, p),
                "frame_kinematics": np.concatenate([x.reshape(q.shape[:-1] + (-1,))
                                                    for x in mb.kinematics.frame_kinematics(model, q, v, body)], -1),
                "inverse_mass_matrix": mb.inverse_mass_matrix(model, q),
                "kinetic_energy": mb.kinetic_energy(model, q, v),
                "potential_energy": mb.potential_energy(model, q),
                "forward_kinematics": mb.forward_kinematics(model, q)}

    args = [states[k] for k in ("q", "v", "a", "tau", "f_ext", "point")]
    if not single:
        return run(*args)
    rows = [run(*(x[s] for x in args)) for s in range(args[0].shape[0])]
    return {name: np.stack([r[name] for r in rows]) for name in _ALGORITHMS}


_PLAIN_PYTHON = textwrap.dedent("""
    import sys
    import numba
    import numpy as np
    import multibody as mb
    from multibody.kernels import aba, coriolis, crba, kinematics, rnea
    sys.path.insert(0, {tests!r})
    import test_driver as t
    from conftest import random_tree_model

    # the kernels and the driver's loop really are plain Python functions
    for f in (rnea.inverse_dynamics, crba.mass_matrix, aba.forward_dynamics, coriolis.coriolis_matrix,
              kinematics.frame_jacobian, mb.driver._batch):
        assert not isinstance(f, numba.core.dispatcher.Dispatcher), f
    out = {{}}
    for name, model in (("double_pendulum", mb.robots.load("double_pendulum")), ("random_tree", random_tree_model(0))):
        data = np.load(sys.argv[1] + "_" + name + ".npz")
        for single in (False, True):
            for k, x in t._algorithms(model, data, single).items():
                out[f"{{name}}/{{k}}/{{single}}"] = x
    np.savez(sys.argv[2], **out)
""")


def test_plain_python_gives_the_compiled_numbers(tmp_path):
    """``NUMBA_DISABLE_JIT=1``: the kernels, and the driver's loop, run as Python with the compiled numbers."""
    models = {"double_pendulum": mb.robots.load("double_pendulum"), "random_tree": random_tree_model(0)}
    states = {name: _states(model, 3, seed=6) for name, model in models.items()}
    for name in models:
        np.savez(tmp_path / f"in_{name}.npz", **states[name])
    script = tmp_path / "plain.py"
    script.write_text(_PLAIN_PYTHON.format(tests=TESTS))
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    subprocess.run([sys.executable, str(script), str(tmp_path / "in"), str(tmp_path / "out.npz")], check=True,
                   env=env, cwd=ROOT, timeout=300)
    out = np.load(tmp_path / "out.npz")
    assert len(out.files) == 2 * 2 * len(_ALGORITHMS)
    for name, model in models.items():
        for single in (False, True):
            compiled = _algorithms(model, states[name], single)
            for k in _ALGORITHMS:
                plain, ref = out[f"{name}/{k}/{single}"], compiled[k]
                assert plain.shape == ref.shape, (name, k)
                assert np.all(np.isfinite(ref)), (name, k)
                err = np.max(np.abs(plain - ref)) / max(1.0, np.max(np.abs(ref)))
                assert err <= TOL_PLAIN, f"{name} {k} (single={single}): plain Python differs by {err:.2e}"


# ============================================================================= CUDA, simulated

_CUDASIM = textwrap.dedent("""
    import sys
    import numpy as np
    from numba import config, cuda
    import multibody as mb
    from multibody.kernels import rnea

    assert config.ENABLE_CUDASIM and config.DISABLE_JIT
    model = mb.load_urdf(sys.argv[1]) if sys.argv[1] != "double_pendulum" else mb.robots.load("double_pendulum")
    tree = model.tree
    data = np.load(sys.argv[2])
    q, v, a, f_ext = data["q"], data["v"], data["a"], data["f_ext"].reshape(len(data["q"]), -1)
    n, nj = q.shape[0], tree.joints.shape[0]


    @cuda.jit
    def inverse_dynamics(joints, reals, frames, q, v, a, f_ext, out, workspace):
        # one thread per state, each with its own row of the workspace
        s = cuda.grid(1)
        if s < q.shape[0]:
            rnea.inverse_dynamics(joints, reals, frames, q[s], v[s], a[s], f_ext[s], out[s], workspace[s])


    args = [cuda.to_device(np.ascontiguousarray(x)) for x in (tree.joints, tree.reals, tree.bodies, q, v, a, f_ext)]
    out = cuda.to_device(np.full((n, 1, model.nv), np.nan))
    workspace = cuda.to_device(np.full((n, rnea.workspace_size(nj, model.nv)), np.nan))
    assert hasattr(out, "__cuda_ndarray__")
    threads = 4
    inverse_dynamics[(n + threads - 1) // threads, threads](*args, out, workspace)
    np.save(sys.argv[3], out.copy_to_host()[:, 0])
""")


@pytest.mark.parametrize("robot", ["double_pendulum", "panda"])
def test_rnea_as_a_cuda_kernel_under_the_simulator(robot, tmp_path):
    """The RNEA kernel, called from a ``@cuda.jit`` kernel with one thread per state and per-thread rows of
    the device arrays, under ``NUMBA_ENABLE_CUDASIM=1``.

    The simulator runs the CUDA kernel as Python and hands it its own stand-ins for device arrays, which
    Numba's CPU dispatchers cannot type; so the kernels it calls run as Python too (``NUMBA_DISABLE_JIT=1``).
    What this checks is the launch pattern and that the kernel's source runs on device-array slices; it does
    not compile it for a GPU.
    """
    if importlib.util.find_spec("numba.cuda") is None:
        pytest.skip("numba.cuda is not importable in this Numba (and the numba-cuda package is not installed)")
    path = "double_pendulum" if robot == "double_pendulum" else erd_urdf("panda_description/urdf/panda.urdf")
    model = mb.robots.load("double_pendulum") if robot == "double_pendulum" else mb.load_urdf(path)
    states = _states(model, 6, seed=7)
    np.savez(tmp_path / "in.npz", **states)
    script = tmp_path / "cudasim.py"
    script.write_text(_CUDASIM)
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "NUMBA_DISABLE_JIT": "1"}
    result = subprocess.run([sys.executable, str(script), path, str(tmp_path / "in.npz"), str(tmp_path / "out.npy")],
                            env=env, cwd=ROOT, timeout=300, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    tau = np.load(tmp_path / "out.npy")
    ref = mb.inverse_dynamics(model, states["q"], states["v"], states["a"], f_ext=states["f_ext"])
    assert tau.shape == ref.shape == (6, model.nv)
    assert np.all(np.isfinite(tau))
    np.testing.assert_allclose(tau, ref, rtol=0, atol=TOL_CUDASIM * max(1.0, np.max(np.abs(ref))))


def test_compiled_before_reports_kernels_with_code_on_disk():
    """After a kernel has run, its compiled code is on disk (Numba's cache index), which is what the
    demo asks before saying that it is compiling."""
    model = mb.robots.load("double_pendulum")
    mb.inverse_dynamics(model, np.zeros(2), np.zeros(2), np.zeros(2))
    assert mb.driver.compiled_before((mb.kernels.rnea.inverse_dynamics,))


def test_compile_kernels_shares_a_cold_cache_among_processes(tmp_path):
    """On an empty cache, ``compile_kernels`` compiles one share here and the other in a worker process:
    both kernels are on disk afterwards, and this process holds the machine code of its share only."""
    script = textwrap.dedent("""
        from multibody import driver
        from multibody.kernels import energy
        kernels = (energy.kinetic_energy, energy.potential_energy)
        assert not driver.compiled_before(kernels)
        driver.compile_kernels(kernels, processes=2)
        print(driver.compiled_before(kernels), len(kernels[0].overloads), len(kernels[1].overloads))
    """)
    done = subprocess.run([sys.executable, "-c", script], env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)},
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "1", "0"]


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")
def test_compile_kernels_compiles_loops_for_their_argument_types(tmp_path):
    """``compile_kernels`` takes ``(function, argument types)`` beside kernels: on an empty cache the compiled
    run's controller loop goes to a worker process and the empty controller is compiled here, both are on disk
    afterwards, and a later process's first batch of a compiled controller says nothing of compiling them."""
    script = textwrap.dedent("""
        from multibody import driver, integrators
        from multibody.kernels import stepping
        entries = ((stepping.no_controller, integrators.CONTROLLER_TYPES),
                   (stepping.controller_rows, integrators._CONTROLLER_ROWS_TYPES))
        assert set(entries) <= set(integrators.ENTRY_POINTS) and not driver.compiled_before(entries)
        driver.compile_kernels(entries, processes=2)
        print(driver.compiled_before(entries), len(stepping.no_controller.overloads),
              len(stepping.controller_rows.overloads))
    """)
    env = {name: value for name, value in os.environ.items() if name != "MULTIBODY_QUIET"}
    env["NUMBA_CACHE_DIR"] = str(tmp_path)
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "1", "0"] and done.stderr == ""
    first_use = textwrap.dedent("""
        import numba
        import numpy as np
        from multibody import integrators

        @numba.njit
        def spring(t, q, v, out):
            out[:] = -q

        print(integrators.CompiledController(spring, 2)(0.0, np.ones((3, 2)), np.zeros((3, 2))).sum())
    """)
    done = subprocess.run([sys.executable, "-c", first_use], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["-6.0"] and "multibody: compiling" not in done.stderr


def test_compile_kernels_does_nothing_when_the_cache_has_them(monkeypatch):
    """Kernels already on disk start no process and compile nothing here."""
    def no_process(*args, **kwargs):
        raise AssertionError("a worker process was started")

    monkeypatch.setattr(mb.driver.subprocess, "Popen", no_process)
    model = mb.robots.load("double_pendulum")
    mb.kinetic_energy(model, np.zeros(2), np.zeros(2))
    kernel = mb.kernels.energy.kinetic_energy
    before = dict(kernel.overloads)
    mb.driver.compile_kernels((kernel,), processes=2)
    assert dict(kernel.overloads) == before


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")
def test_kernels_compile_without_the_reference_counted_runtime():
    """Every compiled function of ``multibody.kernels`` is compiled without Numba's reference-counted
    runtime: none can allocate (as the GPU target requires), and a single call passes plain buffers."""
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    functions = [value for info in pkgutil.iter_modules(mb.kernels.__path__)
                 for value in vars(importlib.import_module(f"multibody.kernels.{info.name}")).values()
                 if isinstance(value, Dispatcher) and value.py_func.__module__.startswith("multibody.kernels")]
    assert len(functions) > 100
    assert [f.py_func.__qualname__ for f in functions if f.targetoptions.get("_nrt", True)] == []


# ============================================================================= memory of batched calls

def test_batched_inputs_that_fit_are_read_in_place():
    """C-contiguous float64 inputs of the whole batch, writable or read-only, and an input of one row reach
    the compiled loop as they are: a call's traced peak is its new result, or below a tenth of one input
    when ``out=`` receives the result (copies of the inputs would take several times it), and a
    read-only input compiles nothing new."""
    import tracemalloc

    from multibody import driver
    from multibody.kernels import rnea

    model = random_tree_model(0)
    n = 4096
    states = _states(model, n, seed=4)
    q, v, a = states["q"], states["v"], states["a"]
    expected = mb.inverse_dynamics(model, q, v, a)
    out = np.empty_like(expected)
    assert mb.inverse_dynamics(model, q, v, a, out=out) is out
    loops, kernels = list(driver._batch.signatures), list(rnea.inverse_dynamics.signatures)
    tracemalloc.start()
    try:
        mb.inverse_dynamics(model, q, v, a)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1.1 * expected.nbytes, (peak, expected.nbytes)  # the new result alone
    for x in (q, v, a):
        x.setflags(write=False)
    for inputs in ((q, v, a), (q, v, a[0])):
        out[:] = np.nan
        tracemalloc.start()
        try:
            result = mb.inverse_dynamics(model, *inputs, out=out)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert result is out
        assert peak < v.nbytes / 10, (peak, v.nbytes)
        np.testing.assert_array_equal(out, expected if inputs[2].ndim == 2 else mb.inverse_dynamics(model, q, v, a[0]))
    assert list(driver._batch.signatures) == loops and list(rnea.inverse_dynamics.signatures) == kernels


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")
def test_an_edited_helper_in_another_file_reaches_its_cached_callers(tmp_path):
    """A kernel's cached machine code holds its helpers from other files, inlined, and Numba checks only the
    kernel's own file: after an edit of ``spatial.dot3`` (which the potential energy's ``Σ gᵀ mᵢ cᵢ`` calls),
    a new process must run the edited helper, not the cached kernel. A copy of the package is edited."""
    package = tmp_path / "copy"
    shutil.copytree(os.path.dirname(mb.__file__), package / "multibody",
                    ignore=shutil.ignore_patterns("__pycache__"))
    script = textwrap.dedent("""
        import numpy as np
        import multibody as mb
        assert mb.__file__.startswith(%r)
        from multibody.inertia import point_mass
        from multibody.joints import Revolute
        builder = mb.ModelBuilder("pendulum")
        builder.add_body("link", joint=Revolute([0, 1, 0]), inertia=point_mass(2.0, [0, 0, -1]))
        print(mb.potential_energy(builder.build(), np.zeros(1)).item())
    """ % str(package))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(package)}

    def energy():
        done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300,
                              cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        return float(done.stdout)

    assert energy() == pytest.approx(-2.0 * 9.81 * 1.0, rel=1e-3)  # m g z with z = -1 m
    spatial = package / "multibody" / "kernels" / "spatial.py"
    source = spatial.read_text()
    dot3 = "    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]\n"
    assert source.count(dot3) == 1
    spatial.write_text(source.replace(dot3, "    return 2.0 * (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])\n"))
    assert energy() == pytest.approx(-2.0 * 2.0 * 9.81 * 1.0, rel=1e-3)
