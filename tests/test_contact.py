"""Contact and joint limits (multibody.contact, multibody.kernels.timestepping): closed forms of the Moreau–Jean step.

Each closed form is checked against the step's own discrete values, derived in the test's docstring: with step
``dt`` the scheme is ``v_{k+1} = v_k + dt (M⁻¹ (τ − h) + κ) + M⁻¹ Jᵀ P``, ``q_{k+1} = chart(q_k, dt v_{k+1})``, so a
body under constant forces changes its velocity by exactly ``dt`` times its acceleration per step.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import multibody as mb
from multibody import contact, inertia
from multibody.joints import FreeFlyer

G = 9.81
DT = 1e-3
TOLERANCE = contact.TOLERANCE


def ball_model(radius=0.1, mass=1.0):
    b = mb.ModelBuilder("ball")
    b.add_body("ball", joint=FreeFlyer(), inertia=inertia.sphere(mass, radius))
    b.add_collision("ball", "sphere", radius)
    return b.build()


def box_model(size=(0.2, 0.2, 0.1), mass=1.0):
    b = mb.ModelBuilder("box")
    b.add_body("box", joint=FreeFlyer(), inertia=inertia.box(mass, size))
    b.add_collision("box", "box", size)
    return b.build()


@pytest.fixture(scope="module")
def ball():
    return ball_model()


@pytest.fixture(scope="module")
def box():
    return box_model()


def world_velocity(trajectory):
    """The world velocity of a free flyer's origin and its angular velocity, ``(n, 3)`` each (``v`` is in body
    axes; quaternions ``[x, y, z, w]``, as SciPy's)."""
    R = Rotation.from_quat(trajectory.q[:, 3:7]).as_matrix()
    return np.einsum("kij,kj->ki", R, trajectory.v[:, :3]), np.einsum("kij,kj->ki", R, trajectory.v[:, 3:6])


def test_ball_comes_to_rest(ball):
    """A ball dropped with e = 0.5 bounces a finite number of times, then rests on the ground (no Zeno chatter):
    from 2 s on it does not move (|v| ≤ 1e-9 m/s), its gap is 0 and the ground carries its weight."""
    system = mb.ConstrainedSystem(ball, [mb.Ground(restitution=0.5)])
    trajectory = mb.simulate(system, [0, 0, 0.6, 0, 0, 0, 1], np.zeros(6), 3.0, dt=DT)
    assert trajectory.status == "completed"
    # bounces: the vertical velocity turning from falling to rising (above the solver's tolerance)
    vz = trajectory.v[:, 2]
    signs = np.sign(vz[np.abs(vz) > 1e-6])
    assert 3 <= (np.diff(signs) > 0).sum() <= 20
    late = trajectory.t >= 2.0
    assert np.abs(trajectory.v[late]).max() <= 1e-9
    assert np.abs(trajectory.q[late, 2] - 0.1).max() <= 1e-12
    for entry in trajectory.contacts[-10:]:
        assert list(entry.body) == ["ball"] and list(entry.other) == ["ground"]
        np.testing.assert_allclose(entry.force.sum(axis=0), [0, 0, G], atol=1e-9)
    assert len(trajectory.contacts[0]) == 0 and trajectory.complementarity[0] == 0.0
    assert trajectory.complementarity.max() <= TOLERANCE


def test_bounce_apexes(ball):
    """Bounce apexes in the ratio e², within the step's discrete values.

    In flight, ``v_{k+1} = v_k − g dt`` and ``z_{k+1} = z_k + dt v_{k+1}``, so the samples lie on the parabola
    ``z(t) = z_k + (v_k − g dt/2) t − g t²/2`` whose apex ``H_k = z_k + (v_k − g dt/2)²/(2g)`` (``z`` the gap) is the
    same at every step of a flight. At the bounce step Newton's law gives ``v_{k+1} = −e v_k`` (``v_k`` the normal
    velocity at the step's start) and ``z_{k+1} = z_k − e v_k dt``, so the next apex is
    ``H' = z_k − e v_k dt + (e v_k + g dt/2)²/(2g)`` exactly, and
    ``H' − e² H = (1 − e²) z_k − e (1 − e) v_k dt/2 + (1 − e²) g dt²/8``, with ``0 ≤ z_k ≤ |v_k| dt``: the ratio is
    ``e²`` to ``O(dt)``."""
    e, radius = 0.8, 0.1
    system = mb.ConstrainedSystem(ball, [mb.Ground(restitution=e)])
    trajectory = mb.simulate(system, [0, 0, 1.0 + radius, 0, 0, 0, 1], np.zeros(6), 2.5, dt=DT)
    z, v = trajectory.q[:, 2] - radius, trajectory.v[:, 2]
    apex = z + (v - G * DT / 2) ** 2 / (2 * G)
    bounces = np.flatnonzero([len(c) and c.force[:, 2].max() > 0 for c in trajectory.contacts]) - 1
    bounces = bounces[np.r_[True, np.diff(bounces) > 1]]  # the first step of each contact
    assert len(bounces) >= 3
    for k in bounces[:3]:
        flight = slice(k - 50, k + 1)
        np.testing.assert_allclose(apex[flight], apex[k], rtol=0, atol=1e-12)
        predicted = z[k] - e * v[k] * DT + (e * v[k] + G * DT / 2) ** 2 / (2 * G)
        np.testing.assert_allclose(apex[k + 1], predicted, rtol=0, atol=1e-12)
        np.testing.assert_allclose(apex[k + 5], apex[k + 1], rtol=0, atol=1e-12)
        bound = (1 - e * e) * abs(v[k]) * DT + e * (1 - e) * abs(v[k]) * DT / 2 + G * DT**2 / 8
        assert abs(apex[k + 1] - e * e * apex[k]) <= bound
        assert abs(apex[k + 1] / apex[k] - e * e) <= 0.01


def slide_time_and_distance(v0, mu, dt):
    """The discrete slide on the flat: ``v_k = v₀ − k μ g dt`` until the step ``K = ⌈v₀/(μ g dt)⌉`` that ends at rest
    (a sticking contact), having moved ``dt Σ_{k=1}^{K−1} v_k``."""
    K = int(np.ceil(v0 / (mu * G * dt)))
    k = np.arange(1, K)
    return K, dt * np.sum(v0 - k * mu * G * dt)


@pytest.mark.parametrize("angle", [0.0, 0.3])
def test_box_slides_to_a_stop_on_a_straight_line(box, angle):
    """A box launched at v₀ along any direction on the flat decelerates by μ g and stops at v₀/(μ g) (its discrete
    stopping step and distance), on the line it was launched along: lateral deviation ≤ 1e-9 m (the cone is
    isotropic, not a pyramid)."""
    mu, v0 = 0.5, 2.0
    direction = np.array([np.cos(angle), np.sin(angle), 0.0])
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=mu)])
    trajectory = mb.simulate(system, [0, 0, 0.05, 0, 0, 0, 1], np.r_[v0 * direction, 0, 0, 0], 0.6, dt=DT)
    velocity, omega = world_velocity(trajectory)
    K, distance = slide_time_and_distance(v0, mu, DT)
    assert abs(K * DT - v0 / (mu * G)) <= DT
    speed = velocity @ direction
    k = np.arange(len(speed))
    np.testing.assert_allclose(speed, np.maximum(v0 - k * mu * G * DT, 0.0), rtol=0, atol=1e-11)
    assert np.abs(trajectory.v[K:]).max() <= 1e-9
    np.testing.assert_allclose(trajectory.q[-1, :3] @ direction, distance, rtol=0, atol=1e-11)
    lateral = trajectory.q[:, :2] @ np.array([-direction[1], direction[0]])
    assert np.abs(lateral).max() <= 1e-9
    assert np.abs(omega).max() <= 1e-9
    assert trajectory.complementarity.max() <= TOLERANCE


def incline(box, alpha, mu):
    """The box resting on the plane through the origin with normal ``(sin α, 0, cos α)``, and its trajectory."""
    normal = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    system = mb.ConstrainedSystem(box, [mb.Ground(normal=normal, friction=mu)])
    q0 = np.r_[0.05 * normal, 0.0, np.sin(alpha / 2), 0.0, np.cos(alpha / 2)]
    return mb.simulate(system, q0, np.zeros(6), 2.0, dt=DT)


