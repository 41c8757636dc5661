"""The Whipple bicycle, built from the library's parts, against the benchmark of Meijaard et al. (2007).

Four rigid bodies: the rear frame with its rider (a free body), the rear wheel (a revolute joint on the
rear frame), the front frame, fork and handlebar (a revolute joint about the steer axis, tilted back by
the head angle λ from the vertical) and the front wheel (a revolute joint on the front frame). Each wheel
is a thin disc rolling without slipping on the ground (``mb.RollingDisc``): the bicycle has three degrees
of freedom of velocity (forward speed, lean rate, steer rate) and seven of position (x, y, yaw, lean,
steer and the wheels' angles; the pitch and the height follow from both wheels touching the ground).

The parameters are the benchmark's (J. P. Meijaard, J. M. Papadopoulos, A. Ruina and A. L. Schwab,
"Linearized dynamics equations for the balance and steer of a bicycle: a benchmark and review",
Proc. R. Soc. A 463 (2007) 1955–1982, Table 1). Linearized about the straight upright motion at speed
``v``, the lean and steer angles ``q = (φ, δ)`` obey their equations

    M q̈ + v C₁ q̇ + (g K₀ + v² K₂) q = 0,

whose eigenvalues against ``v`` are their Table 2: the weave pair turns stable at ``v_w`` = 4.29 m/s and
the capsize mode turns unstable at ``v_c`` = 6.02 m/s, so that the uncontrolled bicycle balances itself
between the two. The example linearizes the library's nonlinear model (``system.linearize``) at speeds
0 … 10 m/s and draws its eigenvalues over the benchmark's, and simulates the nonlinear motion at 5 m/s
recovering from a sideways push (a lean rate), and at 2 m/s falling over.
Run: python examples/whipple_bicycle.py [output_folder]
"""

import sys

import numpy as np
from scipy.linalg import expm, null_space
from scipy.optimize import brentq

import multibody as mb
from multibody.plotting import new_figure, save_figure

#: Meijaard et al. (2007), Table 1, in their axes (x forward, y to the right, z down): lengths in m,
#: masses in kg, inertias in kg m² about each body's centre of mass. The wheels' inertias are those of
#: discs, with I_zz = I_xx.
BENCHMARK = {
    "w": 1.02, "c": 0.08, "lam": np.pi / 10, "g": 9.81,
    "r_R": 0.3, "m_R": 2.0, "I_R": (0.0603, 0.12),
    "x_B": 0.3, "z_B": -0.9, "m_B": 85.0, "I_B": [[9.2, 0.0, 2.4], [0.0, 11.0, 0.0], [2.4, 0.0, 2.8]],
    "x_H": 0.9, "z_H": -0.7, "m_H": 4.0, "I_H": [[0.05892, 0.0, -0.00756], [0.0, 0.06, 0.0], [-0.00756, 0.0, 0.00708]],
    "r_F": 0.35, "m_F": 3.0, "I_F": (0.1405, 0.28),
}

#: The benchmark's axes in the library's (x forward, y to the left, z up): a half turn about x.
BENCHMARK_AXES = np.diag([1.0, -1.0, -1.0])


