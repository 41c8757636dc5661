"""Command line: ``multibody demo NAME`` (``--list``, ``--view``), ``multibody info URDF|MJCF|ROBOT``,
``multibody check URDF|MJCF|ROBOT``, ``multibody view URDF|MJCF|ROBOT [--trajectory FILE.npz]``,
``multibody compile [--all]``, ``multibody --version``. See ``multibody --help``.

Exit status: 0 on success; 1 when ``check`` finds a quantity that disagrees with Pinocchio; 2 on any
failure (a missing file, a directory, an unknown robot name, a malformed URDF or MJCF, a file that is not a
trajectory of the model, ...), which prints one line on standard error, ``multibody COMMAND: what is
wrong``, and no traceback; 141 (128 + SIGPIPE, what the shell reports for a program that a closed pipe
stops) when the reader of standard output goes away early (``multibody info talos | head``), quietly.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

import numpy as np

from . import __version__


class InputError(ValueError):
    """A command's input that names no URDF file or robot; :func:`main` prints it and exits with 2."""


def _urdf_path(source):
    """``(path, robot)``: the URDF file ``source`` names, and whether it named a robot
    (:func:`multibody.robots.path`: shipped models, and example-robot-data's when installed) rather
    than a file. Raises :class:`InputError` for a directory or a name that is neither."""
    from . import robots

    if os.path.isfile(source):
        return source, False
    try:
        return robots.path(source), True
    except (ValueError, ImportError) as error:
        if os.path.isdir(source):
            raise InputError(f"{source!r} is a directory; give a URDF file or a robot name") from None
        if os.path.dirname(source):  # a path, which no robot name is
            raise InputError(f"no such file: {source!r}") from None
        raise InputError(f"{source!r} is neither a URDF file nor a known robot: {error}") from None


# what info, view and check answer to --floating-base with an MJCF file
_MJCF_FLOATING_BASE = "--floating-base is for URDF files: an MJCF file gives its bodies their free joints"


def _load(source, floating_base, package_dirs):
    """The model of a URDF or MJCF file (its root element ``<mujoco>``) or a robot name (see
    :func:`_urdf_path`)."""
    from . import robots
    from .mjcf import is_mjcf_file, load_mjcf
    from .urdf import load_urdf

    path, robot = _urdf_path(source)
    if not robot and is_mjcf_file(path):
        if floating_base:
            raise InputError(_MJCF_FLOATING_BASE)
        return load_mjcf(path, package_dirs=package_dirs)
    if not robot:
        return load_urdf(path, floating_base=floating_base, package_dirs=package_dirs, invalid_inertia="warn")
    # A robot keeps the base and mesh folders robots.load gives it unless the command line says otherwise.
    options = {"floating_base": True} if floating_base else {}
    options.update({"package_dirs": package_dirs} if package_dirs else {})
    return robots.load(source, invalid_inertia="warn", **options)


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
    gravity = ", ".join(f"{g:.6g}" for g in model.gravity)
    print(f"  total mass = {model.total_mass:.6g} kg, gravity = [{gravity}] m/s^2")
    print("tree (joint [type, axis] -> links it moves, with masses):")
    for line in _tree_lines(model):
        print("  " + line)
    if model.mimic:
        print("mimic relations (kept as independent coordinates):")
        for mimic in model.mimic:
            print(f"  {mimic.joint} = {mimic.multiplier:g} * {mimic.mimicked} + {mimic.offset:g}")
    if model.equality_constraints:
        print("equality constraints (model.equality_constraints; pass them to mb.ConstrainedSystem):")
        for constraint in model.equality_constraints:
            print(f"  {constraint.name}: {_describe_constraint(constraint)}")
    messages = [str(w.message) for w in caught] + suspicious_inertias(model)
    for message in messages:
        print(f"warning: {message}")
    return 0


