"""Every use of Numba beyond its documented public API, each with a public fallback.

The rest of multibody imports from Numba only its documented API (``numba.njit``, ``numba.types``,
``numba.prange``, ``numba.config``, ``numba.extending.is_jitted``, ``numba.cuda``) and, from this
module, what Numba keeps in ``numba.core``. A Numba release that renames or drops one of the internal
members below leaves multibody working through the fallback named beside it: the same numbers, at the
cost of speed (a single call through the dispatcher) or of compile time.

Documented in Numba's reference (Just-in-Time compilation, Types and signatures, Event API):

* ``Dispatcher.compile(types)``, ``.py_func``, ``.nopython_signatures`` (each ``args`` and
  ``return_type``) and ``.stats`` (``cache_hits``, ``cache_misses``: counters by signature);
* a ``numba.njit`` function passed to compiled code as a first-class function, an argument of type
  ``numba.types.FunctionType(signature)`` (Types and signatures, "First-class function objects");
* ``numba.core.event`` (``register``, ``Listener`` and the ``numba:compile`` event) and the errors of
  ``numba.core.errors`` (``NumbaError``, ``TypingError``).

Internal (undocumented), each with its fallback:

* :func:`entry_point`: a compiled overload's ``entry_point`` (``Dispatcher.overloads[types]``), the
  machine code's Python entry without the dispatcher's look at every argument's type (a third of a
  small robot's single call); fallback: the dispatcher itself.
* :func:`compiled_code`: a compiled overload (``Dispatcher.overloads[types]``), the record of the machine code a
  dispatcher runs for the types, which ``recompile()`` replaces; fallback: ``None`` (no record, so a caller
  that keeps what it made from the code makes it again).
* :func:`first_class`: ``CompileResultWAP`` of ``numba.core.types.function_type``, a compiled overload
  as a first-class function without a look-up per call; fallback: the dispatcher, compiled for the
  types, which Numba passes as a first-class function all the same.
* :func:`typed_by_types`: an override of ``Dispatcher.get_call_template`` (how compiled code types a
  call) that types constant arguments by their types, saving about 30 compiled specialisations of
  the kernels' helpers (:mod:`multibody.kernels.jit`); fallback: Numba's typing, by value.
* :func:`njit_without_runtime`: ``numba.njit``'s ``_nrt=False`` option (no reference-counted runtime,
  about 0.8 µs of every Panda call); fallback: ``numba.njit`` with its runtime.
* :func:`cached_on_disk`: the dispatcher's cache index file (``_cache._cache_file._index_path``),
  which tells without loading whether machine code is on disk; fallback: load the code
  (``Dispatcher.compile``) and read ``Dispatcher.stats.cache_hits``, which compiles what is missing.
* :func:`cache_directory`: ``numba.core.caching``'s cache locators, the folder Numba caches a
  package's machine code in; fallback: ``__pycache__`` beside the file.
"""

from __future__ import annotations

import os

import numba
from numba.core import event  # noqa: F401  (documented: Numba's Event API, re-exported for the driver)
from numba.core.errors import NumbaError, NumbaExperimentalFeatureWarning, TypingError  # noqa: F401  (documented, re-exported)
from numba.extending import is_jitted

#: The exceptions by which a missing or changed internal member shows itself.
_CHANGED = (AttributeError, ImportError, KeyError, TypeError)

try:
    from numba.core.types.function_type import CompileResultWAP
except ImportError:  # fallback: the dispatcher itself (first_class)
    CompileResultWAP = None


def njit_without_runtime(**options):
    """``numba.njit(**options)`` without Numba's reference-counted runtime (``_nrt=False``, internal);
    ``numba.njit(**options)`` where that option is refused."""
    try:
        return numba.njit(_nrt=False, **options)
    except _CHANGED:
        return numba.njit(**options)


def typed_by_types(dispatcher):
    """``dispatcher`` (a ``numba.njit`` function), whose calls from compiled code are typed by the
    types of constant arguments before their values (:mod:`multibody.kernels.jit`), by overriding its
    ``get_call_template`` (internal); left as it is where it has none (typing by value, the same
    numbers from more compiled specialisations)."""
    try:
        get_call_template = dispatcher.get_call_template
        unliteral = numba.types.unliteral
    except AttributeError:
        return dispatcher

    def typed(args, kws):
        plain = tuple(unliteral(a) for a in args)
        if plain != tuple(args):
            try:
                return get_call_template(plain, kws)
            except TypingError:
                pass  # the function needs the values
        return get_call_template(args, kws)

    dispatcher.get_call_template = typed
    return dispatcher


