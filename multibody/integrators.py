"""Fixed-step and adaptive methods and controllers of :func:`multibody.simulate`, and the compiled runs that take every
step.

A fixed-step method is a table of coefficients (:class:`Tableau`): an explicit partitioned Runge–Kutta method on
the chart state ``y = [δ, w]`` (E. Hairer, C. Lubich and G. Wanner, *Geometric Numerical Integration*, 2nd ed.,
Springer 2006, §II.2.2). :func:`tableau_step` takes one step of it in Python, with the rates as a function;
:class:`CompiledRun` takes all the steps of a trajectory (or of ``N`` of them, on all cores) in one call of
:mod:`multibody.kernels.stepping`, with the same arithmetic, where the system's step is compiled and the joint
forces are data (:class:`PD`), compiled (a ``numba.njit`` function ``f(t, q, v, out)``) or Python (one call
per stage).

An adaptive method is an embedded Runge–Kutta pair with a dense output (:class:`EmbeddedPair`, :data:`EMBEDDED`: RK23,
RK45, DOP853); :class:`AdaptiveRun` takes all its steps with step-size control in one call of
:func:`multibody.kernels.stepping.adaptive`, compiled where the fixed-step run is, else the same function run as Python
with the system's maps.
"""

from __future__ import annotations

import copy
import inspect
import weakref
from dataclasses import dataclass

import numba
import numpy as np
from numba import prange, types

from . import driver, numba_hooks
from .driver import TREE_FLOATS, TREE_INTS
from .numba_hooks import NumbaError
from .kernels import joints as kinds
from .kernels import stepping
from .model import Model
from .tree import FRAME_SIZE, REAL_SIZE, CompiledTree


# ============================================================================= methods


@dataclass(frozen=True)
class Tableau:
    """An explicit partitioned Runge–Kutta method of ``s`` stages (Hairer, Lubich & Wanner, *Geometric Numerical
    Integration*, §II.2.2) on ``y = [δ, w]``: stage ``i`` at ``t₀ + c_i h`` has ``δ_i = δ₀ + h Σ_j
    a_position[i][j] δ̇_j`` and ``w_i = w₀ + h Σ_j a_velocity[i][j] ẇ_j`` (``j < i``), and the step ends at
    ``δ⁺ = δ₀ + h Σ_i b_position[i] δ̇_i``, ``w⁺ = w₀ + h Σ_i b_velocity[i] ẇ_i``. ``order``: its order of
    accuracy."""

    c: tuple
    a_position: tuple
    a_velocity: tuple
    b_position: tuple
    b_velocity: tuple
    order: int

    @property
    def stages(self) -> int:
        return len(self.c)

    @property
    def needs_acceleration(self) -> tuple:
        """Whether each stage's ``ẇ`` enters a later stage or the end; a stage whose does not evaluates only
        ``δ̇ = chart_rate(δ, w)``, without the dynamics."""
        s = self.stages
        return tuple(self.b_velocity[i] != 0.0 or any(self.a_velocity[j][i] != 0.0 for j in range(i + 1, s))
                     for i in range(s))

    def __post_init__(self):
        # (every run of an immutable tableau reads the same coefficients: one block, read-only as runs share it)
        block = np.concatenate([np.ravel(x) for x in (self.c, self.a_position, self.a_velocity, self.b_position,
                                                      self.b_velocity, self.needs_acceleration)]).astype(float)
        block.setflags(write=False)
        object.__setattr__(self, "_block", block)

    def block(self) -> np.ndarray:
        """The coefficients as :mod:`multibody.kernels.stepping` reads them (read-only): ``c``, ``a_position``,
        ``a_velocity`` (row-major), ``b_position``, ``b_velocity``, :attr:`needs_acceleration`."""
        return self._block


def _runge_kutta(c, a, b, order):
    """The :class:`Tableau` of a Runge–Kutta method: one table for both halves of the state."""
    return Tableau(c, a, a, b, b, order)


#: The fixed-step methods of :func:`multibody.simulate` by name.
TABLEAUS = {
    # explicit Euler: y⁺ = y₀ + h f(t₀, y₀) (Euler's polygons: Hairer, Nørsett & Wanner, Solving ODEs I, §I.7)
    "Euler": _runge_kutta((0.0,), ((0.0,),), (1.0,), 1),
    # semi-implicit Euler: w⁺ = w₀ + h ẇ(t₀, δ₀, w₀), then δ⁺ = h chart_rate(0, w⁺) = h w⁺: the symplectic Euler
    # method of Hairer, Lubich & Wanner, GNI eq. (I.1.9), for q̇ = v (symplectic for a separable Hamiltonian,
    # GNI Theorem VI.3.3); two stages, the second of which evaluates δ̇ only
    "semi-implicit Euler": Tableau((0.0, 1.0), ((0.0, 0.0), (0.0, 0.0)), ((0.0, 0.0), (1.0, 0.0)), (0.0, 1.0),
                                   (1.0, 0.0), 1),
    # the classical Runge–Kutta method (Hairer, Nørsett & Wanner, Solving ODEs I, §II.1, Table 1.2, left)
    "RK4": _runge_kutta((0.0, 0.5, 0.5, 1.0),
                        ((0.0, 0.0, 0.0, 0.0), (0.5, 0.0, 0.0, 0.0), (0.0, 0.5, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0)),
                        (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0), 4),
}


def tableau_step(rates, position_rates, t, y, h, tableau):
    """One step of ``tableau`` from the chart state ``y = [δ, w] (..., 2 nv)`` at ``t`` (s) with step ``h`` (s):
    ``y⁺ (..., 2 nv)``. ``rates(t, y) -> ẏ (..., 2 nv)``, ``position_rates(y) -> δ̇ (..., nv)`` (the stages whose
    ``ẇ`` no coefficient uses). The sums are those of :func:`multibody.kernels.stepping.weighted_sum`, term by
    term in the order of the stages, so that both give the same numbers."""
    nv = y.shape[-1] // 2
    K = []
    for i, needed in enumerate(tableau.needs_acceleration):
        y_i = y if i == 0 else _weighted(y, h, tableau.a_position[i][:i], tableau.a_velocity[i][:i], K, nv)
        if needed:
            K.append(rates(t + tableau.c[i] * h, y_i))
        else:
            K_i = np.zeros_like(y)
            K_i[..., :nv] = position_rates(y_i)
            K.append(K_i)
    return _weighted(y, h, tableau.b_position, tableau.b_velocity, K, nv)


