"""multibody.numba_hooks: each use of a Numba internal gives the same results through its public fallback when
the internal member is taken away."""

import os
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest
from numba import types

from multibody import numba_hooks

pytestmark = pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="no compiled code")

VECTOR = types.float64[::1]
TWO_VECTORS = (VECTOR, VECTOR)


def _scaled(x, out):
    for i in range(x.size):
        out[i] = 3.0 * x[i] + i


class _NoLookups(dict):
    """Numba's table of a dispatcher's overloads, which Numba itself still reads (``get``) and fills, but which
    answers no look-up by key: a Numba whose overloads are not reachable that way."""

    def __getitem__(self, key):
        raise KeyError(key)


def test_entry_point_is_the_overloads_entry_and_falls_back_to_the_dispatcher(monkeypatch):
    x = np.arange(4.0)
    internal = numba_hooks.entry_point(numba.njit(_scaled), TWO_VECTORS)
    fallback_dispatcher = numba.njit(_scaled)
    monkeypatch.setattr(fallback_dispatcher, "overloads", _NoLookups())
    fallback = numba_hooks.entry_point(fallback_dispatcher, TWO_VECTORS)
    assert fallback is fallback_dispatcher and internal is not fallback
    out_internal, out_fallback = np.empty(4), np.empty(4)
    internal(x, out_internal)
    fallback(x, out_fallback)
    np.testing.assert_array_equal(out_internal, 3.0 * x + np.arange(4))
    np.testing.assert_array_equal(out_fallback, out_internal)


@numba.njit
def _apply_rows(function, X, OUT):
    for s in range(X.shape[0]):
        function(X[s], OUT[s])


_ROWS_TYPES = (types.FunctionType(types.none(*TWO_VECTORS)), types.float64[:, ::1], types.float64[:, ::1])


def test_first_class_falls_back_to_the_dispatcher_without_compile_result_wap(monkeypatch):
    """Without ``CompileResultWAP``, the dispatcher itself goes to compiled code as a first-class function."""
    X = np.arange(6.0).reshape(2, 3)
    loop = numba_hooks.entry_point(_apply_rows, _ROWS_TYPES)
    wap = numba_hooks.first_class(numba.njit(_scaled), TWO_VECTORS)
    monkeypatch.setattr(numba_hooks, "CompileResultWAP", None)
    dispatcher = numba.njit(_scaled)
    plain = numba_hooks.first_class(dispatcher, TWO_VECTORS)
    assert plain is dispatcher and type(wap) is not type(plain)
    out_wap, out_plain = np.empty((2, 3)), np.empty((2, 3))
    loop(wap, X, out_wap)
    loop(plain, X, out_plain)
    np.testing.assert_array_equal(out_wap, 3.0 * X + np.arange(3))
    np.testing.assert_array_equal(out_plain, out_wap)


