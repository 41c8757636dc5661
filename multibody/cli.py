"""Command line: ``multibody info URDF`` (and more as the library grows). See ``multibody --help``."""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import numpy as np


def _load(source, floating_base, package_dirs):
    """A model from a URDF path or the name of a shipped robot."""
    from . import robots
    from .urdf import load_urdf

    path = source if os.path.exists(source) else None
    if path is None and source in robots.names():
        path = robots.path(source)
    if path is None:
        raise SystemExit(f"multibody: {source!r} is neither a URDF file nor a shipped robot ({', '.join(robots.names())})")
    return load_urdf(path, floating_base=floating_base, package_dirs=package_dirs, invalid_inertia="warn")


def _format_vector(x):
    return "[" + ", ".join(f"{value:.6g}" for value in np.asarray(x)) + "]"


def _tree_lines(model):
    """The joint tree, each moving joint with its type/axis and the links it carries."""
    def links_of(joint):
        parts = []
        # The first link of a joint is the one it moves directly; later ones hang from it by fixed joints.
        for k, b in enumerate(np.flatnonzero(model.body_joints == joint)):
            fixed = " (fixed)" if k > 0 or joint < 0 else ""
            parts.append(f"{model.body_names[b]}{fixed} {model.body_inertias[b].mass:.6g} kg")
        return ", ".join(parts) if parts else "no links"

    children = {i: [] for i in range(-1, model.njoints)}
    for i, parent in enumerate(model.parents):
        children[int(parent)].append(i)
    lines = [f"world: {links_of(-1)}"]

    def visit(joint, prefix, last):
        branch = "└── " if last else "├── "
        lines.append(f"{prefix}{branch}{model.joint_names[joint]} [{model.joints[joint].describe()}] -> {links_of(joint)}")
        kids = children[joint]
        for k, child in enumerate(kids):
            visit(child, prefix + ("    " if last else "│   "), k == len(kids) - 1)

    for k, root in enumerate(children[-1]):
        visit(root, "", k == len(children[-1]) - 1)
    return lines


def cmd_info(args):
    from .model import suspicious_inertias

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = _load(args.urdf, args.floating_base, args.package_dir)
    print(f"model {model.name!r}")
    print(f"  nq = {model.nq}, nv = {model.nv}, {model.njoints} moving joints, {model.nbodies} bodies")
    print(f"  total mass = {model.total_mass:.6g} kg, gravity = {_format_vector(model.gravity)} m/s^2")
    print("tree (joint [type, axis] -> links it moves, with masses):")
    for line in _tree_lines(model):
        print("  " + line)
    if model.mimic:
        print("mimic relations (kept as independent coordinates):")
        for mimic in model.mimic:
            print(f"  {mimic.joint} = {mimic.multiplier:g} * {mimic.mimicked} + {mimic.offset:g}")
    messages = [str(w.message) for w in caught] + suspicious_inertias(model)
    for message in messages:
        print(f"warning: {message}")
    return 0


def build_parser():
    parser = argparse.ArgumentParser(
        prog="multibody", description="Rigid multibody dynamics from Lagrangian mechanics."
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    info = commands.add_parser("info", help="print a model's tree, sizes, mass and suspicious inertias")
    info.add_argument("urdf", help="URDF file, or the name of a shipped robot (e.g. double_pendulum)")
    info.add_argument("--floating-base", action="store_true", help="add a free-flyer joint at the root")
    info.add_argument("--package-dir", action="append", default=[], help="where package:// meshes live (repeatable)")
    info.set_defaults(run=cmd_info)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
