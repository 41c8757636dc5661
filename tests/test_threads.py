"""Threads of the batch driver (:mod:`multibody.driver`).

* ``MULTIBODY_NUM_THREADS``: more threads than Numba starts is clamped with a warning that names the
  variable; a value that is not a whole number of at least 1 stops the import with a message naming it.
* ``mb.set_num_threads`` is the process's setting: a batch run from another Python thread uses it too.
* An interrupt while a batch sets Numba's thread count leaves later batches on the process's setting.
* Under Numba's ``workqueue`` threading layer, batches from two Python threads at once run one after the
  other instead of aborting the process.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading

import numba
import numpy as np
import pytest

import multibody as mb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: States of a batch that every thread gets a share of (``driver.STATES_PER_THREAD`` each).
N_STATES = 4 * mb.driver.STATES_PER_THREAD


def _python(code, **env):
    """Run ``code`` in a fresh interpreter with ``env`` added to this one's environment."""
    environ = {name: value for name, value in os.environ.items() if name != "MULTIBODY_NUM_THREADS"} | env
    return subprocess.run([sys.executable, "-c", code], env=environ, cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


# ============================================================================= MULTIBODY_NUM_THREADS

def test_more_threads_than_numba_starts_are_clamped_with_a_warning():
    done = _python("import multibody as mb; print(mb.get_num_threads())",
                   MULTIBODY_NUM_THREADS="4", NUMBA_NUM_THREADS="2")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["2"]
    assert "MULTIBODY_NUM_THREADS=4" in done.stderr and "NUMBA_NUM_THREADS" in done.stderr, done.stderr


@pytest.mark.parametrize("value", ["abc", "0", "-1", "2.5"])
def test_a_bad_thread_count_in_the_environment_names_the_variable(value):
    done = _python("import multibody", MULTIBODY_NUM_THREADS=value)
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("ValueError: MULTIBODY_NUM_THREADS") and repr(value) in last, done.stderr


def test_the_environment_sets_the_thread_count():
    done = _python("import multibody as mb; print(mb.get_num_threads())",
                   MULTIBODY_NUM_THREADS="1", NUMBA_NUM_THREADS="2")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["1"]
    assert done.stderr == ""


# ============================================================================= set_num_threads

@pytest.mark.parametrize("n", [0, -1, numba.config.NUMBA_NUM_THREADS + 1])
def test_set_num_threads_out_of_range_names_the_argument(n):
    original = mb.get_num_threads()
    with pytest.raises(ValueError, match=r"set_num_threads: n must be between 1 and NUMBA_NUM_THREADS"):
        mb.set_num_threads(n)
    assert mb.get_num_threads() == original


@pytest.mark.parametrize("n", [1.0, "2", True, None])
def test_set_num_threads_takes_an_integer(n):
    with pytest.raises(TypeError, match=r"set_num_threads: n must be an integer"):
        mb.set_num_threads(n)


def _recording_batches(monkeypatch):
    """Record ``(shares, Numba's thread count)`` of every parallel loop the driver runs, then run the loop
    (the results are checked for overflow, so they must be computed)."""
    calls = []
    loop = mb.driver.entry_point(mb.driver._batch, mb.driver._BATCH_TYPES)

    def recorded(*args):
        calls.append((args[-1], numba.get_num_threads()))
        loop(*args)

    monkeypatch.setattr(mb.driver, "_batch", recorded)
    return calls


def _batch_of_states(model):
    rng = np.random.default_rng(0)
    return model.random_configuration(rng, (N_STATES,)), rng.standard_normal((N_STATES, model.nv))


@pytest.fixture
def threaded_batch():
    """``(most, model, q, v)``: ``NUMBA_NUM_THREADS``, the double pendulum and a batch of its states
    that every thread gets a share of; skipped where Numba has one thread only (no count to tell apart).
    The process's thread count is put back afterwards."""
    most = numba.config.NUMBA_NUM_THREADS
    if most < 2:
        pytest.skip("Numba has one thread only (NUMBA_NUM_THREADS=1): no count to tell apart")
    model = mb.robots.load("double_pendulum")
    original = mb.get_num_threads()
    try:
        yield (most, model, *_batch_of_states(model))
    finally:
        mb.set_num_threads(original)


def test_the_thread_count_is_the_process_s(monkeypatch, threaded_batch):
    """A batch run from a second Python thread uses what ``set_num_threads`` set in the first."""
    most, model, q, v = threaded_batch
    calls = _recording_batches(monkeypatch)
    seen, energies = [], []

    def elsewhere():
        seen.append(mb.get_num_threads())
        energies.append(mb.kinetic_energy(model, q, v))

    for n in (1, most):
        mb.set_num_threads(n)
        thread = threading.Thread(target=elsewhere)
        thread.start()
        thread.join()
        assert seen[-1] == n
        assert calls[-1] == (n, n), f"set_num_threads({n}): a batch of another thread ran on {calls[-1]}"
    assert len(seen) == 2 and len(calls) == 2
    # the same states on any number of threads: the same numbers
    np.testing.assert_array_equal(energies[0], energies[1])
    np.testing.assert_array_equal(energies[0], mb.kinetic_energy(model, q, v))


def test_an_interrupt_while_setting_numba_s_threads_leaves_later_batches_on_the_setting(monkeypatch, threaded_batch):
    """Ctrl-C just after a small batch has lowered Numba's thread count: the count comes back, and the
    next large batch runs on every thread of the setting."""
    most, model, q, v = threaded_batch
    mb.set_num_threads(most)
    set_num_threads = numba.set_num_threads
    interrupts = []

    def interrupted(n):
        set_num_threads(n)
        if not interrupts:
            interrupts.append(n)
            raise KeyboardInterrupt

    before = numba.get_num_threads()
    monkeypatch.setattr(numba, "set_num_threads", interrupted)
    with pytest.raises(KeyboardInterrupt):
        mb.kinetic_energy(model, q[:2], v[:2])  # two states: one share, on one thread
    assert interrupts == [1]
    assert numba.get_num_threads() == before
    assert mb.get_num_threads() == most
    calls = _recording_batches(monkeypatch)
    mb.kinetic_energy(model, q, v)
    assert calls == [(most, most)]


# ============================================================================= the workqueue layer

_CONCURRENT = textwrap.dedent("""
    import threading
    import numba
    import numpy as np
    import multibody as mb

    model = mb.robots.load("double_pendulum")
    rng = np.random.default_rng(0)
    q = model.random_configuration(rng, (2048,))
    v = rng.standard_normal((2048, model.nv))
    expected = mb.mass_matrix(model, q), mb.kinetic_energy(model, q, v)
    start = threading.Barrier(2)
    same = {}

    def work(k):
        start.wait()
        same[k] = all(np.array_equal(mb.mass_matrix(model, q), expected[0])
                      and np.array_equal(mb.kinetic_energy(model, q, v), expected[1]) for _ in range(50))

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    print(numba.threading_layer(), same[0], same[1])
""")


def test_concurrent_batches_under_the_workqueue_layer():
    """Two Python threads run 50 batches each at once on Numba's ``workqueue`` layer, which aborts the
    process on concurrent parallel calls: the driver runs them one after the other, with the numbers
    of one thread alone."""
    done = _python(_CONCURRENT, NUMBA_THREADING_LAYER="workqueue", NUMBA_NUM_THREADS="2")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["workqueue", "True", "True"]


def test_a_local_thread_count_is_the_calling_thread_s_only(monkeypatch, threaded_batch):
    """``driver.local_num_threads`` (a Dask task's share of its host): that Python thread's batches use
    it, the process's setting and the other threads' batches keep theirs."""
    most, model, q, v = threaded_batch
    calls = _recording_batches(monkeypatch)
    mb.set_num_threads(most)
    with mb.driver.local_num_threads(1):
        assert mb.get_num_threads() == 1
        mb.kinetic_energy(model, q, v)
        energies = []
        other = threading.Thread(target=lambda: energies.append(mb.kinetic_energy(model, q, v)))
        other.start()
        other.join()
        assert len(energies) == 1, "the other thread's batch failed"
    assert mb.get_num_threads() == most
    mb.kinetic_energy(model, q, v)
    assert calls == [(1, 1), (most, most), (most, most)]
    with pytest.raises(ValueError, match="local_num_threads: n must be between 1 and NUMBA_NUM_THREADS"):
        with mb.driver.local_num_threads(most + 1):
            pass
