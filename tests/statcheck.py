"""Statistical checks used by the numerical tests: Monte-Carlo against first-order theory.

An estimator's first-order covariance is ``J Σ Jᵀ`` with J its Jacobian with respect to the
measurements (finite differences at noise-free data). A Monte-Carlo sample of T estimates has a
covariance whose trace is within a few ``sqrt(2/T)`` relative of the prediction when the
estimator is unbiased to first order and the noise is small; that is the tolerance used, not a
constant picked to pass.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def delta_method_cov(
    f: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, sigma: np.ndarray, h: float = 1e-6
):
    """Covariance (p, p) of f(z) for z = z0 + noise of standard deviations sigma (m,), independent."""
    f0 = f(z0)
    jac = np.empty((f0.size, z0.size))
    for i in range(z0.size):
        dz = np.zeros_like(z0)
        dz[i] = h
        jac[:, i] = (f(z0 + dz) - f(z0 - dz)).ravel() / (2 * h)
    return jac @ np.diag(sigma**2) @ jac.T


def trace_ratio_tolerance(trials: int, k: float = 4.0) -> float:
    """Relative tolerance on a covariance trace estimated from ``trials`` samples (k sigmas)."""
    return k * np.sqrt(2.0 / trials)
