"""Simplifying assumptions, hypotheses and stability of Runge-Kutta pairs (public namespace).

Three levels, as in RungeKutta.jl: raw residuals (``b_error``, ``c_error``, ...), yes/no
checks (``satisfies_b``, ...) and the largest order that holds (``max_order_b``, ...), plus
``hypotheses``, ``conjugacy_error``, ``stability_function``, ``r_infinity`` and the summary
``check_tableau``.
"""

from ._condition_checks import (
    max_order_b,
    max_order_c,
    max_order_c_hat_c,
    max_order_cc_hat,
    max_order_d,
    max_order_d_hat_d,
    max_order_dd_hat,
    satisfies_b,
    satisfies_c,
    satisfies_c_hat_c,
    satisfies_cc_hat,
    satisfies_d,
    satisfies_d_hat_d,
    satisfies_dd_hat,
)
from ._conditions import (
    DEFAULT_TOL,
    b_error,
    c_error,
    c_hat_c_error,
    cc_hat_error,
    d_error,
    d_hat_d_error,
    dd_hat_error,
    max_order,
)
from ._tableau_report import (
    H2_CONDITION_LIMIT,
    Hypotheses,
    TableauReport,
    check_tableau,
    conjugacy_error,
    hypotheses,
    r_infinity,
    stability_function,
)

__all__ = [
    "DEFAULT_TOL", "H2_CONDITION_LIMIT", "Hypotheses", "TableauReport", "check_tableau",
    "b_error", "c_error", "d_error", "cc_hat_error", "c_hat_c_error", "dd_hat_error",
    "d_hat_d_error",
    "satisfies_b", "satisfies_c", "satisfies_d", "satisfies_cc_hat", "satisfies_c_hat_c",
    "satisfies_dd_hat", "satisfies_d_hat_d",
    "max_order", "max_order_b", "max_order_c", "max_order_d", "max_order_cc_hat",
    "max_order_c_hat_c", "max_order_dd_hat", "max_order_d_hat_d",
    "conjugacy_error", "hypotheses", "r_infinity", "stability_function",
]  # fmt: skip