def _describe_constraint(constraint):
    """One line on a built-in constraint of a model file: its kind and what it joins."""
    from .constraints import JointCoupling, LoopClosure

    if isinstance(constraint, LoopClosure):
        return f"{constraint.kind} loop closure of {constraint.body_a or 'the world'} and {constraint.body_b or 'the world'}"
    if isinstance(constraint, JointCoupling):
        if constraint.joint_a is None:
            return f"{constraint.joint_b} held at {constraint.offset:g}"
        terms = " + ".join(f"{c:g}" if k == 0 else f"{c:g} x" if k == 1 else f"{c:g} x^{k}"
                           for k, c in enumerate(constraint.coefficients) if c)
        x = f"{constraint.joint_a} - {constraint.reference:g}" if constraint.reference else constraint.joint_a
        return f"{constraint.joint_b} = {terms or '0'} with x = {x}"
    return type(constraint).__name__


def cmd_check(args):
    from .mjcf import is_mjcf_file

    path, _ = _urdf_path(args.urdf)
    mjcf = is_mjcf_file(path)
    reference = "MuJoCo" if mjcf else "Pinocchio"
    try:
        __import__("mujoco" if mjcf else "pinocchio")
    except ImportError:
        print(f"multibody check: needs {reference}: pip install {'multibody[mjcf]' if mjcf else 'pin'}", file=sys.stderr)
        return 2
    if mjcf and args.floating_base:
        raise InputError(_MJCF_FLOATING_BASE)
    from .check import compare_with_mujoco, compare_with_pinocchio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if mjcf:
            model, rows, condition = compare_with_mujoco(path, args.samples, args.seed, args.package_dir)
        else:
            model, rows, condition = compare_with_pinocchio(path, args.floating_base, args.samples, args.seed,
                                                            args.package_dir)
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
    print(f"all quantities agree with {reference}")
    return 0


def cmd_demo(args):
    from .demos import DEMOS

    if args.list:
        width = max(len(name) for name in DEMOS)
        for name in sorted(DEMOS):
            print(f"{name:<{width}}  {DEMOS[name].__doc__.strip().splitlines()[0]}")
        return 0
    if args.name is None:
        print(f"multibody demo: give a demo name, or --list to list them: {', '.join(sorted(DEMOS))}", file=sys.stderr)
        return 2
    if args.name not in DEMOS:
        print(f"multibody demo: unknown demo {args.name!r}; available: {', '.join(sorted(DEMOS))}", file=sys.stderr)
        return 2
    from .demos import KERNELS
    from .driver import compile_kernels, compiled_before

    print(f"demo {args.name}: {DEMOS[args.name].__doc__.strip().splitlines()[0]}", flush=True)
    if not compiled_before(KERNELS):
        print("compiling multibody's kernels for this machine, on every core (first run only; about 25 s on two idle "
              "cores, longer on fewer or busy ones)", flush=True)
        compile_kernels(KERNELS)
    result = DEMOS[args.name](args.out)
    for key, value in result.summary.items():
        print(f"  {key}: {value:.3e}")
    for path in result.paths:
        print(f"  wrote {path}")
    if args.view:
        from .viewer import view

        return _serve(view(result.model, trajectory=result.trajectory, constraints=result.constraints,
                           port=args.port, trace=result.trace, title=f"multibody demo {args.name}"))
    return 0


def _serve(viewer, html=None):
    """Serve ``viewer`` until Ctrl-C, or, given ``html``, write its offline page there and stop."""
    import time

    try:
        with viewer:
            if html is not None:
                print(f"wrote {viewer.save_html(html)}")
                return 0
            print(f"3-D viewer at {viewer.url} (Ctrl-C to stop)", flush=True)
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt:
        return 0


