"""Error metrics shared by tests and benchmarks (numpy only).

All images are float arrays (H, W, 3) of linear radiance; metrics average over
pixels and channels.
"""
import numpy as np

EPS = 0.01  # keeps relMSE finite in black pixels


def _f64(a):
    return np.asarray(a, dtype=np.float64)


def relmse(x, ref):
    """Relative MSE: mean((x - ref)^2 / (ref^2 + 0.01))."""
    x, ref = _f64(x), _f64(ref)
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + EPS)))


def rmse(x, ref):
    x, ref = _f64(x), _f64(ref)
    return float(np.sqrt(np.mean((x - ref) ** 2)))


def relative_bias(x, ref):
    """Sum(x) / Sum(ref) - 1: overall energy gain (+) or loss (-)."""
    return float(_f64(x).sum() / _f64(ref).sum() - 1.0)


def reference_relmse(a, b):
    """Estimate the relMSE of the mean of two independent renders a, b.

    Var(a - b) = 2 var, and the mean (a + b) / 2 has var / 2, hence the 4.
    """
    a, b = _f64(a), _f64(b)
    ref = 0.5 * (a + b)
    return float(np.mean((a - b) ** 2 / (4.0 * (ref ** 2 + EPS))))


def summary(x, ref):
    return {"relmse": relmse(x, ref), "rmse": rmse(x, ref),
            "bias": relative_bias(x, ref)}
