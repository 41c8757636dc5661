"""``njit`` for the kernels: Numba's, compiling a function once per argument *types*.

Numba compiles a function called from compiled code for the types of the call's arguments, and a
constant argument has a type of its own value: ``load3(x, 9)`` passes a ``Literal[int](9)``, so each
helper would be compiled once for every constant it is called with (``load3`` for 0, 3, 5, 9, 10,
12, …, ``subspace_column`` for each of the six columns), and once more for a variable. The value
is no use to the compiled code: Numba prunes no branch on it, and LLVM folds the constant once the
helper is inlined into its caller. So a call with constant arguments is typed by the constants'
types (``int64``, ``bool``), as Numba's ``@overload`` functions are typed by default, and by the
constants themselves only where the function does not compile for their types. The compiled
arithmetic, and so every number, is the same; the rolling-ball demo's first run compiles 125 functions instead of 155.

Both the typing by types and the compiling without the runtime reach into Numba's internals, which
:mod:`multibody.numba_hooks` holds with their fallbacks (typing by value; the runtime kept).
"""

from __future__ import annotations

from ..numba_hooks import njit_without_runtime, typed_by_types


def njit(**options):
    """``numba.njit(**options)``, with calls from compiled code typed as the module docstring says, and
    without Numba's reference-counted runtime.

    A kernel allocates nothing (it runs on a GPU too): its arrays are the caller's and views of them,
    so they need no reference counts. Without the runtime, a call from Python passes each array as
    its plain buffer instead of wrapping it in a counted block first, and no view inside a kernel
    counts references either: on Panda this takes about 0.8 µs off every call. A function then returns no bare
    array (Numba's rule, as there is no count to keep it alive): the kernels return views of their
    workspace in tuples. Two consequences for code that calls kernel functions:

    * compiled code *with* the runtime (Numba's default) may call only the functions that return no
      array, such as the kernels' entry points, as the driver's batch loop does: it would release a
      reference to a returned view that the kernel never took;
    * Python receives a returned view as the whole array it views (read the workspace instead).

    Under ``NUMBA_DISABLE_JIT=1``: the Python function, as ``numba.njit`` gives it."""
    def decorate(function):
        return typed_by_types(njit_without_runtime(**options)(function))

    return decorate