def _weighted(y, h, position_weights, velocity_weights, K, nv):
    """``[δ₀ + h Σ_j position_weights_j δ̇_j, w₀ + h Σ_j velocity_weights_j ẇ_j]`` of the rates ``K`` (a list of
    ``(..., 2 nv)``), the terms of non-zero weight summed in order."""
    out = y.copy()
    for half, weights in ((np.s_[..., :nv], position_weights), (np.s_[..., nv:], velocity_weights)):
        terms = [(weight, K_j[half]) for weight, K_j in zip(weights, K) if weight != 0.0]
        if terms:
            total = terms[0][0] * terms[0][1]
            for weight, K_j in terms[1:]:
                total = total + weight * K_j
            out[half] = y[half] + h * total
    return out


@dataclass(frozen=True)
class EmbeddedPair:
    """An explicit embedded Runge–Kutta pair with a continuous extension (E. Hairer, S. P. Nørsett and G. Wanner,
    *Solving Ordinary Differential Equations I*, 2nd ed., Springer 1993, §II.4–II.6), as
    :mod:`multibody.kernels.stepping`'s adaptive run takes its steps. The rows ``i`` of ``a`` are the evaluations of
    one step from ``(t₀, y₀)`` with step ``h``: the ``s`` stages, then the end ``y₁ = y₀ + h Σ_j b_j K_j`` (row ``s``,
    ``c_s = 1``, whose rate starts the next step), then the extra stages of the dense output; each is

        K_i = f(t₀ + c_i h, y₀ + h Σ_{j<i} a_ij K_j).

    The error estimate is ``h Σ_j e_j K_j`` (``j ≤ s``) of order ``error_order``, its norm ``‖·‖`` the root mean square
    of its entries each over ``atol_i + rtol max(|y₀ᵢ|, |y₁ᵢ|)`` (HNW eq. (4.11)); with ``e3`` (DOP853) the norm
    is ``|h| ‖e₅‖² / √(‖e₅‖² + 0.01 ‖e₃‖²)`` (E. Hairer's code DOP853), whose ``e₃`` is a third-order estimate.
    The dense output at ``t₀ + x h`` is

        y(x) = y₀ + h x (F₀ + g₁(x) (F₁ + g₂(x) (F₂ + …))),   F_k = Σ_j dense[j][k] K_j,

    with ``g_k(x) = x``, or ``1 − x`` where ``flips[k]`` (HNW §II.6: a polynomial in ``x``, or DOP853's form in
    powers of ``x`` and ``1 − x``)."""

    c: tuple
    a: tuple
    stages: int
    order: int
    error_order: int
    e: tuple
    e3: tuple | None
    dense: tuple
    flips: tuple

    @property
    def rows(self) -> int:
        return len(self.c)

    def block(self) -> np.ndarray:
        """The coefficients as :func:`multibody.kernels.stepping.adaptive` reads them: ``s``, the rows, the
        degree of the dense output, ``error_order``, whether there is ``e3``, then ``c``, ``a`` (rows × rows,
        row-major), ``e``, ``e3`` (zeros without it), ``dense`` (rows × degree) and ``flips``."""
        rows, s, degree = self.rows, self.stages, len(self.flips)
        a = np.zeros((rows, rows))
        for i, row in enumerate(self.a):
            a[i, : len(row)] = row
        dense = np.zeros((rows, degree))
        dense[: len(self.dense)] = self.dense
        e3 = np.zeros(s + 1) if self.e3 is None else self.e3
        return np.concatenate([[s, rows, degree, self.error_order, self.e3 is not None], self.c, a.ravel(), self.e,
                               e3, dense.ravel(), np.asarray(self.flips, dtype=float)]).astype(float)


def _by_stage(weights):
    """``dense[j][k]`` of ``F_k = Σ_j dense[j][k] K_j`` from the rows ``weights[k]`` (one weight per stage)."""
    return tuple(tuple(float(row[j]) for row in weights) for j in range(len(weights[0])))


def _bogacki_shampine():
    """Bogacki–Shampine 3(2) (P. Bogacki and L. F. Shampine, Appl. Math. Lett. 2, 1989; HNW §II.4) with its
    cubic Hermite dense output: FSAL, three stages and the end's rate."""
    c = (0.0, 1 / 2, 3 / 4, 1.0)
    a = ((), (1 / 2,), (0.0, 3 / 4), (2 / 9, 1 / 3, 4 / 9))
    b_hat = (7 / 24, 1 / 4, 1 / 3, 1 / 8)
    e = tuple(b - b_h for b, b_h in zip(a[3] + (0.0,), b_hat))
    # y(x) = y₀ + h x (K₀ + x (−4/3 K₀ + K₁ + 4/3 K₂ − K₃) + x² (5/9 K₀ − 2/3 K₁ − 8/9 K₂ + K₃))
    dense = ((1.0, -4 / 3, 5 / 9), (0.0, 1.0, -2 / 3), (0.0, 4 / 3, -8 / 9), (0.0, -1.0, 1.0))
    return EmbeddedPair(c, a, 3, 3, 2, e, None, dense, (False, False, False))


