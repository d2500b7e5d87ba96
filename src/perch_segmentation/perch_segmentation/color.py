"""sRGB to CIELAB, so colour thresholds are perceptual distances (Delta E 1976)."""

from __future__ import annotations

import numpy as np

# sRGB (D65) to XYZ, rows X, Y, Z; white point D65.
_RGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
_WHITE = np.array([0.95047, 1.0, 1.08883])


_SRGB_LINEAR = np.where(np.arange(256) / 255.0 <= 0.04045, np.arange(256) / 255.0 / 12.92,
                        ((np.arange(256) / 255.0 + 0.055) / 1.055) ** 2.4)


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """(N,3) sRGB (uint8, or floats in [0,1]) to (N,3) CIELAB (L in 0..100)."""
    rgb = np.asarray(rgb)
    if rgb.dtype == np.uint8:
        linear = _SRGB_LINEAR[rgb]  # table lookup: 8-bit colours need no power function
    else:
        c = np.clip(rgb.astype(np.float64), 0.0, 1.0)
        linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    xyz = (linear @ (_RGB_TO_XYZ / _WHITE[:, None]).T)
    eps = (6.0 / 29.0) ** 3
    f = np.where(xyz > eps, np.cbrt(xyz), xyz / (3 * (6.0 / 29.0) ** 2) + 4.0 / 29.0)
    return np.stack([116.0 * f[:, 1] - 16.0, 500.0 * (f[:, 0] - f[:, 1]), 200.0 * (f[:, 1] - f[:, 2])], axis=1)