def build_bicycle(parameters=BENCHMARK):
    """The Whipple bicycle as a :class:`~multibody.constrained.ConstrainedSystem` on the ground ``z = 0``.

    Joints (``v`` in this order): the rear frame's free-flyer (``q`` its rear wheel centre (m) and
    orientation, ``v`` the linear (m/s) and angular (rad/s) velocity in its own axes), the rear wheel's
    angle (rad, positive rolling forward), the steer angle ``δ`` (rad, about the steer axis pointing
    down, so positive to the right as the benchmark's) and the front wheel's angle. Frames: x forward,
    y to the left, z up; at ``q = model.neutral()`` with the free-flyer at height ``r_R`` every body
    has the benchmark's reference pose (upright, steering straight, both wheels on the ground).
    Constraints: one :class:`~multibody.rolling.RollingDisc` per wheel (axis y), each with rows
    [friction along x, friction along y, normal] (multipliers in N).

    Returns ``(model, system)``.
    """
    p = parameters
    w, c, lam, r_R, r_F = p["w"], p["c"], p["lam"], p["r_R"], p["r_F"]

    def point(x, z):
        """A point of the benchmark's x–z plane in the library's axes (m)."""
        return BENCHMARK_AXES @ np.array([x, 0.0, z])

    def tensor(I):
        """An inertia tensor of the benchmark's axes in the library's (kg m²)."""
        return BENCHMARK_AXES @ np.asarray(I, float) @ BENCHMARK_AXES.T

    def wheel(mass, inertia):
        I_xx, I_yy = inertia
        return mb.Inertia(mass, np.zeros(3), np.diag([I_xx, I_yy, I_xx]))

    def translation(p_AB):
        return mb.spatial.pose_from_xyz_rpy(p_AB)

    rear_centre, front_centre = point(0.0, -r_R), point(w, -r_F)
    # The steer axis meets the ground the trail c ahead of the front contact, tilted back by λ; it points
    # down (benchmark: the steer angle is positive to the right). The front frame's joint frame sits on it
    # at the point closest to the front wheel's centre.
    steer_axis = BENCHMARK_AXES @ np.array([np.sin(lam), 0.0, np.cos(lam)])
    ground_point = point(w + c, 0.0)
    steer_point = ground_point + ((front_centre - ground_point) @ steer_axis) * steer_axis

    builder = mb.ModelBuilder("whipple bicycle", gravity=(0.0, 0.0, -p["g"]))
    builder.add_body("rear_frame", joint=mb.joints.FreeFlyer(), joint_name="rear_frame",
                     inertia=mb.Inertia(p["m_B"], point(p["x_B"], p["z_B"]) - rear_centre, tensor(p["I_B"])))
    builder.add_body("rear_wheel", joint=mb.joints.Revolute([0.0, 1.0, 0.0]), parent="rear_frame",
                     joint_name="rear_wheel", inertia=wheel(p["m_R"], p["I_R"]))
    builder.add_body("front_frame", joint=mb.joints.Revolute(steer_axis), parent="rear_frame", joint_name="steer",
                     placement=translation(steer_point - rear_centre),
                     inertia=mb.Inertia(p["m_H"], point(p["x_H"], p["z_H"]) - steer_point, tensor(p["I_H"])))
    builder.add_body("front_wheel", joint=mb.joints.Revolute([0.0, 1.0, 0.0]), parent="front_frame",
                     joint_name="front_wheel", placement=translation(front_centre - steer_point),
                     inertia=wheel(p["m_F"], p["I_F"]))
    model = builder.build()
    system = mb.ConstrainedSystem(model, [mb.RollingDisc("rear_wheel", r_R, axis=(0.0, 1.0, 0.0)),
                                          mb.RollingDisc("front_wheel", r_F, axis=(0.0, 1.0, 0.0))])
    return model, system


def upright_state(model, speed, lean_rate=0.0, parameters=BENCHMARK):
    """The straight upright motion at ``speed`` (m/s), leaning at ``lean_rate`` (rad/s, positive to the
    right) about the line through the wheels' contacts: ``(q (nq,), v (nv,))``, on the constraints.

    The rear frame's centre (the rear wheel's, at height ``r_R``) then moves at ``(speed, −r_R φ̇, 0)``
    in its axes, and each wheel spins at ``speed / r`` rad/s.
    """
    r_R, r_F = parameters["r_R"], parameters["r_F"]
    q = model.neutral()
    q[2] = r_R
    v = np.zeros(model.nv)
    v[:3] = [speed, -r_R * lean_rate, 0.0]
    v[3] = lean_rate
    v[6], v[8] = speed / r_R, speed / r_F
    return q, v


def lean_and_steer(q):
    """Lean ``φ`` (rad, positive to the right) and steer ``δ`` (rad) of configurations ``q (..., nq)``.

    The rear frame's orientation is the benchmark's yaw–lean–pitch sequence, ``R = R_z(−ψ) R_x(φ) R_y(−θ)``
    in the library's axes, whose third row is ``(−cos φ sin θ, sin φ, cos φ cos θ)``.
    """
    R = mb.spatial.quat_to_rotation(q[..., 3:7])
    return np.arcsin(R[..., 2, 1]), q[..., 8]