def test_box_sticks_on_an_incline_without_creep(box):
    """μ > tan α: the box holds still, |v| ≤ 1e-9 m/s at every step for 2 s at dt = 1e-3 (no creep)."""
    alpha = 0.3
    trajectory = incline(box, alpha, mu=0.5)
    assert 0.5 > np.tan(alpha)
    assert np.abs(trajectory.v).max() <= 1e-9
    assert trajectory.complementarity.max() <= TOLERANCE


def test_box_slides_down_an_incline(box):
    """μ < tan α: the box slides with a = g (sin α − μ cos α) exactly, v_k = k a dt along the slope."""
    alpha, mu = 0.3, 0.2
    trajectory = incline(box, alpha, mu)
    velocity, _ = world_velocity(trajectory)
    downhill = np.array([np.cos(alpha), 0.0, -np.sin(alpha)])
    a = G * (np.sin(alpha) - mu * np.cos(alpha))
    np.testing.assert_allclose(velocity @ downhill, a * DT * np.arange(len(velocity)), rtol=0, atol=1e-11)
    np.testing.assert_allclose(velocity[:, 1], 0.0, atol=1e-12)
    assert trajectory.complementarity.max() <= TOLERANCE


def test_sliding_sphere_starts_to_roll(ball):
    """A sphere launched sliding at v₀ without spin decelerates by μ g and spins up by 5 μ g/(2 r) until it rolls, at
    the step ``K = ⌈2 v₀/(7 μ g dt)⌉`` (the closed form's 2v₀/(7μg) within a step); from then on it rolls at 5 v₀/7,
    its angular momentum about the contact point kept by every impulse there."""
    mu, v0, radius = 0.3, 2.0, 0.1
    system = mb.ConstrainedSystem(ball, [mb.Ground(friction=mu)])
    trajectory = mb.simulate(system, [0, 0, radius, 0, 0, 0, 1], [v0, 0, 0, 0, 0, 0], 0.5, dt=DT)
    velocity, omega = world_velocity(trajectory)
    K = int(np.ceil(2 * v0 / (7 * mu * G * DT)))
    assert abs(K * DT - 2 * v0 / (7 * mu * G)) <= DT
    k = np.arange(len(velocity))
    expected = np.where(k < K, v0 - k * mu * G * DT, 5 * v0 / 7)
    np.testing.assert_allclose(velocity[:, 0], expected, rtol=0, atol=1e-11)
    np.testing.assert_allclose(omega[:, 1] * radius, np.where(k < K, 2.5 * k * mu * G * DT, 5 * v0 / 7), atol=1e-11)
    # (the normal velocity of a sliding contact is zero to the solver's complementarity, |P·û|/‖P‖ ≤ tolerance,
    # which allows u_N up to tolerance · ‖P‖/P_N = tolerance · √(1 + μ²))
    np.testing.assert_allclose(velocity[:, 2], 0.0, atol=TOLERANCE * np.sqrt(1 + mu * mu))
    np.testing.assert_allclose(trajectory.q[:, 2], radius, atol=1e-12)


def test_stack_interface_forces_equal_the_weight_above():
    """Three boxes stacked on the ground: each interface carries the weight above it, to 1e-6 N, though each is
    four redundant corner contacts (a singular Delassus matrix)."""
    masses, h = [1.0, 2.0, 0.5], 0.1
    b = mb.ModelBuilder("stack")
    for i, m in enumerate(masses):
        b.add_body(f"box{i}", joint=FreeFlyer(), inertia=inertia.box(m, (0.2, 0.2, h)))
        b.add_collision(f"box{i}", "box", (0.2, 0.2, h))
    model = b.build()
    system = mb.ConstrainedSystem(model, [mb.Ground(friction=0.5), mb.ContactPair("box1", "box0", friction=0.5),
                                          mb.ContactPair("box2", "box1", friction=0.5)])
    q0 = np.concatenate([[0, 0, h / 2 + i * h, 0, 0, 0, 1] for i in range(3)])
    trajectory = mb.simulate(system, q0, np.zeros(18), 0.2, dt=DT)
    for entry in trajectory.contacts[1:]:
        for body, other, above in (("box0", "ground", 3.5), ("box1", "box0", 2.5), ("box2", "box1", 0.5)):
            rows = (entry.body == body) & (entry.other == other)
            assert rows.sum() >= 4
            np.testing.assert_allclose(entry.force[rows].sum(axis=0), [0, 0, above * G], atol=1e-6)
    assert np.abs(trajectory.v).max() <= 1e-9
    assert trajectory.complementarity.max() <= TOLERANCE


def test_limits_error_stops_a_contact_run_at_the_limit_contacts_and_residuals_too():
    """``limits="error"`` on a joint that no JointLimits holds, in a run with contact (a ball resting on the ground
    beside an arm swinging past its limit): one trajectory raises with the part up to the output time where the arm
    left, its contact entries and residuals cut there as its states are; in a batch that trajectory stops there with
    its residuals NaN and its contact entries empty after it, and the other trajectory is left as it ran."""
    b = mb.ModelBuilder("ball and arm")
    b.add_body("ball", FreeFlyer(), inertia=inertia.sphere(1.0, 0.1))
    b.add_collision("ball", "sphere", (0.1,))
    b.add_body("arm", mb.joints.Revolute((0, 1, 0)), inertia=inertia.box(1.0, (0.1, 0.1, 0.5)), lower=-0.2,
               upper=0.2)
    system = mb.ConstrainedSystem(b.build(), [mb.Ground(bodies=["ball"])])
    q0 = np.array([[0, 0, 0.1, 0, 0, 0, 1, 0.0]] * 2)
    v0 = np.zeros((2, 7))
    v0[0, 6] = 2.0  # the arm of trajectory 0 swings past 0.2 rad at t = 0.11 s
    free = mb.simulate(system, q0, v0, 0.3, dt=0.01, limits="ignore")
    with pytest.raises(mb.SimulationError, match="left its limits") as error:
        mb.simulate(system, q0[0], v0[0], 0.3, dt=0.01, limits="error")
    part = error.value.trajectory
    kept = len(part.t)
    assert 1 < kept < len(free.t) and part.q.shape[0] == part.complementarity.shape[0] == len(part.contacts) == kept
    assert list(part.contacts) == list(free.contacts[0][:kept])
    with pytest.warns(RuntimeWarning, match="1 of 2 trajectories stopped early"):
        batch = mb.simulate(system, q0, v0, 0.3, dt=0.01, limits="error")
    assert "left its limits" in batch.status[0] and batch.status[1] == "completed"
    np.testing.assert_array_equal(batch.complementarity[0, :kept], free.complementarity[0, :kept])
    assert np.isnan(batch.complementarity[0, kept:]).all() and np.isnan(batch.q[0, kept:]).all()
    assert batch.contacts[0][:kept] == free.contacts[0][:kept]
    assert len(free.contacts[0][-1]) == 1 and all(len(entry) == 0 for entry in batch.contacts[0][kept:])
    np.testing.assert_array_equal(batch.complementarity[1], free.complementarity[1])
    assert batch.contacts[1] == free.contacts[1]


@pytest.fixture(scope="module")
def panda():
    try:
        return mb.robots.load("panda")
    except (ImportError, FileNotFoundError) as error:
        pytest.skip(f"example-robot-data's Panda is not installed: {error}")


def test_joint_limits_hold_the_panda(panda):
    """The Panda falling under gravity from its neutral posture stays inside its limits at every step (to the
    solver's tolerance), each limit's generalized force pushing back into the range (negative at an upper limit)."""
    system = mb.ConstrainedSystem(panda, [mb.JointLimits()])
    q0 = np.clip(panda.neutral(), panda.lower, panda.upper)
    with warnings.catch_warnings():
        # (the limits enforced are not reported as left, where rounding puts q an ulp past one)
        warnings.simplefilter("error", mb.JointLimitWarning)
        trajectory = mb.simulate(system, q0, np.zeros(panda.nv), 1.5, dt=DT)
    assert (trajectory.q >= panda.lower - 1e-12).all() and (trajectory.q <= panda.upper + 1e-12).all()
    pushed = 0
    for q, entry in zip(trajectory.q[:-1], trajectory.contacts[1:]):
        assert set(entry.other) <= {"limit"}
        for joint, force in zip(entry.body, entry.force[:, 0]):
            iq = panda.idx_q[panda.joint_index(str(joint))]
            middle = (panda.lower[iq] + panda.upper[iq]) / 2
            assert force * (middle - q[iq]) >= 0.0
            pushed += force != 0.0
    assert pushed > 0
    assert trajectory.complementarity.max() <= TOLERANCE


