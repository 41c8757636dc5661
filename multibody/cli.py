"""Command line: ``multibody demo NAME``, ``multibody info URDF``, ``multibody check URDF``. See ``multibody --help``."""

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


def cmd_check(args):
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        print("multibody check needs Pinocchio: pip install pin", file=sys.stderr)
        return 2
    from . import robots
    from .check import compare_with_pinocchio

    path = args.urdf if os.path.exists(args.urdf) else robots.path(args.urdf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model, rows, condition = compare_with_pinocchio(path, args.floating_base, args.samples, args.seed, args.package_dir)
    print(f"{model.name}: nq = {model.nq}, nv = {model.nv}, {args.samples} random states, "
          f"largest cond(M) = {condition:.3g}")
    width = max(len(row.quantity) for row in rows)
    print(f"{'quantity':<{width}}  {'max rel. error':>14}  {'tolerance':>9}")
    for row in rows:
        print(f"{row.quantity:<{width}}  {row.error:14.3e}  {row.tolerance:9.1e}  {'ok' if row.ok else 'FAIL'}")
    failed = [row.quantity for row in rows if not row.ok]
    if failed:
        print(f"FAILED: {', '.join(failed)}")
        return 1
    print("all quantities agree with Pinocchio")
    return 0


def cmd_demo(args):
    from .demos import DEMOS

    if args.name not in DEMOS:
        print(f"unknown demo {args.name!r}; available: {', '.join(sorted(DEMOS))}", file=sys.stderr)
        return 2
    from .driver import compiled_before
    from .kernels import constraints, integration, kkt

    print(f"demo {args.name}: {DEMOS[args.name].__doc__.strip().splitlines()[0]}", flush=True)
    # the kernels a simulation with built-in constraints runs first
    if not compiled_before((integration.chart_derivative, kkt.constrained_accelerations, constraints.constraint_levels)):
        print("compiling multibody's kernels for this machine (first run only; a minute or two)", flush=True)
    summary, paths = DEMOS[args.name](args.out)
    for key, value in summary.items():
        print(f"  {key}: {value:.3e}")
    for path in paths:
        print(f"  wrote {path}")
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

    from .demos import DEMOS

    demo = commands.add_parser("demo", help=f"run a named demo and write its figures ({', '.join(sorted(DEMOS))})")
    demo.add_argument("name", help="demo name: " + ", ".join(sorted(DEMOS)))
    demo.add_argument("--out", default="multibody_output", help="folder for the figures (default multibody_output)")
    demo.set_defaults(run=cmd_demo)

    check = commands.add_parser("check", help="compare kinematics and dynamics with Pinocchio at random states")
    check.add_argument("urdf", help="URDF file, or the name of a shipped robot")
    check.add_argument("--floating-base", action="store_true", help="add a free-flyer joint at the root")
    check.add_argument("--samples", type=int, default=20, help="number of random states (default 20)")
    check.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    check.add_argument("--package-dir", action="append", default=[], help="where package:// meshes live (repeatable)")
    check.set_defaults(run=cmd_check)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return args.run(args)
    except (ValueError, FileNotFoundError) as error:  # malformed URDFs (URDFError), unknown names, bad paths
        print(f"multibody {args.command}: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