def _dormand_prince():
    """Dormand–Prince 5(4) (J. R. Dormand and P. J. Prince, J. Comput. Appl. Math. 6, 1980; HNW Table II.5.2),
    FSAL, with its continuous extension of order 4 (HNW §II.6, eq. (6.12); L. F. Shampine, Math. Comp. 46, 1986)."""
    c = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0)
    a = ((),
         (1 / 5,),
         (3 / 40, 9 / 40),
         (44 / 45, -56 / 15, 32 / 9),
         (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
         (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
         (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84))
    b_hat = (5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40)
    e = tuple(b - b_h for b, b_h in zip(a[6] + (0.0,), b_hat))
    # the coefficients of x, x², x³, x⁴ in y(x) = y₀ + h Σ_j p_j(x) K_j
    dense = ((1.0, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432),
             (0.0, 0.0, 0.0, 0.0),
             (0.0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799),
             (0.0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072),
             (0.0, 127303824393 / 49829197408, -318862633887 / 49829197408, 701980252875 / 199316789632),
             (0.0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844),
             (0.0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423))
    return EmbeddedPair(c, a, 6, 5, 4, e, None, dense, (False,) * 4)


def _dop853():
    """DOP853: Dormand–Prince 8(5,3) with its dense output of order 7 (HNW §II.5, Table 5.4, and §II.6; E. Hairer's
    code DOP853, whose coefficients these are). Twelve stages and the end's rate; a fifth-order error estimate
    ``e₅`` and a third-order one ``e₃``; three more stages for the dense output."""
    c = (0.0, 0.05260015195876773, 0.0789002279381516, 0.1183503419072274, 0.2816496580927726, 1 / 3, 0.25,
         0.3076923076923077, 0.6512820512820513, 0.6, 0.8571428571428571, 1.0, 1.0, 0.1, 0.2, 0.7777777777777778)
    a = ((),
         (0.05260015195876773,),
         (0.0197250569845379, 0.0591751709536137),
         (0.02958758547680685, 0.0, 0.08876275643042054),
         (0.2413651341592667, 0.0, -0.8845494793282861, 0.924834003261792),
         (0.037037037037037035, 0.0, 0.0, 0.17082860872947386, 0.12546768756682242),
         (0.037109375, 0.0, 0.0, 0.17025221101954405, 0.06021653898045596, -0.017578125),
         (0.03709200011850479, 0.0, 0.0, 0.17038392571223998, 0.10726203044637328, -0.015319437748624402,
          0.008273789163814023),
         (0.6241109587160757, 0.0, 0.0, -3.3608926294469414, -0.868219346841726, 27.59209969944671,
          20.154067550477894, -43.48988418106996),
         (0.47766253643826434, 0.0, 0.0, -2.4881146199716677, -0.590290826836843, 21.230051448181193,
          15.279233632882423, -33.28821096898486, -0.020331201708508627),
         (-0.9371424300859873, 0.0, 0.0, 5.186372428844064, 1.0914373489967295, -8.149787010746927,
          -18.52006565999696, 22.739487099350505, 2.4936055526796523, -3.0467644718982196),
         (2.273310147516538, 0.0, 0.0, -10.53449546673725, -2.0008720582248625, -17.9589318631188,
          27.94888452941996, -2.8589982771350235, -8.87285693353063, 12.360567175794303, 0.6433927460157636),
         # b: the end
         (0.054293734116568765, 0.0, 0.0, 0.0, 0.0, 4.450312892752409, 1.8915178993145003, -5.801203960010585,
          0.3111643669578199, -0.1521609496625161, 0.20136540080403034, 0.04471061572777259),
         # the dense output's stages
         (0.056167502283047954, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25350021021662483, -0.2462390374708025,
          -0.12419142326381637, 0.15329179827876568, 0.00820105229563469, 0.007567897660545699, -0.008298),
         (0.03183464816350214, 0.0, 0.0, 0.0, 0.0, 0.028300909672366776, 0.053541988307438566,
          -0.05492374857139099, 0.0, 0.0, -0.00010834732869724932, 0.0003825710908356584,
          -0.00034046500868740456, 0.1413124436746325),
         (-0.42889630158379194, 0.0, 0.0, 0.0, 0.0, -4.697621415361164, 7.683421196062599, 4.06898981839711,
          0.3567271874552811, 0.0, 0.0, 0.0, -0.0013990241651590145, 2.9475147891527724, -9.15095847217987))
    b = a[12] + (0.0,)
    e5 = (0.01312004499419488, 0.0, 0.0, 0.0, 0.0, -1.2251564463762044, -0.4957589496572502, 1.6643771824549864,
          -0.35032884874997366, 0.3341791187130175, 0.08192320648511571, -0.022355307863886294, 0.0)
    # e₃ = b − b̂₃, b̂₃ nonzero at stages 0, 8 and 11
    b3 = {0: 0.244094488188976377952755905512, 8: 0.733846688281611857341361741547,
          11: 0.220588235294117647058823529412e-01}
    e3 = tuple(b[j] - b3.get(j, 0.0) for j in range(13))
    # F₃..F₆ = h Σ_j d_kj K_j
    d = ((-8.428938276109013, 0.0, 0.0, 0.0, 0.0, 0.5667149535193777, -3.0689499459498917, 2.38466765651207,
          2.117034582445028, -0.871391583777973, 2.2404374302607883, 0.6315787787694688, -0.08899033645133331,
          18.148505520854727, -9.194632392478356, -4.436036387594894),
         (10.427508642579134, 0.0, 0.0, 0.0, 0.0, 242.28349177525817, 165.20045171727028, -374.5467547226902,
          -22.113666853125306, 7.733432668472264, -30.674084731089398, -9.332130526430229, 15.697238121770845,
          -31.139403219565178, -9.35292435884448, 35.81684148639408),
         (19.985053242002433, 0.0, 0.0, 0.0, 0.0, -387.0373087493518, -189.17813819516758, 527.8081592054236,
          -11.57390253995963, 6.8812326946963, -1.0006050966910838, 0.7777137798053443, -2.778205752353508,
          -60.19669523126412, 84.32040550667716, 11.99229113618279),
         (-25.69393346270375, 0.0, 0.0, 0.0, 0.0, -154.18974869023643, -231.5293791760455, 357.6391179106141,
          93.40532418362432, -37.45832313645163, 104.0996495089623, 29.8402934266605, -43.53345659001114,
          96.32455395918828, -39.17726167561544, -149.72683625798564))
    rows = len(c)
    b = b + (0.0,) * (rows - len(b))
    first, end = np.eye(rows)[0], np.eye(rows)[12]
    # Δy = h Σ b_j K_j: F₀ = Δy / h, F₁ = K₀ − Δy / h, F₂ = 2 Δy / h − K₀ − K₁₂, then the d rows (HNW §II.6, DOP853's
    # CONTD8), in y(x) = y₀ + h x (F₀ + (1 − x) (F₁ + x (F₂ + (1 − x) (F₃ + x (F₄ + (1 − x) (F₅ + x F₆)))))).
    weights = (np.array(b), first - np.array(b), 2.0 * np.array(b) - first - end) + tuple(np.array(row) for row in d)
    return EmbeddedPair(c, a, 12, 8, 7, e5, e3, _by_stage(weights), (False, True, False, True, False, True,
                                                                               False))


#: The adaptive methods of :func:`multibody.simulate` by name: embedded pairs with step-size control and dense output.
EMBEDDED = {"RK23": _bogacki_shampine(), "RK45": _dormand_prince(), "DOP853": _dop853()}


# ============================================================================= controllers


def _real(x, name):
    """``x`` as a float array, or ``TypeError`` naming ``name`` (strings, objects, complex numbers)."""
    array = np.asarray(x)
    if array.dtype.kind not in "biuf":
        raise TypeError(f"mb.PD: {name} must be real numbers, got {array.dtype} ({type(x).__name__})")
    return array.astype(float)


def _require_finite(x, name):
    """``ValueError`` naming ``name`` and its first non-finite entries unless ``x`` is finite."""
    if np.isfinite(x).all():
        return
    bad = np.argwhere(~np.isfinite(np.atleast_1d(x)))
    where = ", ".join(f"{name}{index.tolist() if x.ndim else ''} = {np.atleast_1d(x)[tuple(index)]}"
                      for index in bad[:5])
    raise ValueError(f"mb.PD: {name} must be finite: {where}" + (f" and {len(bad) - 5} more" if len(bad) > 5 else ""))


class PD:
    """A joint-space PD controller as data, which :func:`multibody.simulate` runs inside its compiled step:

        τ = k_p ⊙ (q_ref ⊖ q) + k_d ⊙ (v_ref − v) + τ_ff

    with ``q_ref ⊖ q = model.difference(q, q_ref)``, the velocity (tangent space, ``(nv,)``) that takes ``q`` to
    ``q_ref`` in unit time: ``q_ref − q`` for angles and displacements, the logarithm of SO(3), SE(3) or SE(2) for
    spherical, free-flyer and planar joints. Joint forces in N·m or N per coordinate of ``v``.

    Args:
        kp, kd: gains, a number or ``(nv,)`` (N·m/rad or N/m, and N·m·s/rad or N·s/m), or ``(N, nv)`` for ``N``
            trajectories; finite.
        q_ref: the reference configuration ``(nq,)``; with ``t_ref``, a table ``(n, nq)`` of references at the
            times ``t_ref``. ``(N, nq)`` or ``(N, n, nq)`` for ``N`` trajectories.
        v_ref: the reference velocity ``(nv,)`` (default zero); with ``t_ref``, a table ``(n, nv)``; ``(N, …)`` as
            ``q_ref``.
        tau_ff: feed-forward joint forces, a number or ``(nv,)`` (default zero), or ``(N, nv)``.
        t_ref: strictly increasing times ``(n,)`` (s) of the reference tables. Between two of them the reference
            moves linearly: ``v_ref`` entry by entry and ``q_ref`` as ``q_i ⊕ s (q_{i+1} ⊖ q_i)`` (linear for
            angles and displacements, along the great circle for quaternions); before the first time and after
            the last the end rows hold.

    Shapes against the model (``nq``, ``nv``), the number of trajectories and unit quaternions are checked when
    :func:`multibody.simulate` binds the controller to its system (:meth:`bind`). Called with a bound
    controller's ``(t, q, v)`` the law gives ``τ (nv,)``, or ``(N, nv)`` for a batch of states.
    """

    def __init__(self, kp, kd, q_ref, v_ref=None, tau_ff=None, *, t_ref=None):
        self.kp, self.kd = _real(kp, "kp"), _real(kd, "kd")
        self.tau_ff = None if tau_ff is None else _real(tau_ff, "tau_ff")
        self.q_ref = _real(q_ref, "q_ref")
        self.v_ref = None if v_ref is None else _real(v_ref, "v_ref")
        self.t_ref = None if t_ref is None else _real(t_ref, "t_ref")
        for name in ("kp", "kd", "tau_ff"):
            value = getattr(self, name)
            if value is not None and value.ndim > 2:
                raise ValueError(f"mb.PD: {name} must be a number, (nv,) or (N, nv) for N trajectories, got shape "
                                 f"{value.shape}")
        table = self.t_ref is not None
        if table and (self.t_ref.ndim != 1 or not self.t_ref.size):
            raise ValueError(f"mb.PD: t_ref must be the times (n,) of the reference tables, n >= 1, got shape "
                             f"{self.t_ref.shape}")
        for name, size in (("q_ref", "nq"), ("v_ref", "nv")):
            value = getattr(self, name)
            if value is None:
                continue
            if table and value.ndim not in (2, 3):
                raise ValueError(f"mb.PD: with t_ref, {name} must be a table (n, {size}) of references at the n = "
                                 f"{self.t_ref.size} times t_ref (or (N, n, {size}) for N trajectories), got shape "
                                 f"{value.shape}")
            if table and value.shape[-2] != self.t_ref.size:
                raise ValueError(f"mb.PD: {name} has {value.shape[-2]} rows but t_ref has {self.t_ref.size} times "
                                 f"(shape {value.shape} against t_ref {self.t_ref.shape})")
            if not table and value.ndim not in (1, 2):
                raise ValueError(f"mb.PD: {name} must be ({size},) (or (N, {size}) for N trajectories; a table of "
                                 f"references needs t_ref), got shape {value.shape}")
        for name in ("kp", "kd", "tau_ff", "q_ref", "v_ref", "t_ref"):
            value = getattr(self, name)
            if value is not None:
                _require_finite(value, name)
        if table and np.any(np.diff(self.t_ref) <= 0.0):
            k = int(np.argmax(np.diff(self.t_ref) <= 0.0))
            raise ValueError(f"mb.PD: t_ref must be strictly increasing: t_ref[{k}] = {self.t_ref[k]} is followed by "
                             f"t_ref[{k + 1}] = {self.t_ref[k + 1]}")

    def __repr__(self):
        table = "" if self.t_ref is None else f", t_ref ({self.t_ref.size},)"
        return f"PD(kp {self.kp.shape}, kd {self.kd.shape}, q_ref {self.q_ref.shape}{table})"

    def _per_trajectory(self):
        """``{name: N}`` of the arguments given per trajectory, ``(N, …)``: ``kp``, ``kd``, ``tau_ff`` of two axes,
        ``q_ref``, ``v_ref`` of one more than a reference (or a table of them, with ``t_ref``)."""
        table = self.t_ref is not None
        unbatched = {"kp": 1, "kd": 1, "tau_ff": 1, "q_ref": 1 + table, "v_ref": 1 + table}
        return {name: getattr(self, name).shape[0] for name, ndim in unbatched.items()
                if getattr(self, name) is not None and getattr(self, name).ndim > ndim}

    def trajectories(self, start, stop):
        """The controller of the trajectories ``start`` to ``stop`` (exclusive) of a batch: a :class:`PD` whose
        arguments given per trajectory, ``(N, …)``, keep their rows ``[start:stop]``, and whose others are shared
        as they are (this PD itself when none is per trajectory). A chunk of a batch
        (:func:`multibody.distributed.simulate_many`) simulates with it.

        Raises:
            ValueError: not ``0 <= start <= stop <= N`` (integers) for the ``N`` trajectories of the rows.
        """
        sizes = self._per_trajectory()
        if not sizes:
            return self
        count = next(iter(sizes.values()))
        integers = all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in (start, stop))
        if not integers or not 0 <= start <= stop <= count:
            name = next(iter(sizes))
            raise ValueError(f"mb.PD.trajectories: start and stop must be integers with 0 <= start <= stop <= {count} "
                             f"(the trajectories of {name} {getattr(self, name).shape}), got {start!r} and {stop!r}")
        part = copy.copy(self)
        for name in sizes:
            setattr(part, name, getattr(self, name)[start:stop])
        return part

    def bind(self, system, batch=None):
        """The controller on ``system`` (``nq``, ``nv``; a ``Model`` or a mechanical system whose configurations
        are a vector space) for one trajectory (``batch`` ``None``) or ``batch`` of them: a
        :class:`PDController`. ``ValueError`` names the argument whose shape does not fit."""
        nq, nv = system.nq, system.nv
        model = system if isinstance(system, Model) else getattr(system, "model", None)
        if model is None and (nq != nv or (hasattr(system, "chart") and not getattr(system, "vector_space", False))):
            raise ValueError(f"mb.PD needs a Model, or a system whose configurations are a vector space (q̇ = v), to "
                             f"take q_ref ⊖ q; {type(system).__name__} has nq = {nq}, nv = {nv} and charts")
        table = self.t_ref is not None
        n = 1 if not table else self.t_ref.size
        for name, size in (("kp", nv), ("kd", nv), ("tau_ff", nv), ("q_ref", nq), ("v_ref", nv)):
            value = getattr(self, name)
            if value is None or value.ndim == 0:
                continue
            if value.shape[-1] != size:
                expected = f"(n, {size})" if table and name in ("q_ref", "v_ref") else f"({size},)"
                raise ValueError(f"mb.PD: {name} must have shape {expected} (or (N, ...) for N trajectories) for this "
                                 f"system (nq = {nq}, nv = {nv}), got {value.shape}")
        sizes = self._per_trajectory()
        if sizes and batch is None:
            name, count = next(iter(sizes.items()))
            raise ValueError(f"mb.PD: {name} has shape {getattr(self, name).shape}, for {count} trajectories, but the "
                             "simulation has one initial state")
        for name, count in sizes.items():
            if count != batch:
                raise ValueError(f"mb.PD: {name} has shape {getattr(self, name).shape}, for {count} trajectories, but "
                                 f"the simulation has {batch} initial states")
        count = batch if sizes else 1
        # each trajectory's row [k_p | k_d | τ_ff | n | t_ref | q_ref | v_ref], each part broadcast as it is written
        rows = np.empty((count, 3 * nv + 1 + n * (1 + nq + nv)))
        at = 0
        for value, size in ((self.kp, nv), (self.kd, nv), (self.tau_ff, nv), (float(n), 1),
                            (self.t_ref if table else 0.0, n), (self.q_ref.reshape((-1, n * nq)), n * nq),
                            (None if self.v_ref is None else self.v_ref.reshape((-1, n * nv)), n * nv)):
            rows[:, at : at + size] = 0.0 if value is None else value
            at += size
        if model is not None:
            try:
                model.check_configuration(rows[:, 3 * nv + 1 + n : 3 * nv + 1 + n * (1 + nq)].reshape((count, n, nq)),
                                          "q_ref")
            except ValueError as error:
                raise ValueError(f"mb.PD: q_ref: {error}") from None
        tree = model.tree if model is not None else vector_space_tree(nq)
        return PDController(tree, rows, nq, nv)


class PDController:
    """A :class:`PD` bound to a system: ``controller(t, q, v)`` gives ``τ (nv,)`` for ``q (nq,)``, ``v (nv,)``, or
    ``(N, nv)`` for a batch ``(N, nq)``, ``(N, nv)`` (with ``N`` rows of gains and references, each state its
    own), by :func:`multibody.kernels.stepping.pd_torque`: the code the compiled step runs.

    Attributes:
        rows: ``(1 or N, L)`` the law's data, one row per trajectory (layout of
            :func:`~multibody.kernels.stepping.pd_torque`).
    """

    def __init__(self, tree, rows, nq, nv):
        self.tree, self.rows, self.nq, self.nv = tree, rows, nq, nv

    def __call__(self, t, q, v):
        q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
        t = np.array([t], dtype=float)
        if q.ndim == 1 and v.ndim == 1 and len(self.rows) == 1:
            return driver.evaluate_one(stepping.pd_kernel, self.tree, (1, self.nv), driver.contiguous(q),
                                       driver.contiguous(v), self.rows[0], t, workspace=self.nq + self.nv)[0]
        batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], self.rows.shape[:-1])
        return driver.evaluate(stepping.pd_kernel, self.tree, (q, v, self.rows, t), (1, self.nv), batch,
                               workspace=self.nq + self.nv).reshape(batch + (self.nv,))