@pytest.mark.parametrize("spin", [0.0, 30.0])
def test_energy_never_increases_at_impacts(ball, box, spin):
    """With e < 1 every step with a contact impulse (the impacts, and the sliding and rolling after them) loses
    energy or keeps it: the step adds none, nor does the position correction of penetration. A spinning ball thrown
    obliquely (slip and stick at impact), and a box dropped flat onto four redundant corners."""
    runs = [(ball, [mb.Ground(friction=0.3, restitution=0.6)], [0, 0, 0.5, 0, 0, 0, 1], [1.0, 0, -1.0, 0, spin, 0]),
            (box, [mb.Ground(friction=0.5, restitution=0.5)], [0, 0, 0.3, 0, 0, 0, 1], [0.4, 0.2, 0, 0, 0, spin])]
    for model, constraints, q0, v0 in runs:
        trajectory = mb.simulate(mb.ConstrainedSystem(model, constraints), q0, v0, 1.5, dt=DT)
        impacts = [k for k, entry in enumerate(trajectory.contacts) if len(entry) and np.abs(entry.force).max() > 0]
        assert len(impacts) > 10
        energy = trajectory.energy
        for k in impacts:
            assert energy[k] <= energy[k - 1] + 1e-12 * abs(energy[k - 1])
        assert energy[-1] < energy[0]
        assert trajectory.complementarity.max() <= TOLERANCE


@pytest.mark.parametrize("mu", [0.1, 0.4, 0.7, 1.0, 1.5])
def test_a_tumbling_box_lands_flat_and_comes_to_rest(box, mu):
    """A box thrown tumbling lands flat on four corners whose gaps are a little either side of zero (the step closes
    them to first order only). Its four normal rows are dependent (the corners' impulses ½(−1, 1, 1, −1) exert no
    force), so their bounds must stay affine in the corners' gaps, as the gaps themselves are, for the contact problem
    to have a solution near the others; with large μ its contacts are strongly coupled (two corners sliding slowly,
    two sticking). For every μ each step is solved to the tolerance, no step with a contact impulse adds energy (as in
    test_energy_never_increases_at_impacts: the impulses only dissipate), and the box comes to rest."""
    q0 = np.r_[0, 0, 0.4, Rotation.from_rotvec([0.4, 0.3, 0.0]).as_quat()]
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=mu)])
    trajectory = mb.simulate(system, q0, [0.5, 0, 0, 1.0, -2.0, 0.5], 1.5, dt=DT)
    assert trajectory.status == "completed"
    assert trajectory.complementarity[1:].max() <= TOLERANCE
    energy = trajectory.energy
    impacts = [k for k, entry in enumerate(trajectory.contacts) if len(entry) and np.abs(entry.force).max() > 0]
    assert len(impacts) > 1000
    for k in impacts:
        assert energy[k] <= energy[k - 1] + 1e-12 * abs(energy[k - 1])
    assert np.abs(trajectory.v[-1]).max() <= 1e-9
    assert len(trajectory.contacts[-1]) == 4 and trajectory.q[-1, 2] == pytest.approx(0.05, abs=1e-9)


def slab_and_box(hulls):
    """A fixed slab (1 m × 1 m × 0.1 m, top face at z = 0) and a free box (0.2 m × 0.2 m × 0.1 m, 1 kg) over it, as
    box shapes or as the convex hulls of their corners."""
    b = mb.ModelBuilder("slab and box")
    b.add_body("slab")
    b.add_body("box", joint=FreeFlyer(), inertia=inertia.box(1.0, (0.2, 0.2, 0.1)))
    slab = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.1, 0.0)])
    corners = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (-0.05, 0.05)])
    if hulls:
        b.add_collision("slab", "convex", vertices=slab)
        b.add_collision("box", "convex", vertices=corners)
    else:
        b.add_collision("slab", "box", (1.0, 1.0, 0.1), np.r_[np.c_[np.eye(3), [0, 0, -0.05]], [[0, 0, 0, 1]]])
        b.add_collision("box", "box", (0.2, 0.2, 0.1))
    return b.build()


def test_a_hull_box_rests_on_a_hull_slab_as_a_box_does():
    """A box made of the convex hull of its corners, dropped flat from 2 mm onto a hull slab (a face on a face: four
    clipped corners, not one GJK/EPA point to rock about), comes to rest: from 0.1 s on |v| ≤ 1e-9 m/s and its
    orientation does not drift (1e-12); its motion and contact forces are those of the same scene with box shapes."""
    q0 = np.r_[0.1, 0.05, 0.052, Rotation.from_euler("z", 0.2).as_quat()]
    runs = []
    for hulls in (True, False):
        system = mb.ConstrainedSystem(slab_and_box(hulls), [mb.ContactPair("box", "slab", friction=0.5)])
        runs.append(mb.simulate(system, q0, np.zeros(6), 0.5, dt=DT))
    hull, box = runs
    assert hull.status == "completed" and hull.complementarity.max() <= TOLERANCE
    settled = hull.t >= 0.1
    assert np.abs(hull.v[settled]).max() <= 1e-9
    assert np.abs(hull.q[settled, 3:] - q0[3:]).max() <= 1e-12
    np.testing.assert_allclose(hull.q, box.q, atol=1e-9)
    np.testing.assert_allclose(hull.v, box.v, atol=1e-9)
    assert len(hull.contacts[-1]) == 4
    np.testing.assert_allclose(hull.contacts[-1].force.sum(axis=0), [0, 0, G], atol=1e-9)


def test_a_cylinder_stands_on_a_hull_slab():
    """A cylinder (r 0.1 m, 0.2 m long) dropped from 2 mm onto a hull slab, standing on its cap: four rim points
    (its clipped cap), so it comes to rest, from 0.1 s on |v| ≤ 1e-9 m/s, without its orientation drifting."""
    b = mb.ModelBuilder("can on a slab")
    b.add_body("slab")
    b.add_body("can", joint=FreeFlyer(), inertia=inertia.cylinder(1.0, 0.1, 0.2))
    b.add_collision("slab", "convex", vertices=[[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.1, 0)])
    b.add_collision("can", "cylinder", (0.1, 0.2))
    q0 = np.r_[0.1, 0.05, 0.102, Rotation.from_euler("z", 0.2).as_quat()]
    system = mb.ConstrainedSystem(b.build(), [mb.ContactPair("can", "slab", friction=0.5)])
    trajectory = mb.simulate(system, q0, np.zeros(6), 0.5, dt=DT)
    assert trajectory.status == "completed" and trajectory.complementarity.max() <= TOLERANCE
    settled = trajectory.t >= 0.1
    assert np.abs(trajectory.v[settled]).max() <= 1e-9
    assert np.abs(trajectory.q[settled, 3:] - q0[3:]).max() <= 1e-12
    entry = trajectory.contacts[-1]
    assert len(entry) == 4
    np.testing.assert_allclose(np.hypot(*(entry.point[:, :2] - [0.1, 0.05]).T), 0.1, atol=1e-9)
    np.testing.assert_allclose(entry.force.sum(axis=0), [0, 0, G], atol=1e-9)


def test_batch_equals_single(ball):
    """A batch runs each trajectory on its own, on all cores: each equals its single run, bit for bit, contacts and
    residuals included."""
    system = mb.ConstrainedSystem(ball, [mb.Ground(friction=0.4, restitution=0.5)])
    q0 = np.array([[0.1 * r, 0, 0.2 + 0.1 * r, 0, 0, 0, 1] for r in range(4)])
    v0 = np.array([[0.3 * r, -0.2, 0, 0, 10.0 * r, -r] for r in range(4)], dtype=float)
    batch = mb.simulate(system, q0, v0, 0.4, dt=DT)
    assert batch.q.shape == (4, 401, 7) and batch.complementarity.shape == (4, 401)
    for r in range(4):
        single = mb.simulate(system, q0[r], v0[r], 0.4, dt=DT)
        assert np.array_equal(batch.q[r], single.q) and np.array_equal(batch.v[r], single.v)
        assert np.array_equal(batch.complementarity[r], single.complementarity)
        assert batch.contacts[r] == single.contacts
        assert batch.select(r).contacts == single.contacts


