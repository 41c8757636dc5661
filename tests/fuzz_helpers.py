"""What a model loaded from a damaged file must satisfy, shared by the URDF and MJCF fuzz tests."""

from __future__ import annotations

import numpy as np
import pytest

import multibody as mb

# Beyond this condition number the mass matrix is singular in double precision, and the Articulated
# Body Algorithm may meet a zero pivot.
NUMERICALLY_SINGULAR = 1e13
# Below this smallest singular value of the mass matrix (a subnormal mass such as 5e-324 kg), the
# accelerations M⁻¹ τ for |τ| ≈ 1 lie beyond the range of double precision.
OUT_OF_RANGE_INERTIA = 1e-250


def check_forward_dynamics(model, q, v, tau, M, event):
    """Forward dynamics at ``(q, v, tau)`` is finite, or raises a ``LinAlgError`` that names a joint or comes
    from a mass matrix ``M`` singular in double precision; ``event(text)`` records which (Hypothesis's
    statistics)."""
    try:
        a = mb.forward_dynamics(model, q, v, tau)
    except np.linalg.LinAlgError as error:
        event("loaded; forward dynamics: LinAlgError")
        names_a_joint = any(f"joint {name!r}" in str(error) for name in model.joint_names)
        singular_values = np.linalg.svd(M, compute_uv=False)
        numerically_singular = (singular_values.min() <= singular_values.max() / NUMERICALLY_SINGULAR
                                or singular_values.min() < OUT_OF_RANGE_INERTIA)
        assert names_a_joint or numerically_singular, (str(error), singular_values)
    else:
        assert np.all(np.isfinite(a)), a


def check_refused(load, error_type, path, xml, where, fragments):
    """Loading the file ``path`` that holds ``xml`` with ``load(str(path))`` raises ``error_type`` whose
    message starts with ``where`` (the file and, where the format gives one, the line) and holds every one
    of ``fragments`` (the element, the attribute and what is wrong)."""
    path.write_text(xml, encoding="utf-8")
    with pytest.raises(error_type) as info:
        load(str(path))
    message = str(info.value)
    assert message.startswith(where), message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