def vector_space_tree(n):
    """A compiled tree of ``n`` one-coordinate joints (:func:`multibody.kernels.joints.difference` and
    ``integrate`` add and subtract), for the configuration maps of a system without a Model whose
    configurations are a vector space. Its inertias are zero: no dynamics runs on it."""
    joints = np.zeros((n, 6), dtype=np.int64)
    joints[:, 0] = np.arange(n) - 1
    joints[:, 1] = kinds.REVOLUTE
    joints[:, 2] = joints[:, 3] = np.arange(n)
    joints[:, 4] = joints[:, 5] = 1
    frozen = [np.ascontiguousarray(x) for x in (joints, np.zeros((n + 1, REAL_SIZE)), np.zeros((0, FRAME_SIZE)),
                                                 np.zeros((0, FRAME_SIZE)))]
    for x in frozen:
        x.setflags(write=False)
    return CompiledTree(*frozen, n, n, n)


#: The argument types of a compiled controller ``f(t, q, v, out)``.
CONTROLLER_TYPES = (types.float64, types.float64[::1], types.float64[::1], types.float64[::1])


def is_compiled_controller(tau) -> bool:
    """Whether ``tau`` is a ``numba.njit`` function of four parameters ``f(t, q, v, out)``."""
    if not numba.extending.is_jitted(tau):
        return False
    if tau in _CONTROLLER_POINTERS:  # compiled for f(t, q, v, out) already
        return True
    try:
        return len(inspect.signature(tau.py_func).parameters) == 4
    except (TypeError, ValueError):
        return False