def test_controllers_inside_the_step(box):
    """Joint forces as an array, a Python callable (called at each step's start) and a numba.njit controller give
    the same trajectory: a box pushed with F < μ m g does not move, with F > μ m g accelerates by (F − μ m g)/m."""
    import numba

    mu = 0.5
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=mu)])
    q0 = [0, 0, 0.05, 0, 0, 0, 1]
    for force in (0.8 * mu * G, 1.5 * mu * G):
        tau = np.array([force, 0, 0, 0, 0, 0])

        @numba.njit
        def push(t, q, v, out):
            out[0] = force

        runs = [mb.simulate(system, q0, np.zeros(6), 0.3, dt=DT, tau=x) for x in (tau, lambda t, q, v: tau, push)]
        for run in runs[1:]:
            np.testing.assert_array_equal(run.q, runs[0].q)
        a = max(force - mu * G, 0.0)
        np.testing.assert_allclose(runs[0].v[:, 0], a * DT * np.arange(len(runs[0].t)), rtol=0, atol=1e-11)


def test_initial_penetration_is_projected_out(ball):
    """An initial state 1 cm into the ground is moved out with a warning giving the depth; it then rests."""
    system = mb.ConstrainedSystem(ball, [mb.Ground()])
    with pytest.warns(UserWarning, match=r"penetrates by 0\.01 "):
        trajectory = mb.simulate(system, [0, 0, 0.09, 0, 0, 0, 1], np.zeros(6), 0.1, dt=DT)
    np.testing.assert_allclose(trajectory.q[0, 2], 0.1, atol=1e-12)
    assert np.abs(trajectory.v).max() <= 1e-9


def test_zero_length_step_only_for_a_penetrating_initial_state(ball, monkeypatch):
    """The initial states' gaps come from one compiled detection call (the deepest gap, m; at most the margin): the
    zero-length step that projects a state out of penetration runs for the penetrating states of a batch alone,
    with the warning naming each; a state at rest on the ground or above it starts as given."""
    system = mb.ConstrainedSystem(ball, [mb.Ground()])
    program = contact.contact_program(system)
    q0 = np.array([[0, 0, z, 0, 0, 0, 1] for z in (0.1, 0.1005, 0.5, 0.09, 0.1 - 1e-11)])
    gaps = contact.initial_gaps(program, q0)
    np.testing.assert_allclose(gaps, [0.0, 5e-4, contact.MARGIN, -0.01, -1e-11], rtol=0, atol=1e-15)
    separated = []
    original = contact.separate_initial

    def counted(constrained, program, q):
        separated.append(q.copy())
        return original(constrained, program, q)

    monkeypatch.setattr(contact, "separate_initial", counted)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        resting = mb.simulate(system, q0[:3], np.zeros(6), 0.01, dt=DT)
    assert separated == [] and np.array_equal(resting.q[:, 0], q0[:3])
    with pytest.warns(UserWarning, match=r"the initial state \(trajectory 1\) penetrates by 0\.01 ") as caught:
        batch = mb.simulate(system, q0[2:], np.zeros(6), 0.01, dt=DT)
    assert len(caught) == 1 and len(separated) == 1 and np.array_equal(separated[0], q0[3])
    np.testing.assert_allclose(batch.q[1, 0, 2], 0.1, atol=1e-12)
    # (a gap of −1e-11 m is within the position correction's PENETRATION: left alone, as by the step itself)
    assert np.array_equal(batch.q[[0, 2], 0], q0[[2, 4]])


def test_energy_of_each_output_state_comes_from_the_steps(box):
    """Each step writes the energy of the state it starts from (its kinematics pass), the run computes the last
    state's: the trajectory's energy equals the system's energy of every output state bit for bit, through the
    compiled controller and a Python one, and a trajectory that stops has the energy of the states it reached, NaN
    after them."""
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])
    q0 = np.array([[0, 0, 0.05, 0, 0, 0, 1], [0.3, 0, 0.5, 0, 0, 0, 1]], dtype=float)
    v0 = np.array([[0.2, 0, 0, 0, 0, 1.0], [0, 0.1, 0, 0.5, 0, 0]])
    for tau in (None, lambda t, q, v: np.r_[0.1, 0, 0, 0, 0, 0.01 * t]):
        single = mb.simulate(system, q0[0], v0[0], 0.05, dt=DT, tau=tau)
        np.testing.assert_array_equal(single.energy, system.energy(single.q, single.v))
        assert np.isfinite(single.energy).all()
    # the resting box's first step does not finish in one iteration; the box in the air falls freely
    batch = contact.run(system, q0, v0, DT * np.arange(6), None, None, 2, max_iterations=1)
    assert batch.status[1] == "completed" and batch.status[0].startswith("the contact problem")
    np.testing.assert_array_equal(batch.energy[1], system.energy(batch.q[1], batch.v[1]))
    assert batch.energy[0, 0] == system.energy(q0[0], v0[0]) and np.isnan(batch.energy[0, 1:]).all()


def test_save_and_load_keep_contacts(ball, tmp_path):
    system = mb.ConstrainedSystem(ball, [mb.Ground(restitution=0.5)])
    trajectory = mb.simulate(system, [0, 0, 0.3, 0, 0, 0, 1], np.zeros(6), 0.5, dt=DT)
    loaded = mb.Trajectory.load(trajectory.save(tmp_path / "ball"), ball)
    assert loaded.contacts == trajectory.contacts
    np.testing.assert_array_equal(loaded.complementarity, trajectory.complementarity)
    batch = mb.simulate(system, [[0, 0, 0.3, 0, 0, 0, 1]] * 2, np.zeros(6), 0.2, dt=DT)
    loaded = mb.Trajectory.load(batch.save(tmp_path / "batch"), ball)
    assert loaded.contacts == batch.contacts


def test_bad_input_messages(ball, panda):
    with pytest.raises(ValueError, match=r"Ground: friction must be >= 0, got -0\.1"):
        mb.Ground(friction=-0.1)
    with pytest.raises(ValueError, match=r"Ground: restitution must be in \[0, 1\], got 1\.5"):
        mb.Ground(restitution=1.5)
    with pytest.raises(ValueError, match=r"ContactPair\('a', 'b'\): restitution must be in \[0, 1\], got -1"):
        mb.ContactPair("a", "b", restitution=-1)
    with pytest.raises(ValueError, match=r"ContactPair\('a', 'b'\): friction must be >= 0"):
        mb.ContactPair("a", "b", friction=-1)
    with pytest.raises(ValueError, match=r"JointLimits: restitution must be in \[0, 1\]"):
        mb.JointLimits(restitution=2.0)
    with pytest.raises(ValueError, match="Ground: normal must be a non-zero"):
        mb.Ground(normal=(0, 0, 0))
    with pytest.raises(ValueError, match="Ground: .*'bal'.*did you mean 'ball'"):
        mb.ConstrainedSystem(ball, [mb.Ground(bodies=["bal"])])
    b = mb.ModelBuilder("two")
    b.add_body("ball", joint=FreeFlyer(), inertia=inertia.sphere(1.0, 0.1))
    b.add_collision("ball", "sphere", 0.1)
    b.add_body("bare", joint=FreeFlyer(), inertia=inertia.sphere(1.0, 0.1))
    two = b.build()
    with pytest.raises(ValueError, match="Ground: body 'bare' has no collision geometry"):
        mb.ConstrainedSystem(two, [mb.Ground(bodies=["bare"])])
    with pytest.raises(ValueError, match=r"ContactPair\('ball', 'bare'\): body 'bare' has no collision geometry"):
        mb.ConstrainedSystem(two, [mb.ContactPair("ball", "bare")])
    with pytest.raises(ValueError, match="JointLimits: .*'panda_joint8'.*did you mean"):
        mb.ConstrainedSystem(panda, [mb.JointLimits(["panda_joint8"])])
    continuous = mb.ModelBuilder("wheel")
    continuous.add_body("wheel", joint=mb.joints.Continuous([0, 0, 1]), inertia=inertia.sphere(1.0, 0.1))
    with pytest.raises(ValueError, match="JointLimits: joint .* has no finite limit"):
        mb.ConstrainedSystem(continuous.build(), [mb.JointLimits([0])])
    system = mb.ConstrainedSystem(ball, [mb.Ground()])
    with pytest.raises(ValueError, match="method='RK4' cannot simulate contact or joint limits .*'Moreau-Jean'"):
        mb.simulate(system, [0, 0, 0.3, 0, 0, 0, 1], np.zeros(6), 0.1, dt=DT, method="RK4")