# ----------------------------------------------------------------------------- the benchmark's equations

#: The benchmark's coefficient matrices of ``M q̈ + v C₁ q̇ + (g K₀ + v² K₂) q = 0`` for the parameters of
#: Table 1, as the paper gives them (coordinates φ, δ; M in kg m², C₁ in kg m, K₀ in kg m, K₂ in kg).
PUBLISHED_MATRICES = {
    "M": np.array([[80.81722, 2.31941332208709], [2.31941332208709, 0.29784188199686]]),
    "C1": np.array([[0.0, 33.86641391492494], [-0.85035641456978, 1.68540397397560]]),
    "K0": np.array([[-80.95, -2.59951685249872], [-2.59951685249872, -0.80329488458618]]),
    "K2": np.array([[0.0, 76.59734589573222], [0.0, 2.65431523794604]]),
}
#: The benchmark's weave and capsize speeds (m/s), Table 2: the uncontrolled bicycle is stable between them.
WEAVE_SPEED, CAPSIZE_SPEED = 4.29238253634111, 6.02426201538837


def benchmark_state_matrix(speed, matrices=PUBLISHED_MATRICES, g=BENCHMARK["g"]):
    """The benchmark's first-order matrix ``(4, 4)`` of the state ``(φ, δ, φ̇, δ̇)`` at ``speed`` (m/s).

    From the benchmark's equations, ``q̈ = −M⁻¹ ((g K₀ + v² K₂) q + v C₁ q̇)``; its eigenvalues are the roots of
    ``det(M s² + v C₁ s + g K₀ + v² K₂) = 0`` (1/s).
    """
    M, C1, K0, K2 = (matrices[name] for name in ("M", "C1", "K0", "K2"))
    stiffness = np.linalg.solve(M, g * K0 + speed**2 * K2)
    damping = np.linalg.solve(M, speed * C1)
    return np.block([[np.zeros((2, 2)), np.eye(2)], [-stiffness, -damping]])


def benchmark_eigenvalues(speed, matrices=PUBLISHED_MATRICES, g=BENCHMARK["g"]):
    """The four eigenvalues (1/s) of the benchmark's lean and steer at ``speed`` (m/s), sorted by real part."""
    return np.sort_complex(np.linalg.eigvals(benchmark_state_matrix(speed, matrices, g)))


# ----------------------------------------------------------------------------- the model's linearization

def steady_motion_directions(linearization, parameters=BENCHMARK):
    """The six directions ``(p + k, 6)`` of ``[s; u]`` along which a straight upright motion stays one.

    Moving the bicycle along x or y, turning it about the vertical through the rear contact, or turning
    a wheel on its axle (``δq`` of the rear frame's free-flyer in its own axes, or of a wheel's joint, with
    ``δv = 0``), and rolling faster (``δq = 0``, ``δv`` the rates of 1 m/s more) each give another straight
    upright motion. ``A`` maps the shifts along x and y and the wheels' turns to zero, the turn about the
    vertical to a drift along y (``v`` per rad: the bicycle heads elsewhere) and the speed to a drift along
    x and the wheels' angles: these six span an invariant subspace of ``A`` on which it is nilpotent, and
    carry its six zero eigenvalues. Their coordinates are those of ``linearization.coordinates``.
    """
    nv = linearization.position_basis.shape[0]
    dq, dv = np.zeros((6, nv)), np.zeros((6, nv))
    dq[0, 0] = dq[1, 1] = dq[2, 5] = 1.0   # x, y (m) and yaw about z (rad) of the rear frame
    dq[3, 6] = dq[4, 8] = 1.0              # the wheels' angles (rad)
    dv[5, [0, 6, 8]] = 1.0, 1.0 / parameters["r_R"], 1.0 / parameters["r_F"]
    return linearization.coordinates(dq, dv).T


