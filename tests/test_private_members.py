"""No module of multibody subclasses or overrides a private member of SciPy or Numba, and only
multibody/numba_hooks.py imports Numba's internals (numba.core) or an underscore name of either."""

import ast
import importlib
import inspect
import pathlib
import pkgutil

import multibody

PACKAGE = pathlib.Path(multibody.__file__).parent
HOOKS = PACKAGE / "numba_hooks.py"
FOREIGN = ("scipy", "numba")

#: Members Python's abc module puts in every class of an abstract base, not code of ours.
ABC_MADE = {"_abc_impl"}
#: Private members of SciPy or Numba that multibody subclasses or overrides: none.
KNOWN = []


def _private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _foreign(module):
    return isinstance(module, str) and module.split(".")[0] in FOREIGN


def _dotted(node):
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    return ".".join([node.id] + parts[::-1]) if isinstance(node, ast.Name) else None


def _static_findings(path):
    """Imports of underscore names or of numba.core outside the hooks module, and assignments (``x._y = ...``,
    ``setattr(x, "_y", ...)``) to underscore attributes of names that come from SciPy or Numba."""
    module = "multibody." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts).removesuffix(".__init__")
    tree = ast.parse(path.read_text())
    foreign = set()  # local names bound to SciPy or Numba objects
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if _foreign(alias.name):
                    foreign.add((alias.asname or alias.name).split(".")[0])
                    if path != HOOKS and (any(map(_private, alias.name.split("."))) or alias.name.startswith("numba.core")):
                        found.append((module, alias.name, "imports"))
        elif isinstance(node, ast.ImportFrom) and _foreign(node.module):
            for alias in node.names:
                foreign.add(alias.asname or alias.name)
                if path != HOOKS and (_private(alias.name) or any(map(_private, node.module.split(".")))
                                      or node.module.startswith("numba.core")):
                    found.append((module, f"{node.module}.{alias.name}", "imports"))
    for node in ast.walk(tree):  # names assigned from SciPy's or Numba's objects
        if isinstance(node, ast.Assign):
            roots = {n.id for n in ast.walk(node.value) if isinstance(n, ast.Name)}
            if roots & foreign:
                foreign.update(t.id for t in node.targets if isinstance(t, ast.Name))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del)) and _private(node.attr):
            root = (_dotted(node.value) or "").split(".")[0]
            if root in foreign:
                found.append((module, f"{_dotted(node.value)}.{node.attr}", "assigns"))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("setattr", "delattr")
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and _private(str(node.args[1].value))
              and (_dotted(node.args[0]) or "").split(".")[0] in foreign):
            found.append((module, f"{_dotted(node.args[0])}.{node.args[1].value}", "assigns"))
        elif path != HOOKS and isinstance(node, ast.Attribute) and _dotted(node) == "numba.core":
            found.append((module, "numba.core", "imports"))
    return found


def _all_subclasses(cls):
    for sub in type.__subclasses__(cls):
        yield sub
        yield from _all_subclasses(sub)


def _class_findings():
    """Every class, static or made by ``type(...)``, with a class of multibody and a class of SciPy or Numba in its
    MRO: a private SciPy/Numba base, or an underscore member that a multibody class of the MRO defines and a
    SciPy/Numba class further along defines too."""
    for info in pkgutil.walk_packages(multibody.__path__, "multibody."):
        try:
            importlib.import_module(info.name)
        except ImportError:  # an optional dependency missing: the static scan still reads its source
            pass
    found = set()
    for cls in set(_all_subclasses(object)):
        mro = inspect.getmro(cls) if isinstance(cls, type) else ()
        ours = [c for c in mro if isinstance(c.__module__, str) and c.__module__.startswith("multibody.")]
        theirs = [c for c in mro if _foreign(c.__module__)]
        if not ours or not theirs:
            continue
        for base in cls.__bases__:
            if _foreign(base.__module__) and (_private(base.__name__) or any(map(_private, base.__module__.split(".")))
                                              and not _public_reexport(base)):
                found.add((f"{cls.__module__}.{cls.__qualname__}", f"{base.__module__}.{base.__name__}", "subclasses"))
        for owner in ours:
            later = mro[mro.index(owner) + 1:]
            for name in vars(owner):
                if _private(name) and name not in ABC_MADE and any(name in vars(c) for c in later if _foreign(c.__module__)):
                    found.add((f"{owner.__module__}.{owner.__qualname__}", name, "overrides"))
    return found


def _public_reexport(cls):
    """Whether a class defined in a private SciPy/Numba module is exported by a public one (``scipy.integrate.RK45``
    lives in ``scipy.integrate._ivp.rk``)."""
    parts = cls.__module__.split(".")
    for k in range(len(parts), 0, -1):
        public = ".".join(parts[:k])
        if not any(map(_private, parts[:k])):
            return getattr(importlib.import_module(public), cls.__name__, None) is cls
    return False


def test_no_module_subclasses_or_overrides_a_private_scipy_or_numba_member():
    findings = sorted(set(_class_findings()) | {f for path in sorted(PACKAGE.rglob("*.py"))
                                                 for f in _static_findings(path)})
    assert findings == KNOWN


def test_the_scan_finds_each_kind_of_private_use(tmp_path):
    """The static scan, on a module that does each thing it looks for (outside the hooks module)."""
    source = tmp_path / "bad.py"
    source.write_text("import numba\nfrom scipy.integrate._ivp import rk\nfrom numba.core.dispatcher import Dispatcher\n"
                      "d = numba.njit(lambda x: x)\nd._cache = None\nsetattr(rk.RK45, '_estimate_error_norm', None)\n"
                      "x = numba.core.config\n")
    global PACKAGE
    package, PACKAGE = PACKAGE, tmp_path
    try:
        kinds = sorted((what, kind) for _, what, kind in _static_findings(source))
    finally:
        PACKAGE = package
    assert kinds == [("d._cache", "assigns"), ("numba.core", "imports"),
                     ("numba.core.dispatcher.Dispatcher", "imports"), ("rk.RK45._estimate_error_norm", "assigns"),
                     ("scipy.integrate._ivp.rk", "imports")]
