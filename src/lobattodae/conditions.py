"""Simplifying assumptions, hypotheses and stability of Runge-Kutta pairs (public namespace).

Three levels, as in RungeKutta.jl: raw residuals (``b_error``, ``c_error``, ...), yes/no
checks (``satisfies_b``, ...) and the largest order that holds (``max_order_b``, ...), plus
``hypotheses``, ``conjugacy_error``, ``stability_function``, ``r_infinity`` and the summary
``check_tableau``.
"""

from ._conditions import *  # noqa: F401,F403
from ._conditions import __all__  # noqa: F401
