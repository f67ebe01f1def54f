"""Closed-form minimizers of the continuous Dirichlet problem (docs/method.md section 6), raw alpha."""

import numpy as np


def circle_distance(x, alpha):
    """Regularized distance on the circle of length 2 pi from the source x = 0.

    Parameters
    ----------
    x : (k,) ndarray of float
        Arc-length positions (any real value; taken mod 2 pi).
    alpha : float
        Raw weight, 0 < alpha <= pi.

    Returns
    -------
    (k,) ndarray of float
        With xh = x mod 2 pi and L = pi - alpha: u = xh on [0, L],
        u = pi - alpha / 2 - (xh - pi)^2 / (2 alpha) on [L, 2 pi - L],
        u = 2 pi - xh on [2 pi - L, 2 pi].
    """
    if not 0 < alpha <= np.pi:
        raise ValueError(f"expected 0 < alpha <= pi, got {alpha}")
    xh = np.mod(x, 2.0 * np.pi)
    L = np.pi - alpha
    middle = np.pi - alpha / 2.0 - (xh - np.pi) ** 2 / (2.0 * alpha)
    return np.where(xh <= L, xh, np.where(xh >= 2.0 * np.pi - L, 2.0 * np.pi - xh, middle))


def disk_distance(r, radius, alpha):
    """Regularized distance to the boundary of a flat disk.

    Parameters
    ----------
    r : (k,) ndarray of float
        Distances from the centre, 0 <= r <= radius.
    radius : float
        Disk radius R.
    alpha : float
        Raw weight, 0 < 2 alpha <= R.

    Returns
    -------
    (k,) ndarray of float
        u = R - r for r >= 2 alpha, u = R - alpha - r^2 / (4 alpha) for r <= 2 alpha.
    """
    if not 0 < 2.0 * alpha <= radius:
        raise ValueError(f"expected 0 < 2 alpha <= radius, got alpha {alpha} and radius {radius}")
    return np.where(r >= 2.0 * alpha, radius - r, radius - alpha - r**2 / (4.0 * alpha))


def ball_distance(r, radius, alpha):
    """Regularized distance to the boundary sphere of a solid ball.

    Parameters
    ----------
    r : (k,) ndarray of float
        Distances from the centre, 0 <= r <= radius.
    radius : float
        Ball radius R.
    alpha : float
        Raw weight, 0 < 3 alpha <= R.

    Returns
    -------
    (k,) ndarray of float
        u = R - r for r >= 3 alpha, u = R - 3 alpha / 2 - r^2 / (6 alpha) for r <= 3 alpha
        (Laplace(u) = -1 / alpha inside, C^1 at r = 3 alpha).
    """
    if not 0 < 3.0 * alpha <= radius:
        raise ValueError(f"expected 0 < 3 alpha <= radius, got alpha {alpha} and radius {radius}")
    return np.where(r >= 3.0 * alpha, radius - r, radius - 1.5 * alpha - r**2 / (6.0 * alpha))
