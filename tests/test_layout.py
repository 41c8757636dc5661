"""The layout of multibody's modules: no module imports another module's private (underscore) name or reads a
private member of another module's objects, and the modules' imports (function-level ones included) form no cycle.

All are read from the source with ``ast``, without importing anything: ``from .x import _y`` and ``x._y`` on a
module ``x`` bound by an import count as private imports; ``obj._y`` or ``getattr(obj, "_y")`` on anything but
``self`` or ``cls``, where ``_y`` is a member of another module's classes and none of the module's own, as a private
member read (``multibody/numba_hooks.py`` reads Numba's internals by design: ``tests/test_private_members.py``);
every ``import``/``from ... import`` of a multibody module, wherever it stands in a file, is an edge of the import
graph.
"""

import ast
import pathlib
import textwrap

import multibody

PACKAGE = pathlib.Path(multibody.__file__).parent


def module_name(path):
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def _absolute(module, is_package, level, name):
    """The absolute name of ``from <level dots><name> import ...`` in ``module``."""
    if level == 0:
        return name
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _private(name):
    return name.startswith("_") and not name.startswith("__")


def imports(module, source=None, modules=MODULES):
    """``(edges, private)`` of one module (its text ``source``, default its file): the modules of ``modules`` it
    imports, and ``(line, name)`` of the private names it takes from other multibody modules."""
    path = modules[module]
    tree = ast.parse(path.read_text() if source is None else source)
    is_package = path.name == "__init__.py"
    edges, private, bound = set(), [], {}  # bound: local name -> the multibody module it stands for
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            source = _absolute(module, is_package, node.level, node.module)
            if source.split(".")[0] != "multibody":
                continue
            for alias in node.names:
                full = f"{source}.{alias.name}"
                if full in modules:  # a submodule
                    edges.add(full)
                    bound[alias.asname or alias.name] = full
                else:
                    edges.add(source)
                    if _private(alias.name):
                        private.append((node.lineno, full))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "multibody":
                    edges.add(alias.name)
                    if alias.asname:
                        bound[alias.asname] = alias.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound
                and _private(node.attr)):
            private.append((node.lineno, f"{bound[node.value.id]}.{node.attr}"))
    edges.discard(module)
    return {edge for edge in edges if edge in modules}, private


#: The functions that read or write a member named by a string: ``getattr(obj, "_y")`` is ``obj._y``.
_ATTRIBUTE_FUNCTIONS = ("getattr", "hasattr", "setattr", "delattr")


def _on_self(node):
    return isinstance(node, ast.Name) and node.id in ("self", "cls")


