"""Robust statistics the diagnosis is built on: Huber M-estimation by iteratively
reweighted least squares (with Gaussian priors), the Huber loss as a robust
likelihood, robust scales and locations, and the centre that TDOA delays are
reported against. Real UWB residuals are heavy-tailed and carry outliers; these
estimators keep a few of them from hiding, or faking, a systematic error."""

from __future__ import annotations

import numpy as np

HUBER_C = 1.345                # Huber threshold, in noise standard deviations
MIN_SAMPLES = 50               # the fewest samples a robust scale or location is taken from
GAUGE_SPREAD_M = 0.3           # the delays' centre: delays further off than this count as the anchor's own


def huber_loss(z: np.ndarray) -> np.ndarray:
    a = np.abs(z)
    return np.where(a <= HUBER_C, 0.5 * z * z, HUBER_C * (a - 0.5 * HUBER_C))


def huber_weight(z: np.ndarray) -> np.ndarray:
    a = np.abs(z)
    return np.where(a <= HUBER_C, 1.0, HUBER_C / np.maximum(a, 1e-12))


def irls(z: np.ndarray, x: np.ndarray, prior: np.ndarray | None = None, iterations: int = 8) -> np.ndarray:
    """Huber M-estimate of theta in z ≈ x theta (both standardised), with a Gaussian
    prior of standard deviation `prior` on each parameter: look-alike effects fitted
    together stay at physical sizes instead of cancelling each other at absurd ones."""
    theta = np.zeros(x.shape[1])
    ridge = np.diag(np.full(x.shape[1], 1e-9) if prior is None else 1.0 / np.asarray(prior, float) ** 2)
    for _ in range(iterations):
        gram, moment = weighted_normal(z, x, theta)
        new = np.linalg.solve(gram + ridge, moment)
        if np.allclose(new, theta, atol=1e-10, rtol=1e-6):
            return new
        theta = new
    return theta


def weighted_normal(z: np.ndarray, x: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations of z ≈ x theta with the Huber weights of the residual at
    `theta`: XᵀWX and XᵀWz."""
    xw = x * huber_weight(z - x @ theta)[:, None]
    return xw.T @ x, xw.T @ z


def robust_rms(residual: np.ndarray, scale: np.ndarray) -> float:
    """The mismatch in the channel's unit: an RMS that stops growing past HUBER_C noise
    deviations (so a few outliers do not hide a systematic error)."""
    if not len(residual):
        return float("nan")
    z = residual / scale
    return float(np.sqrt(2.0 * np.mean(huber_loss(z) * scale ** 2)))


def robust_nll(r: np.ndarray, sigma: np.ndarray | float) -> np.ndarray:
    """Robust negative log-likelihood per sample (Huber loss with scale)."""
    return np.log(sigma) + huber_loss(r / sigma)


def mad_scale(values: np.ndarray) -> float:
    """The normal-equivalent median absolute deviation of the finite values (1 when
    there are none, or they do not spread)."""
    values = values[np.isfinite(values)]
    scale = 1.4826 * np.median(np.abs(values - np.median(values))) if len(values) else 1.0
    return float(scale) if scale > 1e-9 else 1.0


def huber_mean(values: np.ndarray, scale: float) -> float:
    """Huber M-estimate of location, for noise of this scale (NaN for no values)."""
    if not len(values):
        return float("nan")
    return float(irls(values / scale, np.ones((len(values), 1)))[0] * scale)


def delay_centre(delays: np.ndarray) -> float:
    """The centre delays are reported against: a Huber M-estimate of location with a
    fixed spread (GAUGE_SPREAD_M). Like a median, one anchor's large delay moves it by
    a bounded amount, the spread over the number of anchors (so it shows on that
    anchor nearly alone, where a mean would spread it as −1/n over all the others);
    unlike a median of eight, which averages the middle two, a delay that changes on
    one anchor moves it smoothly by about 1/n of the change, not by up to half of it
    (a middle anchor's change would read about half as large against its control).
    A spread scaled by the delays' own MAD would jump with it. Fitted by
    `irls` from their median (delays spread wide apart can leave a flat stretch of
    centres), in units where its Huber threshold is the spread."""
    median, unit = float(np.median(delays)), GAUGE_SPREAD_M / HUBER_C
    about_median = (np.asarray(delays, float) - median) / unit
    return median + float(irls(about_median, np.ones((len(delays), 1)), iterations=100)[0]) * unit


def delay_centre_slope(delays: np.ndarray) -> np.ndarray:
    """How `delay_centre` moves with each delay: a Huber location moves with the delays
    within its spread of it, equally, and not with those beyond (their pull on it is
    capped). It maps the delays' covariance to that of the delays as reported."""
    near = np.abs(np.asarray(delays, float) - delay_centre(delays)) <= GAUGE_SPREAD_M
    if not near.any():
        near[:] = True
    return near / near.sum()
