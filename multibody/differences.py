"""Five-point central differences, for the parts of a derivative that are cheap to evaluate and have no
analytical form here (constraint rows, chart maps).

    f'(x) ≈ (8 (f(x + h) − f(x − h)) − (f(x + 2h) − f(x − 2h))) / 12h

is exact for polynomials of degree four; its truncation error is ``O(h⁴)`` and its rounding error
``O(ε/h)``, both near ``1e-12`` relative at ``h ≈ ε^{1/5} ≈ 7e-4`` times the scale of ``x``
(Fornberg, *Generation of finite difference formulas on arbitrarily spaced grids*, Math. Comp. 51, 1988).
"""

from __future__ import annotations

import numpy as np

#: The step per unit of the variable's scale: about the fifth root of the machine epsilon.
STEP = 7e-4


def five_point_jacobian(f, displace, n, h):
    """``∂f/∂x (..., k, n)`` of ``f(x) -> (..., k)`` along ``n`` directions, by the five-point stencil.

    ``displace(steps)`` maps the steps ``(4 n, 1..., n)`` (rows ``+h e_j``, ``−h e_j``, ``+2h e_j``,
    ``−2h e_j``) to the displaced inputs, with a leading axis of ``4 n``; ``f`` takes them all in one call
    and returns ``(4 n, ..., k)``. ``h``: the step (the same unit as ``x``).
    """
    unit = np.eye(n)
    steps = np.concatenate([unit, -unit, 2.0 * unit, -2.0 * unit]) * h
    values = f(displace(steps))
    plus, minus, plus2, minus2 = values[:n], values[n : 2 * n], values[2 * n : 3 * n], values[3 * n :]
    # column j: (8 (f₊₁ − f₋₁) − (f₊₂ − f₋₂)) / 12h
    return np.moveaxis((8.0 * (plus - minus) - (plus2 - minus2)) / (12.0 * h), 0, -1)
