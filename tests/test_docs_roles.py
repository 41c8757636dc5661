"""The API reference renders the docstrings' Sphinx roles as links (docs/hooks/sphinx_roles.py, the griffe
extension that mkdocs.yml names): no role is left in any module's docstrings once the package is loaded
as the site loads it, and each link points at a section of the reference. Skipped without the docs
extra (``pip install -e ".[docs]"``), which brings griffe; ``.ci/run`` also checks the built site."""

import importlib.util
import os

import pytest

griffe = pytest.importorskip("griffe")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HOOK = os.path.join(ROOT, "docs", "hooks", "sphinx_roles.py")


@pytest.fixture(scope="module")
def roles():
    spec = importlib.util.spec_from_file_location("sphinx_roles", HOOK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def package(roles):
    """multibody as the site loads it: with the extension, Google-style docstrings."""
    return griffe.load("multibody", search_paths=[ROOT], extensions=griffe.load_extensions(f"{HOOK}:SphinxRoles"),
                       docstring_parser="google")


def test_roles_become_links_or_code(roles):
    sections = {"multibody.model.Model": "multibody.model.Model", "view": "multibody.viewer.view",
                "multibody.dynamics": "multibody.dynamics"}
    text = ("A :class:`~multibody.model.Model`, :func:`view`, :mod:`multibody.dynamics`, "
            ":meth:`the model's chart <multibody.model.Model>`, :func:`_nice`, :class:`numpy.ndarray`.\n"
            "```python\nx = ':class:`Model`'\n```\n:py:class:`~multibody.model.Model`")
    assert roles.convert(text, sections.get) == (
        "A [`Model`][multibody.model.Model], [`view`][multibody.viewer.view], [`multibody.dynamics`][multibody.dynamics], "
        "[`the model's chart`][multibody.model.Model], `_nice`, `numpy.ndarray`.\n"
        "```python\nx = ':class:`Model`'\n```\n[`Model`][multibody.model.Model]")


def test_every_documented_module_the_pages_render_is_found(roles):
    documented = roles.documented_modules()
    assert "multibody.viewer" in documented and "multibody.dynamics" in documented
    # the mechanical-system interface (ModelSystem, Charts, CHART_TURN) that simulate and custom systems read
    assert "multibody.mechanical" in documented
    assert not any(module.startswith("multibody.kernels") for module in documented)


def test_targets_are_found_as_sphinx_finds_them(roles, package):
    resolve = roles.Resolver(package, roles.documented_modules())
    viewer = package["viewer"]
    # relative to the docstring's object: a method of its class, a function of its module
    assert resolve("save_html", viewer["Viewer"]) == "multibody.viewer.Viewer.save_html"
    assert resolve("Viewer.save_html", viewer["view"]) == "multibody.viewer.Viewer.save_html"
    # a re-exported name links to where the object is documented
    assert resolve("multibody.forward_kinematics", viewer) == "multibody.kinematics.forward_kinematics"
    # no section: a private helper, the compiled kernels, another package
    assert resolve("_nice", viewer) is None
    assert resolve("multibody.kernels.kkt", package["constrained"]) is None
    assert resolve("numpy.ndarray", viewer) is None


def test_no_role_is_left_in_any_docstring_and_links_point_at_sections(roles, package):
    import re

    resolve = roles.Resolver(package, roles.documented_modules())
    link = re.compile(r"\[`[^`]*`\]\[(?P<path>[\w.]+)\]")
    checked = 0
    for module in sorted(roles.documented_modules()):
        for obj in roles.objects_under(package[module.removeprefix("multibody.")]):
            if obj.docstring is None:
                continue
            text = obj.docstring.value
            assert not roles.ROLE.search(text), f"{obj.path}: {roles.ROLE.search(text).group()}"
            for found in link.finditer(text):
                target = resolve.lookup(found["path"])
                assert target is not None and resolve.section(target) == found["path"], (obj.path, found["path"])
                checked += 1
    assert checked > 150  # the docstrings' roles, now links