class CompiledController:
    """A ``numba.njit`` function ``f(t, q, v, out)`` that writes the joint forces ``τ (nv,)`` into ``out``
    (zeros on entry) and returns nothing, compiled for ``t`` a float (s) and C-contiguous float64 vectors
    ``q (nq,)``, ``v (nv,)``, ``out (nv,)``: the compiled step calls it at every stage. Called as
    ``controller(t, q, v)`` it gives ``τ (nv,)``, or ``(N, nv)`` for a batch of states, from the same code.

    ``TypeError`` names ``tau`` when the function does not compile for those types or returns a value."""

    def __init__(self, function, nv):
        self.function, self.nv = function, nv
        #: the function as the compiled run takes it (a first-class function), checked and made once per function
        # (kept while the function lives, not by the driver, which would hold every controller made)
        # (the machine code the pointer was made from must still be the function's: ``recompile()`` replaces it)
        made, self.pointer = _CONTROLLER_POINTERS.get(function, (None, None))
        code = numba_hooks.compiled_code(function, CONTROLLER_TYPES)
        if code is None or made is not code:
            self.pointer = _controller_pointer(function)
            code = numba_hooks.compiled_code(function, CONTROLLER_TYPES)
            # (without Numba's record of the code nothing tells the pointer is current; a pointer that is the
            # function itself would keep its weak key alive)
            if code is not None and self.pointer is not function:
                _CONTROLLER_POINTERS[function] = (code, self.pointer)

    def __call__(self, t, q, v):
        q, v = driver.contiguous(np.asarray(q, dtype=float)), driver.contiguous(np.asarray(v, dtype=float))
        if q.ndim == 1 and v.ndim == 1:
            out = np.zeros(self.nv)
            self.function(float(t), q, v, out)
            return out
        batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
        n = int(np.prod(batch))
        q = driver.contiguous(np.broadcast_to(q, batch + q.shape[-1:]).reshape(n, -1))
        v = driver.contiguous(np.broadcast_to(v, batch + v.shape[-1:]).reshape(n, -1))
        out = np.empty((n, self.nv))
        driver.entry_point(stepping.controller_rows, _CONTROLLER_ROWS_TYPES)(self.pointer, float(t), q, v, out)
        return out.reshape(batch + (self.nv,))