def cmd_view(args):
    from .trajectory import Trajectory
    from .viewer import INSTALL_HINT

    try:
        import viser  # noqa: F401
    except ImportError:
        print(f"multibody view: {INSTALL_HINT}", file=sys.stderr)
        return 2
    from .viewer import view

    model = _load(args.urdf, args.floating_base, args.package_dir)
    trajectory = None
    if args.trajectory is not None:
        if os.path.isdir(args.trajectory):
            raise InputError(f"{args.trajectory!r} is a directory; give a trajectory file (.npz, Trajectory.save)")
        if not os.path.isfile(args.trajectory):
            raise InputError(f"no such file: {args.trajectory!r}")
        trajectory = Trajectory.load(args.trajectory, model=model)
    viewer = view(model, trajectory=trajectory, port=args.port, trace=args.trace,
                  title=f"multibody view {os.path.basename(args.urdf)}")
    return _serve(viewer, args.html)


def _compiled_by_default():
    """The kernels ``multibody compile`` compiles without ``--all``: those of the demos
    (:data:`multibody.demos.KERNELS`), then those of the common dynamics calls (inverse and forward
    dynamics, mass and Coriolis matrices, body placements and Jacobians) and of configuration arithmetic
    (integrate, difference, normalize); then the compiled loops (:func:`_loops`)."""
    from .demos import KERNELS
    from .kernels import aba, configuration, coriolis, crba, kinematics, rnea

    common = (rnea.inverse_dynamics, aba.forward_dynamics, crba.mass_matrix, coriolis.coriolis_matrix,
              kinematics.frame_placements, kinematics.frame_jacobian, configuration.integrate,
              configuration.difference, configuration.normalize)
    # (the demos' kernels first: heaviest first, so that compile_kernels deals them out evenly)
    return tuple(dict.fromkeys(KERNELS + common)) + _loops()


def _loops():
    """The compiled loops that ``multibody compile`` compiles with or without ``--all``, as ``(function, argument
    types)``: the batches' (:data:`multibody.driver.ENTRY_POINTS`), the fixed-step run's
    (:data:`multibody.integrators.ENTRY_POINTS`), the variational run's (:data:`multibody.variational.ENTRY_POINTS`)
    and the contact run's (:data:`multibody.contact.ENTRY_POINTS`), which a first batch, fixed-step, variational or
    contact simulation would compile."""
    from . import contact, driver, integrators, variational

    return driver.ENTRY_POINTS + integrators.ENTRY_POINTS + variational.ENTRY_POINTS + contact.ENTRY_POINTS


def cmd_compile(args):
    import time

    from numba.extending import is_jitted

    from . import driver

    which = ("every kernel and the loops of batches, fixed-step, variational and contact runs" if args.all else
             "the kernels of the demos and the common dynamics calls, and the loops of batches, fixed-step, variational "
             "and contact runs")
    kernels = driver.ALL_KERNELS + _loops() if args.all else _compiled_by_default()
    if not all(is_jitted(kernel) for kernel in driver.ALL_KERNELS):
        print("nothing to compile: NUMBA_DISABLE_JIT=1 runs the kernels as Python")
        return 0
    missing = [kernel for kernel in kernels if not driver.compiled_before((kernel,))]
    if not missing:
        print(f"{which}: all {len(kernels)} compiled already, in Numba's cache on disk")
        return 0
    print(f"{which}: compiling {len(missing)} of {len(kernels)} on every core "
          f"({len(kernels) - len(missing)} compiled already)", flush=True)
    start = time.perf_counter()
    driver.compile_kernels(missing)
    elapsed = time.perf_counter() - start
    failed = [kernel for kernel in missing if not driver.compiled_before((kernel,))]
    if failed:
        print(f"multibody compile: {len(failed)} of {len(missing)} functions did not compile (each compiles on its "
              f"first use instead): {', '.join(driver.qualified_name(kernel) for kernel in failed)}", file=sys.stderr)
        return 2
    print(f"compiled {len(missing)} functions in {elapsed:.1f} s; later processes load them from Numba's cache")
    return 0


def _model_arguments(command):
    """The arguments that name the model of ``info``, ``view`` and ``check``: a file or robot, and how to load it."""
    command.add_argument("urdf", metavar="URDF|MJCF|ROBOT", help="URDF or MJCF (.xml) file, or a robot name (e.g. "
                         "double_pendulum; example-robot-data's when installed)")
    command.add_argument("--floating-base", action="store_true", help="add a free-flyer joint at the root")
    command.add_argument("--package-dir", action="append", default=[], help="where package:// meshes live (repeatable)")


