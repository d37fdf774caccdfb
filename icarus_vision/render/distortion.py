"""Lens distortion of the FPV camera: OpenCV's radial-tangential and fisheye models.

A distorted camera keeps its pinhole K (from the field of view and resolution) and moves every
pinhole pixel as OpenCV does. With normalised coordinates (x, y) = ((u - cx) / fx, (v - cy) / fy)
and r² = x² + y²:

* ``radtan`` (``cv2.projectPoints``), coefficients ``[k1, k2, p1, p2]`` or ``[k1, k2, p1, p2, k3]``:
  x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²), and y' likewise with
  p1 (r² + 2 y²) + 2 p2 x y;
* ``fisheye`` (``cv2.fisheye.projectPoints``), coefficients ``[k1, k2, k3, k4]``: θ = atan r,
  θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), (x', y') = (θd / r) (x, y);

then (u', v') = (fx x' + cx, fy y' + cy). :func:`undistort_pixels` inverts that by Newton's method
(to 1e-9 of a normalised unit), batched over any number of pixels.
"""

from __future__ import annotations

import numpy as np

MODELS = {"none": (0,), "radtan": (4, 5), "fisheye": (4,)}
"""Distortion models and how many coefficients each takes."""


def check_distortion(model: str, coeffs: tuple[float, ...]) -> str | None:
    """Why (``model``, ``coeffs``) is not a usable distortion, or None when it is."""
    if model not in MODELS:
        return f"distortion must be one of {', '.join(MODELS)}, got {model!r}"
    if len(coeffs) not in MODELS[model]:
        want = " or ".join(str(n) for n in MODELS[model])
        return f"distortion {model!r} takes {want} coefficients, got {len(coeffs)}"
    if not all(isinstance(c, int | float) and np.isfinite(c) for c in coeffs):
        return f"distortion coefficients must be finite numbers, got {list(coeffs)}"
    return None


def distort_normalized(xy: np.ndarray, model: str, coeffs: tuple[float, ...]) -> np.ndarray:
    """(..., 2) pinhole normalised coordinates -> distorted ones (module docstring)."""
    xy = np.asarray(xy, float)
    if model == "none":
        return xy.copy()
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if model == "radtan":
        k1, k2, p1, p2, k3 = (*coeffs, 0.0)[:5]
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=-1)
    k1, k2, k3, k4 = coeffs
    r = np.sqrt(r2)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(r > 1e-12, theta_d / r, 1.0)
    return xy * scale[..., None]


def _to_normalized(k: np.ndarray, px: np.ndarray) -> np.ndarray:
    return (np.asarray(px, float) - (k[0, 2], k[1, 2])) / (k[0, 0], k[1, 1])


def _to_pixels(k: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return xy * (k[0, 0], k[1, 1]) + (k[0, 2], k[1, 2])


def distort_pixels(
    k: np.ndarray, px: np.ndarray, model: str, coeffs: tuple[float, ...]
) -> np.ndarray:
    """(..., 2) pixels of the pinhole camera K -> where the distorted camera images them (NaN
    stays NaN)."""
    if model == "none":
        return np.asarray(px, float).copy()
    return _to_pixels(k, distort_normalized(_to_normalized(k, px), model, coeffs))


def undistort_pixels(
    k: np.ndarray, px: np.ndarray, model: str, coeffs: tuple[float, ...], iterations: int = 20
) -> np.ndarray:
    """Inverse of :func:`distort_pixels`: (..., 2) distorted pixels -> pinhole pixels.

    Newton's method on the normalised coordinates, the Jacobian by central differences, from the
    distorted point itself; a pixel where it does not converge (outside the range where the
    distortion is one-to-one) comes back NaN.
    """
    if model == "none":
        return np.asarray(px, float).copy()
    with np.errstate(all="ignore"):  # diverging pixels become NaN, silently
        target = _to_normalized(k, px)
        p = target.copy()
        h = 1e-6
        ex, ey = np.array([h, 0.0]), np.array([0.0, h])
        for _ in range(iterations):
            f = distort_normalized(p, model, coeffs) - target
            jx = distort_normalized(p + ex, model, coeffs) - distort_normalized(
                p - ex, model, coeffs
            )
            jy = distort_normalized(p + ey, model, coeffs) - distort_normalized(
                p - ey, model, coeffs
            )
            a, c = jx[..., 0] / (2 * h), jx[..., 1] / (2 * h)  # d(xd, yd)/dx
            b, d = jy[..., 0] / (2 * h), jy[..., 1] / (2 * h)  # d(xd, yd)/dy
            det = a * d - b * c
            step = np.stack([(d * f[..., 0] - b * f[..., 1]) / det,
                             (a * f[..., 1] - c * f[..., 0]) / det], axis=-1)  # fmt: skip
            p = p - step
            if np.nanmax(np.abs(step), initial=0.0) < 1e-12:
                break
        residual = np.abs(distort_normalized(p, model, coeffs) - target).max(axis=-1)
        p[~(residual < 1e-9)] = np.nan
    return _to_pixels(k, p)


__all__ = ["MODELS", "check_distortion", "distort_normalized", "distort_pixels",
           "undistort_pixels"]  # fmt: skip