def test_the_package_runs_batches_where_numba_has_no_compile_result_wap(tmp_path):
    """Imported where Numba's ``CompileResultWAP`` is absent, multibody's batch (the kernel as a first-class
    function) gives what single calls give."""
    script = textwrap.dedent("""
        import numba.core.types.function_type as function_type
        del function_type.CompileResultWAP
        import numpy as np
        import multibody as mb
        from multibody import driver, kernels
        model = mb.robots.load("double_pendulum")
        rng = np.random.default_rng(1)
        q, v, a = (rng.standard_normal((300, 2)) for _ in range(3))
        batch = mb.inverse_dynamics(model, q, v, a)
        single = np.array([mb.inverse_dynamics(model, *state) for state in zip(q, v, a)])
        assert (driver.first_class(kernels.rnea.inverse_dynamics, driver._SINGLE_CALL_TYPES)
                is kernels.rnea.inverse_dynamics)
        print(np.array_equal(batch, single))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "MULTIBODY_QUIET": "1"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True"]


def _term(x, k):
    return x * (k + 1)


def _sum_of_terms(helper):
    def total(x):
        return helper(x, 0) + helper(x, 1) + helper(x, 2)

    return numba.njit(total)


def test_typed_by_types_compiles_one_specialisation_and_its_absence_gives_the_same_numbers():
    """Constant arguments typed by their types: one compiled helper for the three constants, where Numba's own
    typing (the fallback, a dispatcher without ``get_call_template``) compiles one per constant; same sum."""
    by_types = numba_hooks.typed_by_types(numba.njit(_term))
    by_value = numba.njit(_term)
    assert by_types(2.0, 1) == 4.0  # (the override leaves calls from Python as they were)
    assert _sum_of_terms(by_types)(2.0) == _sum_of_terms(by_value)(2.0) == 12.0
    assert [tuple(s.args) for s in by_types.nopython_signatures if s.args[0] == types.float64] == [
        (types.float64, types.int64)]
    assert len(by_value.nopython_signatures) > len(by_types.nopython_signatures)
    python_function = numba_hooks.typed_by_types(_term)  # no get_call_template: left as it is
    assert python_function is _term


def test_njit_without_runtime_falls_back_to_numba_njit_when_the_option_is_refused(monkeypatch):
    without = numba_hooks.njit_without_runtime(cache=False)(_scaled)
    assert without.targetoptions.get("_nrt") is False
    njit = numba.njit

    def refusing(**options):
        if "_nrt" in options:
            raise TypeError("unrecognized option _nrt")
        return njit(**options)

    monkeypatch.setattr(numba_hooks.numba, "njit", refusing)
    with_runtime = numba_hooks.njit_without_runtime(cache=False)(_scaled)
    assert "_nrt" not in with_runtime.targetoptions
    x, out, expected = np.arange(5.0), np.empty(5), np.empty(5)
    without(x, expected)
    with_runtime(x, out)
    np.testing.assert_array_equal(out, expected)


def test_cached_on_disk_reads_the_index_or_else_numbas_stats(tmp_path):
    """In a fresh cache folder: not on disk before the first compile, on disk after it and in the next process,
    by the cache's index file and, with the dispatcher's ``_cache_file`` taken away, by ``stats``."""
    script = textwrap.dedent("""
        import sys, types as pytypes, numba
        from numba import types
        from multibody import numba_hooks
        sys.path.insert(0, sys.argv[2])
        from cached_kernel import scaled
        if sys.argv[1] == "fallback":  # Numba's loading and saving stay; the index file's name is gone
            cache = scaled._cache
            scaled._cache = pytypes.SimpleNamespace(load_overload=cache.load_overload,
                                                    save_overload=cache.save_overload, cache_path=cache.cache_path)
        signature = (types.float64[::1], types.float64[::1])
        first = numba_hooks.cached_on_disk(scaled, signature)
        scaled.compile(signature)
        print(first, numba_hooks.cached_on_disk(scaled, signature))
    """)
    (tmp_path / "cached_kernel.py").write_text("import numba\n\n\n@numba.njit(cache=True)\n"
                                               "def scaled(x, out):\n    out[:] = 3.0 * x\n")

    def run(mode, cache):
        done = subprocess.run([sys.executable, "-c", script, mode, str(tmp_path)], capture_output=True, text=True,
                              timeout=300, env={**os.environ, "NUMBA_CACHE_DIR": str(cache)})
        assert done.returncode == 0, done.stderr
        return done.stdout.split()

    for mode in ("internal", "fallback"):
        cache = tmp_path / f"cache-{mode}"
        assert run(mode, cache) == ["False", "True"]
        assert run(mode, cache) == ["True", "True"]


def test_cache_directory_falls_back_beside_the_file_without_numbas_locators(monkeypatch, tmp_path):
    here = os.path.abspath(__file__)
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))  # (NUMBA_CACHE_DIR as Numba read it)
    found = numba_hooks.cache_directory(_scaled, here)
    assert found is not None and os.path.commonpath([found, str(tmp_path)]) == str(tmp_path)
    monkeypatch.setitem(sys.modules, "numba.core.caching", None)  # (an import of it raises ImportError)
    assert numba_hooks.cache_directory(_scaled, here) == os.path.join(os.path.dirname(here), "__pycache__")


def test_compiled_code_is_the_overload_until_recompiled_and_none_without_numbas_table(monkeypatch):
    """``compiled_code``: ``None`` before the types are compiled, then one object until ``recompile()`` makes
    another; ``None`` where Numba's table of overloads answers no look-up."""
    dispatcher = numba.njit(_scaled)
    assert numba_hooks.compiled_code(dispatcher, TWO_VECTORS) is None
    dispatcher.compile(TWO_VECTORS)
    code = numba_hooks.compiled_code(dispatcher, TWO_VECTORS)
    assert code is not None and numba_hooks.compiled_code(dispatcher, list(TWO_VECTORS)) is code
    dispatcher.recompile()
    assert numba_hooks.compiled_code(dispatcher, TWO_VECTORS) not in (None, code)
    monkeypatch.setattr(dispatcher, "overloads", _NoLookups())
    assert numba_hooks.compiled_code(dispatcher, TWO_VECTORS) is None


def test_return_type_reads_the_documented_signatures():
    dispatcher = numba.njit(lambda x, out: out.sum())
    with pytest.raises(ValueError, match="not compiled"):
        numba_hooks.return_type(dispatcher, TWO_VECTORS)
    dispatcher.compile(TWO_VECTORS)
    assert numba_hooks.return_type(dispatcher, TWO_VECTORS) == types.float64