def entry_point(dispatcher, types):
    """``dispatcher`` compiled for the argument ``types`` (a tuple of Numba types), as a Python callable:
    the overload's entry point (internal), which takes arguments of those types without looking at them;
    the dispatcher itself where that is absent. A plain Python function (``NUMBA_DISABLE_JIT=1``) as it is."""
    if not is_jitted(dispatcher):
        return dispatcher
    dispatcher.compile(types)
    return getattr(compiled_code(dispatcher, types), "entry_point", dispatcher)


def compiled_code(dispatcher, types):
    """The compiled overload of ``dispatcher`` for the argument ``types`` (a tuple of Numba types): an object that
    stays the same until the dispatcher compiles those types again (``recompile()``), so that what was made from
    it is known to be current (internal, ``Dispatcher.overloads``); ``None`` where it is not compiled for them or
    that member is absent."""
    try:
        return dispatcher.overloads[tuple(types)]
    except _CHANGED:
        return None


def first_class(dispatcher, types):
    """``dispatcher`` compiled for the argument ``types``, as a first-class function value that compiled
    code whose argument is ``numba.types.FunctionType`` of that signature calls through a pointer:
    ``CompileResultWAP`` of the overload (internal), else the dispatcher (documented). A plain Python
    function (``NUMBA_DISABLE_JIT=1``) as it is."""
    if not is_jitted(dispatcher):
        return dispatcher
    dispatcher.compile(types)
    try:
        return CompileResultWAP(dispatcher.overloads[types])
    except _CHANGED:
        return dispatcher


def return_type(dispatcher, types):
    """The return type (a Numba type) of ``dispatcher`` compiled for the argument ``types``, from its
    documented ``nopython_signatures``; ``ValueError`` when it is not compiled for them."""
    for signature in dispatcher.nopython_signatures:
        if tuple(signature.args) == tuple(types):
            return signature.return_type
    raise ValueError(f"{getattr(dispatcher, '__name__', dispatcher)!r} is not compiled for {types}")


def cached_on_disk(dispatcher, types):
    """Whether Numba's on-disk cache holds machine code of ``dispatcher`` (a ``numba.njit(cache=True)``
    function) for ``types``. Read from the cache's index file (internal) without loading anything;
    where that is absent, from Numba's documented ``stats``: code this process has compiled or loaded
    already is on disk, and other code is loaded (``Dispatcher.compile``, which compiles it when
    missing) and was on disk when that was a cache hit."""
    try:
        index = dispatcher._cache._cache_file._index_path
    except AttributeError:
        pass
    else:
        return isinstance(index, str) and os.path.isfile(index)
    # code this process compiled or loaded already is on disk (Numba saved it); else loading it tells
    known = any(tuple(signature.args) == tuple(types) for signature in dispatcher.nopython_signatures)
    dispatcher.compile(types)
    stats = dispatcher.stats
    counts = [stats.cache_hits, stats.cache_misses] if known else [stats.cache_hits]
    return any(count.get(tuple(types), 0) > 0 for count in counts)


def cache_directory(function, file):
    """The folder where Numba caches the machine code of ``function`` defined in ``file`` (the path of
    its module), as Numba picks it (``NUMBA_CACHE_DIR``, else ``__pycache__`` beside the file, else the
    user-wide cache), from ``numba.core.caching``'s locators (internal); ``None`` where none is writable;
    ``__pycache__`` beside the file where the locators are absent."""
    try:
        from numba.core.caching import InTreeCacheLocator, UserProvidedCacheLocator, UserWideCacheLocator

        for locator in (UserProvidedCacheLocator, InTreeCacheLocator, UserWideCacheLocator):
            found = locator.from_function(function, file)
            if found is not None:
                return found.get_cache_path()
    except _CHANGED:
        return os.path.join(os.path.dirname(file), "__pycache__")
    return None