def test_bilateral_rows_in_the_same_solve(ball):
    """A ball on a massless rod (mb.Distance to a world pivot) swings into the ground: the rod's rows are solved
    with the contact, each step's end is projected onto them (|φ| ≤ 1e-12 m, |A v| ≤ 1e-12 m/s), the ground stops the
    ball (its gap ≥ 0), the rod's tension comes out in lam, and the energy never rises."""
    rod = mb.Distance("ball", None, 0.5, point_b=[0.0, 0.0, 0.55])
    system = mb.ConstrainedSystem(ball, [rod, mb.Ground(friction=0.5)])
    trajectory = mb.simulate(system, [0.5, 0, 0.55, 0, 0, 0, 1], np.zeros(6), 1.0, dt=DT)
    assert trajectory.residual.max() <= 1e-12
    assert trajectory.q[:, 2].min() >= 0.1 - 1e-12
    touching = [k for k, entry in enumerate(trajectory.contacts) if len(entry) and entry.force[:, 2].max() > 0]
    assert touching
    # the rod pulls while the ball swings free (a pendulum's tension m (g cos θ + v²/L) > 0 below the pivot's height)
    assert (trajectory.lam[2 : touching[0], 0] > 0).all()
    assert (np.diff(trajectory.energy) <= 1e-12).all()
    assert trajectory.complementarity.max() <= TOLERANCE


def test_the_contact_step_takes_the_systems_one_compiled_step(ball):
    """A contact run reads the bilateral rows as the constrained step has them (``ConstrainedSystem.compiled_step``):
    its tree, program and frames, and in its plan the projection's settings (``project``'s default tolerance and
    iterations, the position rows) and workspace; without bilateral rows it has no frames and no projection; rows
    evaluated in Python have no compiled step, and the run says so."""
    from multibody import constrained
    from multibody.kernels import timestepping as ts

    rod = mb.Distance("ball", None, 0.5, point_b=[0.0, 0.0, 0.55])
    system = mb.ConstrainedSystem(ball, [rod, mb.Ground(friction=0.5)])
    step, program = system.compiled_step, contact.contact_program(system)
    assert program.tree is step.tree and program.bilateral == 1
    np.testing.assert_array_equal(program.program, step.program)
    np.testing.assert_array_equal(program.frames, step.frames)
    np.testing.assert_array_equal(program.plan[int(program.plan[ts.PLAN_SETTINGS_START]) :], step.settings)
    np.testing.assert_array_equal(step.settings,
                                  [constrained.PROJECTION_TOLERANCE, constrained.PROJECTION_ITERATIONS, 1.0])
    assert program.plan[ts.PLAN_PROJECTION_WORKSPACE] == step.projection_workspace > 0
    free = contact.contact_program(mb.ConstrainedSystem(ball, [mb.Ground()]))
    assert free.frames.shape == (0, 13) and free.program.size == 0 and free.plan[ts.PLAN_PROJECTION_WORKSPACE] == 0
    python = mb.ConstrainedSystem(ball, [mb.Holonomic(lambda q, t: np.array([q[2] - 0.5])), mb.Ground()])
    with pytest.raises(ValueError, match=r"needs bilateral constraints with compiled rows \(built-in, fixed in time\)"):
        mb.simulate(python, [0, 0, 0.5, 0, 0, 0, 1], np.zeros(6), 0.01, dt=DT)


def test_elastic_collision_of_two_balls_exchanges_their_velocities():
    """Two equal balls without gravity, one moving at v₀ onto the other (mb.ContactPair, e = 1, frictionless): the
    step of the impact leaves the first at rest and the second at v₀ (momentum and energy kept exactly); the
    force is reported on body_a, along the normal from body_b into it."""
    b = mb.ModelBuilder("two balls", gravity=(0.0, 0.0, 0.0))
    for name in ("a", "b"):
        b.add_body(name, joint=FreeFlyer(), inertia=inertia.sphere(1.0, 0.1))
        b.add_collision(name, "sphere", 0.1)
    model = b.build()
    system = mb.ConstrainedSystem(model, [mb.ContactPair("a", "b", friction=0.0, restitution=1.0)])
    v0 = 2.0
    q0 = np.r_[0, 0, 0, 0, 0, 0, 1, 0.3, 0, 0, 0, 0, 0, 1]
    trajectory = mb.simulate(system, q0, np.r_[v0, 0, 0, 0, 0, 0, np.zeros(6)], 0.1, dt=DT)
    hit = next(k for k, entry in enumerate(trajectory.contacts) if len(entry) and np.abs(entry.force).max() > 0)
    np.testing.assert_allclose(trajectory.v[hit:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(trajectory.v[hit:, 6], v0, rtol=0, atol=1e-12)
    entry = trajectory.contacts[hit]
    np.testing.assert_allclose(entry.normal, [[-1.0, 0.0, 0.0]], atol=1e-12)
    # the impulse on a, −m v₀, over the step
    np.testing.assert_allclose(entry.force[0], [-v0 / DT, 0, 0], rtol=1e-12)
    assert list(entry.body) == ["a"] and list(entry.other) == ["b"]
    np.testing.assert_allclose(trajectory.energy, trajectory.energy[0], rtol=1e-12)
    assert trajectory.q[:, 7].min() - trajectory.q[:, 0].max() >= 0.2 - 1e-12


def test_python_controller_on_a_batch_equals_single_runs(box):
    """A Python callable on a batch is called once per step with the states of the trajectories still running;
    each trajectory equals its single run."""
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])

    def push(t, q, v):
        return np.where(np.arange(6) == 0, 6.0 * np.cos(10 * t), 0.0) * np.ones(q.shape[:-1] + (1,))

    q0 = np.array([[0, 0, 0.05, 0, 0, 0, 1], [0, 0, 0.05, 0, 0, 0, 1]], dtype=float)
    v0 = np.array([[0, 0, 0, 0, 0, 0], [0.5, 0, 0, 0, 0, 0]], dtype=float)
    batch = mb.simulate(system, q0, v0, 0.3, dt=DT, tau=push)
    for r in range(2):
        single = mb.simulate(system, q0[r], v0[r], 0.3, dt=DT, tau=push)
        np.testing.assert_array_equal(batch.q[r], single.q)
        np.testing.assert_array_equal(batch.v[r], single.v)


def test_initial_state_past_a_joint_limit_is_projected_back(panda):
    q0 = np.clip(panda.neutral(), panda.lower, panda.upper)
    iq = panda.idx_q[panda.joint_index("panda_joint4")]
    q0[iq] = panda.upper[iq] + 0.05
    system = mb.ConstrainedSystem(panda, [mb.JointLimits()])
    with pytest.warns(UserWarning, match=r"penetrates by 0\.05 ") as caught:
        trajectory = mb.simulate(system, q0, np.zeros(panda.nv), 0.01, dt=DT)
    assert len(caught) == 1
    assert (trajectory.q >= panda.lower - 1e-12).all() and (trajectory.q <= panda.upper + 1e-12).all()


def test_a_step_the_solver_does_not_finish_stops_the_run_before_it(box):
    """With too few iterations for a resting box's first step, the run stops before that step, its status naming
    the step, the tolerance and the residual: the trajectory holds the initial state, NaN after it, and the failed
    step's residual."""
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])
    trajectory = contact.run(system, np.array([[0, 0, 0.05, 0, 0, 0, 1.0]]), np.zeros((1, 6)), DT * np.arange(5),
                             None, None, None, max_iterations=1)
    assert trajectory.status.startswith("the contact problem of the step from t = 0 s did not reach the tolerance "
                                        "1e-12 m/s in 2 iterations (residual")
    assert np.isfinite(trajectory.q[0]).all() and np.isnan(trajectory.q[1:]).all()
    assert trajectory.complementarity[1] > TOLERANCE and np.isnan(trajectory.complementarity[2:]).all()