def lean_steer_matrix(linearization, parameters=BENCHMARK):
    """``A`` of ``linearization`` on the lean and steer alone: ``(4, 4)``, whose eigenvalues are those of
    ``A`` but for the six zeros of the steady-motion directions (:func:`steady_motion_directions`).

    Those directions span an invariant subspace ``Z`` of ``A``; in an orthonormal basis ``[Z Q]``, ``A`` is
    block upper triangular, and ``Qᵀ A Q`` is the map ``A`` induces on the rest.
    """
    Z = steady_motion_directions(linearization, parameters)
    Q = null_space(Z.T)
    return Q.T @ linearization.A @ Q


def upright_linearization(system, speed, parameters=BENCHMARK):
    """``system.linearize`` about the straight upright motion at ``speed`` (m/s)."""
    q, v = upright_state(system.model, speed, parameters=parameters)
    return system.linearize(q, v)


def lean_steer_eigenvalues(system, speed, parameters=BENCHMARK):
    """The four lean and steer eigenvalues (1/s) of the model at ``speed`` (m/s), sorted by real part."""
    linearization = upright_linearization(system, speed, parameters)
    return np.sort_complex(np.linalg.eigvals(lean_steer_matrix(linearization, parameters)))


def stable_speed_range(system, weave_bracket=(3.0, 5.0), capsize_bracket=(5.0, 8.0), xtol=1e-13):
    """The model's weave and capsize speeds (m/s): where the largest real part of its lean and steer
    eigenvalues crosses zero (:func:`scipy.optimize.brentq` in each bracket)."""
    def growth(speed):
        return lean_steer_eigenvalues(system, speed).real.max()

    return (brentq(growth, *weave_bracket, xtol=xtol, rtol=4 * np.finfo(float).eps),
            brentq(growth, *capsize_bracket, xtol=xtol, rtol=4 * np.finfo(float).eps))


# ----------------------------------------------------------------------------- the nonlinear motion

def push(system, speed, lean_rate, duration, dt=0.01, parameters=BENCHMARK):
    """The nonlinear motion (DOP853) from the straight upright motion at ``speed`` (m/s) given a sideways
    push, a lean rate ``lean_rate`` (rad/s): a :class:`~multibody.trajectory.Trajectory` with outputs every
    ``dt`` s up to ``duration`` s."""
    q0, v0 = upright_state(system.model, speed, lean_rate, parameters)
    return mb.simulate(system, q0, v0, duration, dt=dt, method="DOP853", rtol=1e-10, atol=1e-12)


def benchmark_response(speed, lean_rate, t):
    """Lean and steer ``(2, n)`` (rad) at times ``t (n,)`` (s) by the benchmark's linear equations, from the
    push of :func:`push`: ``x(t) = exp(A t) (0, 0, φ̇₀, 0)``."""
    A = benchmark_state_matrix(speed)
    x0 = np.array([0.0, 0.0, lean_rate, 0.0])
    return np.array([expm(A * time) @ x0 for time in t])[:, :2].T


# ----------------------------------------------------------------------------- the figure