def _member_accesses(tree):
    """``(node, object, name)`` of each member access: ``obj.name`` and ``getattr(obj, "name", ...)`` (or
    ``hasattr``, ``setattr``, ``delattr``) with the name a string constant."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            yield node, node.value, node.attr
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _ATTRIBUTE_FUNCTIONS
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)):
            yield node, node.args[0], node.args[1].value


def own_members(source):
    """The private members of a module's own objects, from its text ``source``: the methods, nested classes and
    class attributes of its classes, and the attributes it sets on ``self`` or ``cls``. Its module-level names and
    local variables are no members."""
    tree = ast.parse(source)
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    own.add(item.name)
                elif isinstance(item, (ast.Assign, ast.AnnAssign)):
                    targets = item.targets if isinstance(item, ast.Assign) else [item.target]
                    own |= {name.id for target in targets for name in ast.walk(target) if isinstance(name, ast.Name)}
    for node, obj, name in _member_accesses(tree):
        stored = (isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del))
                  or isinstance(node, ast.Call) and node.func.id in ("setattr", "delattr"))
        if stored and _on_self(obj):
            own.add(name)
    return {name for name in own if _private(name)}


def private_members(source, others):
    """``(line, "obj._y")`` of each private member read or written in a module's text ``source`` on an object
    other than ``self`` or ``cls`` (``obj._y``, ``getattr(obj, "_y")``) where ``_y`` is a member of another
    module's objects (in ``others``, :func:`own_members` of the other modules) and not of this module's own. A
    name that both own is not found (``ast`` does not know the object's class); nor is a private member of
    another package's objects (``tests/test_private_members.py`` covers SciPy's and Numba's)."""
    tree = ast.parse(source)
    own = own_members(source)
    return sorted((node.lineno, f"{ast.unparse(obj)}.{name}") for node, obj, name in _member_accesses(tree)
                  if _private(name) and name in others and name not in own and not _on_self(obj))


#: The module that reads Numba's internals by design (``tests/test_private_members.py``).
NUMBA_HOOKS = "multibody.numba_hooks"
GRAPH = {}
PRIVATE = set()
WHERE = {}
OWN = {module: own_members(path.read_text()) for module, path in MODULES.items()}
MEMBERS = sorted(f"{MODULES[module].relative_to(PACKAGE.parent)}:{line}: {read}" for module in MODULES
                 if module != NUMBA_HOOKS for line, read in private_members(
                     MODULES[module].read_text(), set().union(*(OWN[other] for other in OWN if other != module))))
for _module in MODULES:
    GRAPH[_module], _found = imports(_module)
    for _line, _name in _found:
        PRIVATE.add((_module, _name))
        WHERE.setdefault((_module, _name), f"{MODULES[_module].relative_to(PACKAGE.parent)}:{_line}")


def cycles(graph):
    """The strongly connected components of more than one module (Tarjan's algorithm), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def connect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def test_no_module_imports_another_modules_private_names():
    new = sorted(PRIVATE)
    assert not new, "private imports (make the name public where it belongs, documented):\n" + "\n".join(
        f"{WHERE[found]}: {found[0]} imports {found[1]}" for found in new)


def test_no_module_reads_a_private_member_of_another_modules_objects():
    assert not MEMBERS, ("private members read on other modules' objects (move the code to the module that owns "
                         "the data, or make the member public, documented):\n" + "\n".join(MEMBERS))


def test_no_import_cycle():
    graph = GRAPH
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(
        " ".join(f"{m} -> {sorted(e for e in graph[m] if e in component)};" for m in component)
        for component in found)


def test_the_checker_finds_private_imports_and_function_level_edges():
    """The checks themselves, on a module's text: a private name imported or read off an imported module, and a
    function-level import, which is an edge of the graph as a top-level one is."""
    modules = {name: PACKAGE / "a.py" for name in ("multibody.a", "multibody.b", "multibody.c")}
    source = ("from .b import _hidden, shown\nfrom . import b as bee\n\n\ndef f():\n    from .c import x\n"
              "    return bee._other, bee.__name__\n")
    edges, private = imports("multibody.a", source, modules)
    assert edges == {"multibody.b", "multibody.c"}
    assert sorted(name for _, name in private) == ["multibody.b._hidden", "multibody.b._other"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_checker_finds_private_members_read_on_other_modules_objects():
    """A private member of another module's objects, read or written on an object (a name, an attribute, a call's
    result) or by ``getattr``, ``hasattr`` or ``setattr`` with its name, is found, whatever module-level name or local
    variable of the same name the module has; one on ``self`` or ``cls``, one the module's classes have too, another
    package's, a dunder and a public one are not."""
    source = textwrap.dedent("""\
        _rows = 3


        def _levels():
            return _rows


        class A:
            _kept = 1

            def f(self, model, other):
                self._own = model._state
                other._cache = {}
                return (other._own, self.system.model._rows, self._hidden, model.__class__, model.rows,
                        make()._made, other._kept, other._f, other._levels(), getattr(model, "_lagrangian", None),
                        hasattr(self, "_cache"), dynamicsymbols._t)

            def _f(cls):
                return cls._g
        """)
    assert own_members(source) == {"_kept", "_own", "_f"}
    others = {"_state", "_cache", "_own", "_rows", "_made", "_kept", "_f", "_levels", "_lagrangian", "_hidden"}
    assert private_members(source, others) == [(12, "model._state"), (13, "other._cache"),
                                               (14, "self.system.model._rows"), (15, "make()._made"),
                                               (15, "model._lagrangian"), (15, "other._levels")]


def test_every_eagerly_bound_name_of_the_api_is_in_all():
    """``from multibody import *`` gives every class and function of ``docs/api.md`` that ``import multibody``
    binds (the names of optional extras, such as ``mb.view``, load on first use and stay out)."""
    import re
    import types

    text = (PACKAGE.parent / "docs" / "api.md").read_text()
    bound = vars(multibody)
    names = {name for name in re.findall(r"`mb\.([A-Za-z_]\w*)", text)
             if name in bound and not isinstance(bound[name], types.ModuleType)}
    assert {"Ground", "ContactPair", "JointLimits"} <= names
    assert sorted(names - set(multibody.__all__)) == []


def test_no_outside_module_is_a_public_attribute():
    """``import multibody`` binds no module of another package under a public name (``mb.importlib`` would be
    one): every public module attribute is one of multibody's own."""
    import types

    outside = sorted(name for name, value in vars(multibody).items()
                     if isinstance(value, types.ModuleType) and not name.startswith("_")
                     and not value.__name__.startswith("multibody."))
    assert outside == []