def test_contact_record_names_rows_and_reads_as_a_list():
    """``Trajectory.contacts`` of a run reads the compiled record: each step's first ``count`` rows, named (a body, a
    joint for a limit, ``"ground"``, ``"limit"``), arrays copied out of the record; indexing, negative indices,
    slices, iteration and ``==`` as a list's."""
    from types import SimpleNamespace

    from multibody.kernels import timestepping as ts
    from multibody.trajectory import Contacts

    program = SimpleNamespace(body_names=("base", "arm"), joint_names=("shoulder", "elbow"))
    records = np.zeros((1, 3, 4, ts.RECORD_COLUMNS))
    summaries = np.zeros((1, 3, ts.SUMMARY_COLUMNS))
    # step 1: the elbow's limit (a joint index and LIMIT), the arm on the ground; step 2: the arm on the base
    records[0, 1, 0, [ts.RECORD_BODY, ts.RECORD_OTHER, ts.RECORD_FORCE]] = 1, ts.LIMIT, -2.5
    records[0, 1, 1, : ts.RECORD_FORCE] = 1, ts.GROUND, 0.1, 0.2, 0.0, 0, 0, 1
    records[0, 1, 1, ts.RECORD_FORCE :] = 0.5, 0.0, 9.0
    records[0, 2, 0] = [1, 0, 1, 2, 3, 0, 0, -1, 0, 0, -4]
    records[0, 2, 1] = 7.0  # a row past the step's count: not read
    summaries[0, :, ts.SUMMARY_COUNT] = 0, 2, 1
    (record,) = contact.contact_records(records, summaries, program)
    expected = [Contacts(np.zeros(0, str), np.zeros(0, str), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))),
                Contacts(np.array(["elbow", "arm"]), np.array(["limit", "ground"]), np.array([[0, 0, 0], [0.1, 0.2, 0]]),
                         np.array([[0, 0, 0], [0, 0, 1.0]]), np.array([[-2.5, 0, 0], [0.5, 0, 9]])),
                Contacts(np.array(["arm"]), np.array(["base"]), np.array([[1.0, 2, 3]]), np.array([[0, 0, -1.0]]),
                         np.array([[0, 0, -4.0]]))]
    assert len(record) == 3 and [len(entry) for entry in record] == [0, 2, 1]
    assert record == expected and expected == record and list(record) == expected
    assert record[-1] is record[2] and record[1:] == expected[1:] and record[::-1] == expected[::-1]
    assert record != expected[:2] and record != expected[:2] + expected[:1]
    record[2].force[0, 2] = 0.0  # an entry's arrays are its own
    assert records[0, 2, 0, ts.RECORD_FORCE + 2] == -4.0
    with pytest.raises(IndexError, match="contacts index 3 out of range for 3 output times"):
        record[3]
    with pytest.raises(TypeError):
        record["1"]


@pytest.mark.parametrize("capacity", [1, 4, 10**6])
def test_records_widen_when_a_step_has_more_rows(box, monkeypatch, capacity):
    """Each output step's record starts at ``contact.RECORD_CAPACITY`` rows; a step with more contacts widens the
    run's records and the run goes on from that step: a batch of a box resting flat (4 corner contacts from the
    first step) and one landing flat later gives the same states and contacts, bit for bit, whatever the starting
    capacity, and the same as the single runs."""
    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])
    q0 = np.array([[0, 0, 0.05, 0, 0, 0, 1], [0.3, 0, 0.1, 0, 0, 0, 1]], dtype=float)
    v0 = np.zeros((2, 6))
    singles = [mb.simulate(system, q0[r], v0[r], 0.2, dt=DT) for r in range(2)]
    monkeypatch.setattr(contact, "RECORD_CAPACITY", capacity)
    batch = mb.simulate(system, q0, v0, 0.2, dt=DT)
    assert batch.status == ["completed", "completed"]
    for r in range(2):
        assert np.array_equal(batch.q[r], singles[r].q) and np.array_equal(batch.v[r], singles[r].v)
        assert batch.contacts[r] == singles[r].contacts
        counts = [len(entry) for entry in batch.contacts[r]]
        assert max(counts) == 4 and (r == 1) == (min(counts[1:]) == 0)


def box_stack():
    """Three boxes stacked on the ground, just above it (a ground item per box and two pairs; up to 8 contact points
    each), and their initial configuration."""
    b = mb.ModelBuilder("stack")
    for i in range(3):
        b.add_body(f"box{i}", joint=FreeFlyer(), inertia=inertia.box(1.0, (0.2, 0.2, 0.1)))
        b.add_collision(f"box{i}", "box", (0.2, 0.2, 0.1))
    system = mb.ConstrainedSystem(b.build(), [mb.Ground(friction=0.5), mb.ContactPair("box1", "box0", friction=0.5),
                                              mb.ContactPair("box2", "box1", friction=0.5)])
    return system, np.concatenate([[0.01 * i, 0, 0.05 + 0.1 * i + 0.002, 0, 0, 0, 1] for i in range(3)])


def test_step_workspace_follows_the_records():
    """A step's workspace is sized by its record's rows ``R`` (limits and contacts): room for ``c = min(C, R)``
    contacts and ``m = m_b + 3c + min(2L, R − c)`` rows, growing with ``R`` up to every row the plan can have
    (``C`` contact points, ``L`` limited coordinates) and no further."""
    from multibody.kernels import timestepping as ts

    system, _ = box_stack()
    program = contact.contact_program(system)
    C = ts.max_contacts(3, 2)  # a ground item per box, two pairs
    assert program.records == C == 40
    assert ts.row_capacity(0, 0, C, 8) == (8, 24) and ts.row_capacity(0, 0, C, 50) == (40, 120)
    # limits: their rows fill what the contacts leave of the record
    assert ts.row_capacity(2, 3, 4, 5) == (4, 2 + 12 + 1) and ts.row_capacity(2, 3, 4, 100) == (4, 2 + 12 + 6)
    floats = [program.workspaces(R)[0] for R in (1, 8, C, 10 * C)]
    assert floats[0] < floats[1] < floats[2] == floats[3]
    assert [program.workspaces(R)[1] for R in (1, 8, C, 10 * C)] == [2, 16, 80, 80]


@pytest.mark.parametrize("capacity", [1, 5])
def test_a_stack_whose_rows_outgrow_the_records_equals_the_wide_run(monkeypatch, capacity):
    """Records (and with them the step's workspaces) starting at ``capacity`` rows, fewer than a box stack's
    contacts, grow as the steps need them: the states, contacts and residuals equal, bit for bit, those of a run
    whose records hold every row from the start, single and batched."""
    system, q0 = box_stack()
    v0 = np.zeros(18)
    monkeypatch.setattr(contact, "RECORD_CAPACITY", 10**6)
    wide = mb.simulate(system, q0, v0, 0.05, dt=DT)
    monkeypatch.setattr(contact, "RECORD_CAPACITY", capacity)
    narrow = mb.simulate(system, q0, v0, 0.05, dt=DT)
    batch = mb.simulate(system, np.stack([q0, q0]), np.zeros((2, 18)), 0.05, dt=DT)
    assert wide.status == "completed" and max(len(entry) for entry in wide.contacts) >= 12
    runs = [(narrow.q, narrow.v, narrow.contacts, narrow.complementarity)] + \
        [(batch.q[r], batch.v[r], batch.contacts[r], batch.complementarity[r]) for r in range(2)]
    for q, v, contacts, residuals in runs:
        assert np.array_equal(q, wide.q) and np.array_equal(v, wide.v)
        assert contacts == wide.contacts and np.array_equal(residuals, wide.complementarity)


def test_joint_limit_rows_past_the_records_grow_them(panda, monkeypatch):
    """Joint limits' rows beyond the record's rows are counted, not written, and the run goes on with wider records
    from that step: the Panda falling onto its limits with records of one row equals the run with every row."""
    system = mb.ConstrainedSystem(panda, [mb.JointLimits()])
    # (the widest record: both limits of each limited coordinate)
    assert contact.contact_program(system).records == 2 * len(system.unilateral[0].limits) > 0
    q0 = np.clip(panda.neutral(), panda.lower, panda.upper)
    monkeypatch.setattr(contact, "RECORD_CAPACITY", 10**6)
    wide = mb.simulate(system, q0, np.zeros(panda.nv), 0.3, dt=DT)
    monkeypatch.setattr(contact, "RECORD_CAPACITY", 1)
    narrow = mb.simulate(system, q0, np.zeros(panda.nv), 0.3, dt=DT)
    assert wide.status == narrow.status == "completed" and max(len(entry) for entry in wide.contacts) >= 2
    assert np.array_equal(narrow.q, wide.q) and np.array_equal(narrow.v, wide.v)
    assert narrow.contacts == wide.contacts