def main(out="output", speeds=None, pushes=((5.0, 0.5, 10.0), (2.0, 0.1, 1.7))):
    """Linearize the bicycle at ``speeds`` (m/s; default 0, 0.25, …, 10), simulate two ``pushes``, each
    ``(speed (m/s), lean rate (rad/s), duration (s))``, and draw the figure ``whipple_bicycle.png`` into
    ``out``. Returns the path and a dict of what was measured."""
    speeds = np.linspace(0.0, 10.0, 41) if speeds is None else np.asarray(speeds, float)
    _, system = build_bicycle()
    ours = np.array([lean_steer_eigenvalues(system, speed) for speed in speeds])
    fine = np.linspace(speeds.min(), speeds.max(), 401)
    published = np.array([benchmark_eigenvalues(speed) for speed in fine])
    weave, capsize = stable_speed_range(system)
    summary = {"weave speed (m/s)": weave, "capsize speed (m/s)": capsize,
               "weave speed error (m/s)": weave - WEAVE_SPEED, "capsize speed error (m/s)": capsize - CAPSIZE_SPEED,
               "largest eigenvalue difference (1/s)": float(max(
                   np.abs(mine - benchmark_eigenvalues(speed)).max() for mine, speed in zip(ours, speeds)))}

    figure = new_figure((15.0, 4.6))
    axes = figure.subplots(1, 3)
    axis = axes[0]
    axis.axvspan(WEAVE_SPEED, CAPSIZE_SPEED, color="tab:green", alpha=0.1, lw=0)
    # Dots rather than lines: sorted by real part, the roots swap places where two branches cross.
    along = np.broadcast_to(fine[:, None], published.shape)
    oscillating = np.abs(published.imag) > 0
    axis.plot(along.ravel(), published.real.ravel(), ".", color="lightsteelblue", ms=5,
              label="benchmark (published M, C₁, K₀, K₂): real part")
    axis.plot(along[oscillating], np.abs(published.imag[oscillating]), ".", color="peachpuff", ms=5,
              label="benchmark: |imaginary part|")
    along = np.broadcast_to(speeds[:, None], ours.shape)
    oscillating = np.abs(ours.imag) > 0
    axis.plot(along.ravel(), ours.real.ravel(), "o", color="tab:blue", ms=2.5, label="library model: real part")
    axis.plot(along[oscillating], np.abs(ours.imag[oscillating]), "o", color="tab:orange", ms=2.5,
              label="library model: |imaginary part|")
    for speed, name in ((weave, "$v_w$"), (capsize, "$v_c$")):
        axis.axvline(speed, color="k", lw=0.8, ls=":")
        axis.annotate(f"{name} = {speed:.4f} m/s", (speed, 9.5), rotation=90, ha="right", va="top", fontsize=8)
    axis.axhline(0.0, color="k", lw=0.5)
    axis.set_ylim(-10.0, 10.0)
    axis.set_xlabel("forward speed v (m/s)")
    axis.set_ylabel("eigenvalue (1/s)")
    axis.set_title("lean and steer eigenvalues (Meijaard et al. 2007)")
    axis.legend(loc="lower right", fontsize=7)

    for axis, (speed, lean_rate, duration) in zip(axes[1:], pushes):
        trajectory = push(system, speed, lean_rate, duration)
        lean, steer = lean_and_steer(trajectory.q)
        linear = benchmark_response(speed, lean_rate, trajectory.t)
        drift = float(np.ptp(trajectory.energy) / np.abs(trajectory.energy).max())
        summary[f"{speed:g} m/s: energy drift (relative)"] = drift
        summary[f"{speed:g} m/s: largest |lean| (rad)"] = float(np.abs(lean).max())
        summary[f"{speed:g} m/s: final |lean| (rad)"] = float(abs(lean[-1]))
        axis.plot(trajectory.t, lean, color="tab:blue", label="lean φ")
        axis.plot(trajectory.t, steer, color="tab:red", label="steer δ")
        axis.plot(trajectory.t, linear[0], color="tab:blue", lw=0.8, ls="--", label="lean, benchmark's linear equations")
        axis.plot(trajectory.t, linear[1], color="tab:red", lw=0.8, ls="--", label="steer, benchmark's linear equations")
        axis.axhline(0.0, color="k", lw=0.5)
        # the linear response of an unstable motion grows without bound: the nonlinear one sets the scale
        reach = 1.15 * max(np.abs(lean).max(), np.abs(steer).max())
        axis.set_ylim(-reach, reach)
        axis.set_xlabel("t (s)")
        axis.set_ylabel("angle (rad)")
        axis.set_title(f"push of φ̇ = {lean_rate:g} rad/s at {speed:g} m/s "
                       f"({'self-stable' if WEAVE_SPEED < speed < CAPSIZE_SPEED else 'weave unstable: falls'})")
        axis.legend(loc="lower left", fontsize=7)
    path = save_figure(figure, out, "whipple_bicycle", dpi=110)
    return path, summary


if __name__ == "__main__":
    path, summary = main(sys.argv[1] if len(sys.argv) > 1 else "output")
    for key, value in summary.items():
        print(f"{key}: {value:.15g}" if "speed (m/s)" in key else f"{key}: {value:.3g}")
    print("wrote", path)
