"""Sphinx cross-reference roles in multibody's docstrings, rendered as links in the API reference.

The docstrings name other objects with Sphinx roles (``:class:`~multibody.model.Model```,
``:func:`view```), which read well in ``help()``. mkdocstrings renders docstrings as Markdown, where a
role would show literally, so this griffe extension (``mkdocs.yml``: the python handler's
``extensions``) rewrites each role when the package is loaded, before any page is rendered:

* into an autorefs link, ``[`Model`][multibody.model.Model]``, when its target has a section in the
  reference (a public object with a docstring, in a module that a page of ``docs/`` renders with
  ``::: module``); re-exported names (``multibody.simulate``) link to where the object is defined;
* into plain code, ``` `Model` ```, otherwise: private helpers, the compiled kernels, NumPy.

Targets are looked up as Sphinx does: from the object whose docstring names them outwards (its class,
its module, the package), then as full paths. ``~`` keeps the last component only; ``title <target>``
shows the title. The rewriting is :func:`convert`, which the tests run on every module's docstrings.
"""

from __future__ import annotations

import re
from pathlib import Path

import griffe

#: A Sphinx role of the Python domain: ``:kind:`target```, ``:kind:`~target``` or ``:kind:`title <target>```.
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):`(?P<body>[^`]+)`")
#: A fenced code block, left as written.
FENCE = re.compile(r"^[ \t]*```.*?^[ \t]*```[^\n]*$", re.DOTALL | re.MULTILINE)
#: The folder of the pages whose ``::: module`` lines say which modules have a reference page.
DOCS = Path(__file__).resolve().parent.parent


def documented_modules(docs=DOCS):
    """The modules that a page of ``docs`` renders (``::: multibody.dynamics``): a set of dotted paths."""
    found = set()
    for page in Path(docs).rglob("*.md"):
        for line in page.read_text(encoding="utf-8").splitlines():
            if line.startswith(":::"):
                found.add(line[3:].strip())
    return found


def convert(text, resolve):
    """``text`` with every Sphinx role rewritten as Markdown (fenced code blocks left alone).

    ``resolve(target)`` gives the dotted path of the reference section to link to, or ``None`` for a
    target without one, which is shown as code.
    """
    def rewrite(match):
        body = match["body"].strip()
        titled = re.fullmatch(r"(?P<title>.+?)\s*<(?P<target>[^<>]+)>", body)
        if titled:
            shown, target = titled["title"], titled["target"].strip()
        else:
            target = body.lstrip("~")
            shown = target.rsplit(".", 1)[-1] if body.startswith("~") else target
        path = resolve(target.lstrip("."))
        return f"[`{shown}`][{path}]" if path else f"`{shown}`"

    pieces, end = [], 0
    for fence in FENCE.finditer(text):
        pieces += [ROLE.sub(rewrite, text[end : fence.start()]), fence.group()]
        end = fence.end()
    return "".join(pieces) + ROLE.sub(rewrite, text[end:])


class Resolver:
    """Finds the reference section of a role's target, seen from the object whose docstring names it."""

    def __init__(self, package, documented):
        self.package = package
        self.documented = set(documented)

    def lookup(self, path):
        """The griffe object at dotted ``path`` under the package, or ``None``."""
        names = path.split(".")
        if names[0] != self.package.name:
            return None
        found = self.package
        try:
            for name in names[1:]:
                found = found.members[name]
        except (KeyError, griffe.AliasResolutionError, griffe.CyclicAliasError):
            return None
        return found

    def section(self, found):
        """The path of ``found``'s section in the reference, or ``None`` when it has none."""
        try:
            target = found.final_target if found.is_alias else found
        except (griffe.AliasResolutionError, griffe.CyclicAliasError):
            return None
        module = target if target.is_module else target.module
        if module.path not in self.documented:
            return None
        # every object from the module down is shown: public (the "!^_" filter) and documented
        node = target
        while node is not module:
            if (node.name.startswith("_") and node.name != "__init__") or not node.has_docstrings:
                return None
            node = node.parent
        return target.path

    def __call__(self, target, scope):
        """The section of ``target`` looked up from ``scope`` outwards, then as a full path."""
        while scope is not None:
            found = self.lookup(f"{scope.path}.{target}")
            if found is not None:
                return self.section(found)
            scope = scope.parent
        found = self.lookup(target)
        return None if found is None else self.section(found)


def objects_under(obj):
    """``obj`` and every object defined under it (aliases, which are documented where they point, skipped)."""
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from objects_under(member)


def convert_package(package, documented=None):
    """Rewrite the roles in the docstrings of ``package`` (a griffe module) and of everything under it."""
    resolver = Resolver(package, documented_modules() if documented is None else documented)
    for obj in objects_under(package):
        if obj.docstring is not None:
            obj.docstring.value = convert(obj.docstring.value, lambda target, obj=obj: resolver(target, obj))


class SphinxRoles(griffe.Extension):
    """The griffe extension: rewrites the roles once the package is loaded, when every target can be found."""

    def on_package(self, *, pkg, **kwargs):
        convert_package(pkg)