def test_a_contact_runs_warnings_point_at_the_caller():
    """A contact run's warning of a joint limit it does not enforce, left, names the line that called ``simulate``,
    as a fixed-step run's does."""
    import os

    b = mb.ModelBuilder("limited pendulum")
    placement = np.eye(4)
    placement[2, 3] = 1.0
    b.add_body("bob", mb.joints.Revolute((0.0, 1.0, 0.0)), placement=placement, lower=[-0.1], upper=[0.1],
               inertia=inertia.sphere(1.0, 0.05).transformed(mb.spatial.pose_matrix(np.eye(3), [0.0, 0.0, -0.5])))
    b.add_collision("bob", "sphere", 0.05)
    model = b.build()
    system = mb.ConstrainedSystem(model, [mb.Ground()])
    with pytest.warns(mb.JointLimitWarning) as caught:
        mb.simulate(system, [0.05], [3.0], 0.05, dt=DT)
    assert [os.path.basename(w.filename) for w in caught if issubclass(w.category, mb.JointLimitWarning)] == \
        [os.path.basename(__file__)]


def recorded_updates(monkeypatch):
    """The times the contact runs tell their progress bars (``Progress.update``), in order; the bars work as
    before."""
    from multibody import runs

    told = []
    update = runs.Progress.update

    def recording(bar, t):
        told.append(t)
        update(bar, t)

    monkeypatch.setattr(runs.Progress, "update", recording)
    return told


def test_a_contact_runs_bar_moves_between_its_compiled_calls(ball, monkeypatch, capsys):
    """A contact run's compiled steps go in calls (``runs.FIRST_CHUNK`` steps, then about ``runs.CHUNK_SECONDS``
    each) and its bar is told the time after each, single or batched; a Python controller's run, after each step.
    ``progress=True`` draws the bar to its end; a run expected to take long opens it by itself where it is seen."""
    from multibody import runs

    system = mb.ConstrainedSystem(ball, [mb.Ground(friction=0.4, restitution=0.5)])
    steps = 3 * runs.FIRST_CHUNK
    q0, v0 = np.array([0, 0, 0.3, 0, 0, 0, 1.0]), np.array([0.5, 0, 0, 0, 1.0, 0])
    told = recorded_updates(monkeypatch)
    for start in (q0, np.stack([q0, q0 + 0.01])):
        trajectory = mb.simulate(system, start, v0, steps * DT, dt=DT, progress=False)
        assert len(told) >= 2 and told[0] == trajectory.t[runs.FIRST_CHUNK] and told[-1] == trajectory.t[-1]
        assert np.all(np.diff(told) > 0)
        told.clear()
    trajectory = mb.simulate(system, q0, v0, 10 * DT, dt=DT, tau=lambda t, q, v: np.zeros(6), progress=False)
    assert told == list(trajectory.t[1:])
    assert capsys.readouterr().err == ""

    mb.simulate(system, q0, v0, 0.1, dt=DT, progress=True)
    err = capsys.readouterr().err
    assert "simulate: 100%" in err and "t = 0.1/0.1 s" in err
    monkeypatch.setattr(runs, "PROGRESS_AFTER", 0.0)
    monkeypatch.setattr(runs, "_visible", lambda: True)
    slow = lambda t, q, v: __import__("time").sleep(0.001) or np.zeros(6)  # noqa: E731
    mb.simulate(system, q0, v0, 0.2, dt=DT, tau=slow)
    assert "simulate: 100%" in capsys.readouterr().err


def test_an_interrupt_between_calls_stops_a_contact_run(ball, monkeypatch):
    """A KeyboardInterrupt (Ctrl-C, which Python raises when a compiled call returns) raised where the bar is told
    the time after the first call stops the run there: no further compiled call, and the bar is closed."""
    from multibody import runs

    system = mb.ConstrainedSystem(ball, [mb.Ground(friction=0.4)])
    told, calls, closed = [], [], []

    def interrupt(bar, t):
        told.append(t)
        raise KeyboardInterrupt

    dispatch = contact._dispatch
    monkeypatch.setattr(runs.Progress, "update", interrupt)
    monkeypatch.setattr(runs.Progress, "close", lambda bar: closed.append(bar))
    monkeypatch.setattr(contact, "_dispatch", lambda *args, **kwargs: calls.append(args[3]) or dispatch(*args,
                                                                                                        **kwargs))
    q0 = np.array([0, 0, 0.3, 0, 0, 0, 1.0])
    for start in (q0, np.stack([q0, q0])):
        with pytest.raises(KeyboardInterrupt):
            mb.simulate(system, start, np.zeros(6), 1.0, dt=DT, progress=False)
        assert told == [runs.FIRST_CHUNK * DT] and len(calls) == 1 and len(closed) == 1
        told.clear(), calls.clear(), closed.clear()


def test_chunks_leave_the_steps_unchanged(box, monkeypatch):
    """The compiled calls' lengths change no step: runs in calls of 7 steps equal, bit for bit (states, contacts,
    residuals, statuses), the runs in one call, for a box stack whose records widen on the way and a batch whose
    trajectories stop at different steps (a contact problem not solved in the iterations allowed: the resting box
    at its first step, the falling one when it lands), whose stopped trajectory stays stopped."""

    def both(simulate):
        results = []
        for chunk in (10**6, 7):
            monkeypatch.setattr(contact, "FIRST_CHUNK", chunk)
            monkeypatch.setattr(contact, "next_chunk", lambda steps, seconds: chunk)
            results.append(simulate())
        return results

    system, q0 = box_stack()
    monkeypatch.setattr(contact, "RECORD_CAPACITY", 1)
    one, chunked = both(lambda: mb.simulate(system, q0, np.zeros(18), 0.1, dt=DT))
    assert one.status == "completed" and max(len(entry) for entry in one.contacts) >= 12
    assert np.array_equal(one.q, chunked.q) and np.array_equal(one.v, chunked.v)
    assert one.contacts == chunked.contacts and np.array_equal(one.complementarity, chunked.complementarity)

    system = mb.ConstrainedSystem(box, [mb.Ground(friction=0.5)])
    q0 = np.array([[0, 0, 0.05, 0, 0, 0, 1], [0.3, 0, 0.1, 0, 0, 0, 1]], dtype=float)
    one, chunked = both(lambda: contact.run(system, q0, np.zeros((2, 6)), DT * np.arange(200), None, None, 2,
                                            max_iterations=1))
    assert one.status == chunked.status and all(s.startswith("the contact problem of the step") for s in one.status)
    stops = [int(np.argmax(np.isnan(one.q[r, :, 0]))) for r in range(2)]
    assert stops[0] == 1 and 1 < stops[1] < 200
    assert np.array_equal(one.q, chunked.q, equal_nan=True) and np.array_equal(one.v, chunked.v, equal_nan=True)
    assert np.array_equal(one.complementarity, chunked.complementarity, equal_nan=True)
    assert [list(c) for c in one.contacts] == [list(c) for c in chunked.contacts]