def _controller_pointer(function):
    """The ``numba.njit`` controller ``function`` compiled for :data:`CONTROLLER_TYPES`, as a first-class function;
    ``TypeError`` names it when it does not compile for them or returns a value."""
    name = getattr(function, "__name__", repr(function))
    try:
        function.compile(CONTROLLER_TYPES)
    except NumbaError as error:
        raise TypeError(f"tau: the numba.njit controller {name}(t, q, v, out) does not compile for t a float and "
                        f"q, v, out float64 vectors: {error}") from error
    returned = numba_hooks.return_type(function, CONTROLLER_TYPES)
    if returned != types.none:
        raise TypeError(f"tau: the numba.njit controller {name}(t, q, v, out) must write the joint forces into "
                        f"out and return nothing; it returns {returned}")
    return numba_hooks.first_class(function, CONTROLLER_TYPES)


#: The compiled overload and first-class function of each controller (:func:`_controller_pointer`), by the
#: ``numba.njit`` function, held while that lives: a function defined again is another key, and one compiled
#: again has another overload, so either is checked and made again.
_CONTROLLER_POINTERS = weakref.WeakKeyDictionary()
#: The type of a compiled controller as a first-class function, which the compiled runs take.
CONTROLLER_FUNCTION = types.FunctionType(types.none(*CONTROLLER_TYPES))
_CONTROLLER_ROWS_TYPES = (CONTROLLER_FUNCTION, types.float64, types.float64[:, ::1], types.float64[:, ::1],
                          types.float64[:, ::1])


def as_controller(tau, system, batch=None):
    """``tau`` as :func:`multibody.simulate` runs it: a :class:`PD` bound to ``system`` (:class:`PDController`),
    a ``numba.njit`` function ``f(t, q, v, out)`` as a :class:`CompiledController`, anything else unchanged."""
    if isinstance(tau, PD):
        return tau.bind(system, batch)
    if is_compiled_controller(tau):
        return CompiledController(tau, system.nv)
    return tau


def control_rows(controller, nv):
    """``(kind, control)`` of a controller as :mod:`multibody.kernels.stepping` reads it: ``kind`` one of
    :data:`~multibody.kernels.stepping.NO_CONTROL`, ``CONSTANT``, ``PD``, ``FUNCTION``, ``PYTHON``, and ``control
    (1 or N, L)`` float64 rows: the constant joint forces ``(N, nv)`` (N·m or N), a :class:`PDController`'s rows
    behind ``nv`` zero columns, else one row of ``nv`` zeros. ``controller`` is what :func:`as_controller` gives."""
    if controller is None:
        return stepping.NO_CONTROL, np.zeros((1, nv))
    if isinstance(controller, np.ndarray):
        return stepping.CONSTANT, np.ascontiguousarray(controller.reshape(-1, nv), dtype=float)
    if isinstance(controller, PDController):
        rows = controller.rows
        return stepping.PD, np.ascontiguousarray(np.concatenate([np.zeros((len(rows), nv)), rows], axis=1))
    if isinstance(controller, CompiledController):
        return stepping.FUNCTION, np.zeros((1, nv))
    return stepping.PYTHON, np.zeros((1, nv))


def controller_function(kind, controller):
    """The first-class function the compiled runs call as the controller of ``kind`` (:func:`control_rows`):
    ``controller``'s compiled function for :data:`~multibody.kernels.stepping.FUNCTION`, else
    :func:`multibody.kernels.stepping.no_controller`."""
    return controller.pointer if kind == stepping.FUNCTION else driver.first_class(stepping.no_controller,
                                                                                   CONTROLLER_TYPES)


# ============================================================================= the compiled run

#: The argument types of :func:`multibody.kernels.stepping.run` (one trajectory): the tree's arrays and the constraint
#: frames read-only, then the program, times, plan, control row, states, io and workspace; and of
#: :func:`~multibody.kernels.stepping.advance`, which takes a compiled controller first.
_RUN_TYPES = (TREE_INTS, TREE_FLOATS, TREE_FLOATS, types.float64[::1], types.float64[::1], types.float64[::1],
              types.float64[::1], types.float64[:, ::1], types.float64[::1], types.float64[::1])