def build_parser():
    parser = argparse.ArgumentParser(
        prog="multibody", description="Rigid multibody dynamics from Lagrangian mechanics."
    )
    parser.add_argument("--version", action="version", version=f"multibody {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")

    info = commands.add_parser("info", help="print a model's tree, sizes, mass and suspicious inertias")
    _model_arguments(info)
    info.set_defaults(run=cmd_info)

    from .demos import DEMOS

    demo = commands.add_parser("demo", help=f"run a named demo and write its figures ({', '.join(sorted(DEMOS))})")
    demo.add_argument("name", nargs="?", help="demo name: " + ", ".join(sorted(DEMOS)))
    demo.add_argument("--list", action="store_true", help="list the demos, each with what it shows")
    demo.add_argument("--out", default="multibody_output", help="folder for the figures (default multibody_output)")
    demo.add_argument("--view", action="store_true", help="then show the motion in the 3-D viewer (needs Viser: pip install viser)")
    demo.add_argument("--port", type=int, default=8080, help="the viewer's port (default 8080; the next free one if taken)")
    demo.set_defaults(run=cmd_demo)

    view = commands.add_parser("view", help="show a model, or a saved trajectory of it, in the 3-D viewer (browser)")
    _model_arguments(view)
    view.add_argument("--trajectory", metavar="FILE.npz", help="a trajectory saved by Trajectory.save, to play")
    view.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; the next free one if taken)")
    view.add_argument("--trace", action="append", default=[], metavar="BODY",
                      help="draw the path of this body's origin (repeatable)")
    view.add_argument("--html", metavar="FILE.html",
                      help="write a self-contained page that replays it offline, and exit instead of serving")
    view.set_defaults(run=cmd_view)

    check = commands.add_parser("check", help="compare kinematics and dynamics with Pinocchio (MJCF: MuJoCo) at random "
                                              "states")
    _model_arguments(check)
    check.add_argument("--samples", type=int, default=20, help="number of random states (default 20)")
    check.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    check.set_defaults(run=cmd_check)

    compile_ = commands.add_parser(
        "compile", help="compile multibody's kernels for this machine ahead of first use, on every core",
        description="Compile multibody's Numba kernels into Numba's on-disk cache, sharing them among "
                    "worker processes (one per core), so that later runs start without compiling. Without "
                    "--all: the kernels the demos run, and those of the common dynamics calls (inverse and "
                    "forward dynamics, mass and Coriolis matrices, placements, Jacobians, configuration "
                    "arithmetic). With or without --all: the loops of batches and of fixed-step simulations. "
                    "Functions compiled already are skipped.")
    compile_.add_argument("--all", action="store_true", help="every kernel (derivatives, centroidal quantities, "
                          "inverse kinematics, the variational integrator, ...)")
    compile_.set_defaults(run=cmd_compile)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 0
        try:
            status = args.run(args)
            sys.stdout.flush()  # (so that a reader that has gone shows here, not at exit)
            return status
        except BrokenPipeError:
            raise
        except (ValueError, OSError) as error:  # malformed URDFs (URDFError), unknown names, bad paths and files
            message = str(error)
        except Exception as error:  # noqa: BLE001 (a failure of multibody itself: one line all the same)
            message = f"{type(error).__name__}: {error}"
    except BrokenPipeError:
        return _closed_pipe()
    print(f"multibody {args.command}: {message}", file=sys.stderr)
    return 2


def _closed_pipe():
    """Stop quietly after the reader of standard output has gone: status 141, as the shell reports for a
    program that SIGPIPE stops (128 + 13)."""
    # Python flushes standard output once more at exit, which must not fail again: it goes to devnull.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 141


if __name__ == "__main__":
    sys.exit(main())