def test_initial_states_off_the_bilateral_rows_are_projected_with_a_warning(ball):
    """A contact run projects its initial state onto the bilateral rows with the warning of the smooth runs, naming
    the distance and the coordinates that moved most (a batch: how many of its trajectories moved, by up to how
    much, in which one), pointing at the line that called ``simulate``, as its penetration warning does."""
    import os

    rod = mb.Distance("ball", None, 0.5, point_b=[0.0, 0.0, 0.55])
    system = mb.ConstrainedSystem(ball, [rod, mb.Ground(friction=0.5)])
    on = np.array([0.5, 0, 0.55, 0, 0, 0, 1])
    off = on + [0.01, 0, 0, 0, 0, 0, 0]
    with pytest.warns(UserWarning, match=r"initial state violated the constraints; projected onto them \(moved by "
                                         r"0\.01: q\[0\] \(joint 'ball_joint', m\) by 0\.01\)") as caught:
        single = mb.simulate(system, off, np.zeros(6), 0.05, dt=DT)
    assert [os.path.basename(w.filename) for w in caught] == [os.path.basename(__file__)]
    np.testing.assert_allclose(single.q[0], on, atol=1e-12)
    with pytest.warns(UserWarning, match=r"the initial states of 1 of 2 trajectories violated the constraints; "
                                         r"projected onto them \(moved by up to 0\.01, in trajectory 1\)") as caught:
        batch = mb.simulate(system, np.stack([on, off]), np.zeros(6), 0.05, dt=DT)
    assert [os.path.basename(w.filename) for w in caught] == [os.path.basename(__file__)]
    assert np.array_equal(batch.q[1], single.q)
    np.testing.assert_allclose(batch.q[0], batch.q[1], atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mb.simulate(system, on, np.zeros(6), 0.05, dt=DT)  # a state on the rows starts as given, silently
    with pytest.warns(UserWarning, match=r"penetrates by 0\.01 ") as caught:
        mb.simulate(mb.ConstrainedSystem(ball, [mb.Ground()]), [0, 0, 0.09, 0, 0, 0, 1], np.zeros(6), 0.01, dt=DT)
    assert [os.path.basename(w.filename) for w in caught] == [os.path.basename(__file__)]


def test_non_finite_state_or_joint_forces_are_named_by_joint(ball):
    """A contact run stopped by a non-finite state or non-finite joint forces names the coordinates, by joint and
    with their values, as the smooth runs do: the forces of a compiled controller, of a PD and of a batch's Python
    controller (the trajectory whose row is not finite), and a state that overflowed under finite forces."""
    import numba

    system = mb.ConstrainedSystem(ball, [mb.Ground()])
    q0 = np.array([0, 0, 100.0, 0, 0, 0, 1])

    @numba.njit
    def failing(t, q, v, out):
        if t >= 0.0045:
            out[2] = np.nan

    expected = r"the joint forces are not finite at t = 0\.005 s: tau\[2\] \(joint 'ball_joint', N\) = nan"
    with pytest.raises(mb.SimulationError, match=expected):
        mb.simulate(system, q0, np.zeros(6), 0.01, dt=DT, tau=failing)
    pd = mb.PD(np.r_[0, 1e308, 0, 0, 0, 0], np.zeros(6), q0 + [0, 10, 0, 0, 0, 0, 0])  # (1e309 N overflows)
    with pytest.raises(mb.SimulationError, match=r"the joint forces are not finite at t = 0 s: tau\[1\] \(joint "
                                                 r"'ball_joint', N\) = inf"):
        mb.simulate(system, q0, np.zeros(6), 0.01, dt=DT, tau=pd)

    def python(t, q, v):
        tau = np.zeros((2, 6))
        tau[1, 4] = np.inf if t >= 0.0045 else 0.0
        return tau

    with pytest.warns(RuntimeWarning, match="1 of 2 trajectories stopped early"):
        batch = mb.simulate(system, np.stack([q0, q0]), np.zeros(6), 0.01, dt=DT, tau=python)
    assert batch.status[0] == "completed"
    assert batch.status[1] == ("the joint forces are not finite at t = 0.005 s: tau[4] (joint 'ball_joint', N·m) = "
                               "inf")
    # finite forces that accelerate a light ball past the largest float
    light = mb.ConstrainedSystem(ball_model(mass=1e-6), [mb.Ground()])
    with pytest.raises(mb.SimulationError, match=r"the state is not finite at t = 0 s: q\[0\] \(joint 'ball_joint', "
                                                 r"m\) = nan, .*, v\[0\] \(joint 'ball_joint', m/s\) = nan"):
        mb.simulate(light, q0, np.zeros(6), 0.01, dt=DT, tau=np.r_[1.7e308, np.zeros(5)])


def test_a_batch_python_controller_sees_a_stopped_trajectory_at_its_last_state(ball):
    """A batch's Python controller is called with every trajectory's row; a trajectory stopped (here by its own
    non-finite joint forces at t = 0.005 s) is seen at its last state, as simulate's smooth batch passes it."""
    system = mb.ConstrainedSystem(ball, [mb.Ground()])
    q0 = np.array([0, 0, 100.0, 0, 0, 0, 1])
    seen = []

    def python(t, q, v):
        seen.append((t, q.copy(), v.copy()))
        tau = np.zeros((2, 6))
        tau[1, 4] = np.inf if t >= 0.0045 else 0.0
        return tau

    with pytest.warns(RuntimeWarning, match="1 of 2 trajectories stopped early"):
        batch = mb.simulate(system, np.stack([q0, q0]), np.zeros(6), 0.01, dt=DT, tau=python)
    after = [(q, v) for t, q, v in seen if t > 0.0045]
    assert len(after) == 5
    for q, v in after:
        np.testing.assert_array_equal(q[1], batch.q[1, 5])
        np.testing.assert_array_equal(v[1], batch.v[1, 5])
    assert np.isnan(batch.q[1, 6:]).all()


def test_a_last_state_whose_energy_overflows_keeps_the_trajectory_and_its_status():
    """A light ball pushed by 1e300 N reaches v ≈ 1e303 m/s after one step, whose energy overflows float64, and
    the next step's state is not finite: the run returns its trajectory with that status (its energy there NaN),
    and simulate raises SimulationError with it for one trajectory, as the smooth runs do."""
    light = mb.ConstrainedSystem(ball_model(mass=1e-6), [mb.Ground()])
    q0 = np.array([0, 0, 100.0, 0, 0, 0, 1])
    push = np.r_[1e300, np.zeros(5)]
    with pytest.raises(mb.SimulationError, match=r"the state is not finite at t = 0\.001 s") as raised:
        mb.simulate(light, q0, np.zeros(6), 0.01, dt=DT, tau=push)
    partial = raised.value.trajectory
    assert partial.status.startswith("the state is not finite at t = 0.001 s")
    assert np.isfinite(partial.v[1]).all() and np.abs(partial.v[1]).max() > 1e300
    assert np.isfinite(partial.energy[0]) and np.isnan(partial.energy[1:]).all()
    with pytest.warns(RuntimeWarning, match="2 of 2 trajectories stopped early"):
        batch = mb.simulate(light, np.stack([q0, q0]), np.zeros(6), 0.01, dt=DT, tau=push)
    assert batch.status == [partial.status] * 2
    np.testing.assert_array_equal(batch.v[0], partial.v)


def test_a_batch_initial_state_whose_projection_fails_stops_that_trajectory_alone(ball):
    """A batch's initial state that cannot be projected onto the bilateral rows (a rod whose two points coincide)
    stops its trajectory before its first step (its status says why, its outputs are NaN) while the others run as
    they do alone; a Python controller sees it at rest in the neutral configuration, as simulate's smooth batch
    does. One such state raises the projection's error."""
    rod = mb.Distance("ball", None, 0.5, point_b=[0.0, 0.0, 0.55])
    system = mb.ConstrainedSystem(ball, [rod, mb.Ground(friction=0.5)])
    on, coincident = np.array([0.5, 0, 0.55, 0, 0, 0, 1]), np.array([0, 0, 0.55, 0, 0, 0, 1.0])
    with pytest.raises(ValueError, match="the two points coincide"):
        mb.simulate(system, coincident, np.zeros(6), 0.01, dt=DT)
    seen = []

    def python(t, q, v):
        seen.append((q.copy(), v.copy()))
        return np.zeros((2, 6))

    single = mb.simulate(system, on, np.zeros(6), 0.01, dt=DT)
    for tau in (None, python):
        with pytest.warns(RuntimeWarning, match="1 of 2 trajectories stopped early"):
            batch = mb.simulate(system, np.stack([on, coincident]), np.zeros(6), 0.01, dt=DT, tau=tau)
        assert batch.status[0] == "completed"
        assert batch.status[1] == ("the projection onto the bilateral constraints failed at t = 0 s: distance "
                                   "ball-None: the two points coincide, so the rod has no direction")
        np.testing.assert_array_equal(batch.q[0], single.q)
        np.testing.assert_array_equal(batch.v[0], single.v)
        assert np.isnan(batch.q[1]).all() and np.isnan(batch.v[1]).all() and np.isnan(batch.energy[1]).all()
        # the rod's multiplier: the single run's where the trajectory ran, NaN where it never did
        np.testing.assert_array_equal(batch.lam[0], single.lam)
        assert batch.lam.shape == (2, len(single.t), 1) and np.isnan(batch.lam[1]).all()
        np.testing.assert_array_equal(batch.complementarity[0], single.complementarity)
        assert np.isnan(batch.complementarity[1]).all()
    assert len(seen) == 10
    for q, v in seen:
        np.testing.assert_array_equal(q[1], ball.neutral())
        np.testing.assert_array_equal(v[1], np.zeros(6))