_ADVANCE_TYPES = (CONTROLLER_FUNCTION,) + _RUN_TYPES
_TRAJECTORIES_TYPES = (types.FunctionType(types.none(*_ADVANCE_TYPES)), CONTROLLER_FUNCTION, TREE_INTS, TREE_FLOATS,
                       TREE_FLOATS, types.float64[::1], types.float64[::1], types.float64[::1], types.float64[:, ::1],
                       types.float64[:, :, ::1], types.float64[:, ::1], types.int64[::1], types.int64, types.int64)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _trajectories(advance, controller, joints, reals, frames, program, times, plan, control, states, io, rows,
                  workspace, shares):
    # ``advance`` (multibody.kernels.stepping.advance) is a first-class function, so that this loop's cached machine
    # code holds none of the kernels' (whose cache multibody.kernels renews when their sources change)
    n = rows.shape[0]
    for share in prange(shares):
        ws = np.empty(workspace)
        for j in range(share * n // shares, (share + 1) * n // shares):
            r = rows[j]
            advance(controller, joints, reals, frames, program, times, plan, control[r if control.shape[0] > 1 else 0],
                    states[r], io[r], ws)


#: The compiled run's functions that Python calls or passes as first-class functions, as ``(function, argument
#: types)``: ``multibody compile`` compiles them beside the kernels (:func:`multibody.driver.compile_kernels`), so
#: that a first fixed-step :func:`multibody.simulate` loads them from Numba's cache instead of compiling them.
ENTRY_POINTS = ((stepping.run, _RUN_TYPES), (stepping.advance, _ADVANCE_TYPES), (_trajectories, _TRAJECTORIES_TYPES),
                (stepping.no_controller, CONTROLLER_TYPES), (stepping.controller_rows, _CONTROLLER_ROWS_TYPES),
                (stepping.adaptive_run, _RUN_TYPES), (stepping.adaptive_run_function, _ADVANCE_TYPES))


@dataclass(frozen=True, eq=False)
class CompiledStep:
    """The compiled step of a system as the compiled runs take it (made by
    :attr:`multibody.constrained.ConstrainedSystem.compiled_step`).

    Attributes:
        tree: the model's compiled tree; ``frames``: the constraint frames' rows (``tree.bodies`` without constraints);
            ``program``: the constraints' program (length 0 without constraints).
        step_columns, step_workspace: the output columns and workspace of the step (ABA's ``nv`` and its workspace
            without constraints, the KKT step's with them).
        settings: ``[tolerance, max_iterations, position mask (m)]`` of the projection at a step's end
            (:func:`multibody.kernels.kkt.project`), ``[0, 0]`` without constraints; ``projection_columns``,
            ``projection_workspace``: its output columns and workspace (0 without constraints).
        charts: whether the stages go through the chart maps (a curved configuration space, or constraints); else
            ``q = q₀ + δ``, ``v = w``.

    ``tree``, ``frames`` and ``settings`` (a copy) are read-only; ``program`` is the array that the system's own
    compiled calls and the runs read, writable because the kernels' argument types are: not to be written.
    """

    tree: CompiledTree | None
    frames: np.ndarray | None
    program: np.ndarray
    step_columns: int
    step_workspace: int
    settings: np.ndarray
    projection_columns: int
    projection_workspace: int
    charts: bool

    def __post_init__(self):
        # (a copy: the system's projection keeps reading its own settings, whatever is done to these)
        settings = np.array(self.settings, dtype=float)
        settings.setflags(write=False)
        object.__setattr__(self, "settings", settings)


#: The step of an adaptive run without a compiled step, which runs as Python only.
_PYTHON_STEP = CompiledStep(None, None, np.zeros(0), 0, 0, np.zeros(2), 0, 0, False)


def _plan(step, method, kind, damping, projection_tolerance, near_singular, nq, nv, rotations=np.zeros(0)):
    """The plan of a run of ``method`` (a :class:`Tableau` or an :class:`EmbeddedPair`) on ``step`` as
    :mod:`multibody.kernels.stepping` reads it: the header, the method's block, the damping ``(nv,)``, the
    projection's settings and the ``rotations`` (an adaptive run's)."""
    block = method.block()
    start = stepping.PLAN_HEADER
    header = np.zeros(start)
    header[[stepping.PLAN_NQ, stepping.PLAN_NV, stepping.PLAN_CHARTS, stepping.PLAN_STAGES, stepping.PLAN_CONTROL,
            stepping.PLAN_PROJECT, stepping.PLAN_PROJECTION_TOLERANCE, stepping.PLAN_NEAR_SINGULAR,
            stepping.PLAN_DAMPED, stepping.PLAN_TABLEAU, stepping.PLAN_DAMPING, stepping.PLAN_SETTINGS,
            stepping.PLAN_STEP_COLUMNS, stepping.PLAN_STEP_WORKSPACE, stepping.PLAN_PROJECTION_COLUMNS,
            stepping.PLAN_PROJECTION_WORKSPACE, stepping.PLAN_ROTATIONS, stepping.PLAN_ROTATION_COUNT]] = (
        nq, nv, step.charts, method.stages, kind, projection_tolerance is not None, projection_tolerance or 0.0,
        near_singular, damping is not None, start, start + block.size, start + block.size + nv, step.step_columns,
        step.step_workspace, step.projection_columns, step.projection_workspace,
        start + block.size + nv + step.settings.size, rotations.size)
    return np.concatenate([header, block, np.zeros(nv) if damping is None else damping, step.settings, rotations])


class CompiledRun:
    """The fixed-step run of one system, method and controller at the output ``times (n,)`` (s), one step per
    interval, compiled (:mod:`multibody.kernels.stepping`).

    Args:
        step: the system's compiled step (:class:`CompiledStep`).
        tableau: the method (:data:`TABLEAUS`).
        controller: ``None``; constant joint forces ``(nv,)`` (or ``(N, nv)``); a :class:`PDController`; a
            :class:`CompiledController`; or any other callable ``(t, q, v)``, called from Python at each stage
            (one trajectory only).
        damping: ``(nv,)`` viscous damping subtracted from the joint forces (``τ − D v``), or ``None``.
        projection_tolerance: the largest move left unprojected at a step's end (``None``: no projection).
        near_singular: the conditioning below which a step's end stops the run (the next step evaluates its
            stages on the constraints), or ``-inf``.
    """

    def __init__(self, step, tableau, controller, damping, projection_tolerance, near_singular, times, nq, nv):
        self.tree, self.frames, self.program = step.tree, step.frames, np.ascontiguousarray(step.program, dtype=float)
        self.times, self.nq, self.nv = np.ascontiguousarray(times, dtype=float), nq, nv
        kind, control = control_rows(controller, nv)
        self.kind, self.control, self.controller = kind, control, controller
        self.pointer = controller_function(kind, controller)
        self.plan = _plan(step, tableau, kind, damping, projection_tolerance, near_singular, nq, nv)
        self.plan[stepping.PLAN_ENERGY] = 1.0
        self.workspace = stepping.workspace_size(nq, nv, tableau.stages, step.step_columns, step.step_workspace,
                                                 step.projection_columns, step.projection_workspace)
        self.ws = np.empty(self.workspace)
        self.io = np.zeros(stepping.io_size(nq, nv, len(self.times)))
        self.io[stepping.io_size(nq, nv) :] = np.nan

    @property
    def energies(self):
        """``(n,)`` the energy (J) of each output state that the run recorded on the way (the stepping kernels'
        :data:`~multibody.kernels.stepping.PLAN_ENERGY`; in a vector space the last state's too), NaN where it did not
        (steps Python took, a run with chart maps or constraints, a Python controller's last state); a view of
        :attr:`io`."""
        return self.io[stepping.io_size(self.nq, self.nv) :]

    def advance(self, states, k, stop, torque=None, joint_forces=None):
        """Steps ``k`` up to ``stop`` (exclusive) of one trajectory, ``states (n, nq + nv)`` filled in place:
        ``(the first step not taken, status)``. A Python controller ``torque(t, q, v)`` gives the joint forces of
        each stage: ``None`` (zero), a float64 array ``(nv,)`` or anything ``joint_forces(value)`` turns into one
        (or raises for). The status's report: :attr:`io` (``IO_TIME``, ``IO_VALUE``, ``τ``)."""
        io = self.io
        io[stepping.IO_STEP], io[stepping.IO_STOP] = k, stop
        io[stepping.IO_STAGE] = io[stepping.IO_TORQUE_GIVEN] = 0.0
        tree = self.tree
        arguments = (tree.joints, tree.reals, self.frames, self.program, self.times, self.plan, self.control[0], states,
                     io, self.ws)
        if self.kind == stepping.FUNCTION:
            # stepping.advance with the controller's pointer, on this thread (the batch's parallel loop would wake
            # Numba's thread pool for one trajectory); the others by stepping.run, compiled without a controller
            entry, arguments = driver.entry_point(stepping.advance, _ADVANCE_TYPES), (self.pointer,) + arguments
        else:
            entry = driver.entry_point(stepping.run, _RUN_TYPES)
        entry(*arguments)
        if io[stepping.IO_STATUS] == stepping.NEED_TORQUE:
            # a Python controller: the stage's t, q, v out, τ in, and the run goes on from that stage
            nq, nv, start = self.nq, self.nv, stepping.IO_HEADER
            q, v = io[start : start + nq], io[start + nq : start + nq + nv]
            tau = io[start + nq + nv : start + nq + 2 * nv]
            shape, waiting, given = (nv,), float(stepping.NEED_TORQUE), stepping.IO_TORQUE_GIVEN
            while True:
                value = torque(io.item(stepping.IO_TIME), q.copy(), v.copy())
                if value is None:
                    value = 0.0
                elif type(value) is not np.ndarray or value.dtype != np.float64 or value.shape != shape:
                    value = joint_forces(value)
                tau[:] = value
                io[given] = 1.0
                entry(*arguments)
                if io[stepping.IO_STATUS] != waiting:
                    break
        return int(io[stepping.IO_STEP]), int(io[stepping.IO_STATUS])

    def advance_batch(self, states, io, rows, threads=None):
        """The steps ``io[r, IO_STEP]`` up to ``io[r, IO_STOP]`` of the trajectories ``rows`` (int64) of ``states (N,
        n, nq + nv)``, each on its own (its status in its ``io`` row, :func:`multibody.kernels.stepping.io_size`),
        on ``threads`` threads (default :func:`multibody.get_num_threads`, at most one per trajectory)."""
        if self.kind == stepping.PYTHON:
            raise ValueError("a batch of trajectories runs a Python controller through simulate's lockstep loop")
        tree = self.tree
        # each thread its own contiguous share of the trajectories, with its own workspace
        shares = max(1, min(driver.get_num_threads() if threads is None else threads, len(rows)))
        entry = driver.entry_point(_trajectories, _TRAJECTORIES_TYPES)
        with driver.parallel_shares(shares):
            entry(driver.first_class(stepping.advance, _ADVANCE_TYPES), self.pointer, tree.joints, tree.reals,
                  self.frames, self.program, self.times, self.plan, self.control, states, io, rows, self.workspace,
                  shares)


class AdaptiveRun:
    """The adaptive run of one system, embedded pair and controller to the output ``times (n,)`` (s)
    (:func:`multibody.kernels.stepping.adaptive`): compiled where the system's step is, else, and for the steps the
    compiled run leaves, the same function run as Python with the system's maps from Python.

    Args:
        step, controller, damping: as :class:`CompiledRun` takes them, and ``projection_tolerance``, ``near_singular``
            too (``step`` ``None``: a system without a compiled step, which runs as Python only).
        curved: whether each step's end starts a new chart.
        pair: the method (:data:`EMBEDDED`); ``rtol``, ``atol``: its tolerances; ``max_step``: its longest step (s).
        turn: the largest turn of a rotation vector of the chart in a step (rad), at the angular speeds of its start;
            ``rotations``: the first index in ``v`` of each rotation vector's three.
    """

    def __init__(self, step, curved, pair, controller, damping, projection_tolerance, near_singular, times, nq, nv,
                 rtol, atol, max_step, turn, rotations):
        step = _PYTHON_STEP if step is None else step
        self.tree, self.frames = step.tree, step.frames
        self.program = np.ascontiguousarray(step.program, dtype=float)
        self.times, self.nq, self.nv = np.ascontiguousarray(times, dtype=float), nq, nv
        kind, control = control_rows(controller, nv)
        self.kind, self.control = kind, control
        self.pointer = controller_function(kind, controller)
        self.plan = _plan(step, pair, kind, damping, projection_tolerance, near_singular, nq, nv,
                          np.asarray(rotations, dtype=float).ravel())
        self.plan[[stepping.PLAN_CURVED, stepping.PLAN_RTOL, stepping.PLAN_ATOL, stepping.PLAN_MAX_STEP,
                   stepping.PLAN_CHART_TURN]] = (curved, rtol, atol, max_step, turn)
        self.ws = np.zeros(stepping.adaptive_workspace_size(nq, nv, pair.rows, len(pair.flips), step.step_columns,
                                                            step.step_workspace, step.projection_columns,
                                                            step.projection_workspace))
        self.io = np.zeros(stepping.io_size(nq, nv))

    def start(self, state, near):
        """The run from ``state = [q, v] (nq + nv,)`` at ``times[0]``, its first output (``near``: whether the rows
        are near singular there)."""
        scalars = self.ws[: stepping.SCALARS]
        scalars[:] = 0.0
        scalars[[stepping.S_T, stepping.S_H_ABS, stepping.S_NEAR, stepping.S_PHASE]] = (
            self.times[0], np.nan, bool(near), stepping.PHASE_RESTART)
        self.ws[stepping.SCALARS + self.nq : stepping.SCALARS + 2 * self.nq + self.nv] = state
        self.io[stepping.IO_STEP] = 1

    @property
    def t(self) -> float:
        """The time (s) the next step starts at."""
        return float(self.ws[stepping.S_T])

    @property
    def near(self) -> bool:
        """Whether the rows are near singular where the next step starts."""
        return bool(self.ws[stepping.S_NEAR])

    @property
    def done(self) -> int:
        """The outputs filled so far."""
        return int(self.io[stepping.IO_STEP])

    def advance(self, states, stop, python=None):
        """The steps up to the one that fills the output ``stop − 1`` of ``states (n, nq + nv)``: ``(outputs filled,
        status)``. Compiled without ``python``, else as Python with its maps (:func:`multibody.kernels.stepping.
        adaptive`)."""
        io = self.io
        io[stepping.IO_STOP] = stop
        tree = self.tree
        if python is not None:
            function = getattr(stepping.adaptive, "py_func", stepping.adaptive)
            function(python, None, None, None, None, self.program, self.times, self.plan, self.control[0], states, io,
                     self.ws)
        elif self.kind == stepping.FUNCTION:
            driver.entry_point(stepping.adaptive_run_function, _ADVANCE_TYPES)(
                self.pointer, tree.joints, tree.reals, self.frames, self.program, self.times, self.plan,
                self.control[0], states, io, self.ws)
        else:
            driver.entry_point(stepping.adaptive_run, _RUN_TYPES)(
                tree.joints, tree.reals, self.frames, self.program, self.times, self.plan, self.control[0], states,
                io, self.ws)
        return int(io[stepping.IO_STEP]), int(io[stepping.IO_STATUS])
