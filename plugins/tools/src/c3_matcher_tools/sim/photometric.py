"""Photometric domain shift between a satellite/ortho image and a nav-camera frame.

A seeded :class:`numpy.random.Generator` draws every random parameter in a fixed order, so the
same seed gives identical bytes. Operations, in order: per-channel white-balance gains and a
global brightness gain, gamma, vignetting, Gaussian blur, additive Gaussian noise (DN), JPEG
re-encode. Images are uint8 RGB (H, W, 3) or grey (H, W).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError

__all__ = ["PhotometricShift"]


def _check_range(name: str, value: tuple[float, float], low: float) -> None:
    a, b = value
    if not (low <= a <= b):
        raise InvalidInputError(f"photometric.{name}", f"expected {low} <= min <= max, got {value}")


@dataclass(frozen=True)
class PhotometricShift:
    """Random photometric shift; ranges are (min, max) drawn uniformly.

    ``gain_range``: per-channel white-balance gain; ``brightness_range``: global gain;
    ``gamma_range``: exponent on [0, 1] intensities; ``vignetting``: fractional darkening at the
    image corners (0 = none; radial, quadratic in the distance from the centre);
    ``blur_sigma_range``: Gaussian blur sigma in px (0 = none); ``noise_sigma``: std of the
    additive Gaussian noise in DN; ``jpeg_quality``: re-encode quality, or None for no JPEG.
    """

    gain_range: tuple[float, float] = (0.88, 1.12)
    brightness_range: tuple[float, float] = (0.85, 1.15)
    gamma_range: tuple[float, float] = (0.8, 1.25)
    vignetting: float = 0.0
    blur_sigma_range: tuple[float, float] = (0.3, 1.0)
    noise_sigma: float = 2.0
    jpeg_quality: int | None = 85

    def __post_init__(self) -> None:
        _check_range("gain_range", self.gain_range, 0.0)
        _check_range("brightness_range", self.brightness_range, 0.0)
        _check_range("gamma_range", self.gamma_range, 1e-3)
        _check_range("blur_sigma_range", self.blur_sigma_range, 0.0)
        if not 0.0 <= self.vignetting < 1.0:
            raise InvalidInputError(
                "photometric.vignetting", f"must be in [0, 1), got {self.vignetting}"
            )
        if self.noise_sigma < 0:
            raise InvalidInputError(
                "photometric.noise_sigma", f"must be >= 0, got {self.noise_sigma}"
            )
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise InvalidInputError(
                "photometric.jpeg_quality", f"must be in [1, 100], got {self.jpeg_quality}"
            )

    @classmethod
    def identity(cls) -> PhotometricShift:
        """A shift that changes nothing (gains 1, gamma 1, no blur, noise or JPEG)."""
        return cls((1.0, 1.0), (1.0, 1.0), (1.0, 1.0), 0.0, (0.0, 0.0), 0.0, None)

    def apply(self, image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
        """Return the shifted image (same shape, uint8); ``rng`` is advanced deterministically."""
        grey = image.ndim == 2
        x = image.astype(np.float32)[..., None] if grey else image.astype(np.float32)
        channels = x.shape[2]
        gains = rng.uniform(*self.gain_range, size=3)[:channels]
        brightness = rng.uniform(*self.brightness_range)
        gamma = rng.uniform(*self.gamma_range)
        sigma = rng.uniform(*self.blur_sigma_range)
        x = x * (gains * brightness).astype(np.float32) / 255.0
        np.clip(x, 0.0, 1.0, out=x)
        if gamma != 1.0:
            x = np.power(x, np.float32(gamma))
        if self.vignetting > 0:
            h, w = x.shape[:2]
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (
                ((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2
            )
            x = x * (1.0 - np.float32(self.vignetting) * r2)[..., None]
        x = x * 255.0
        if sigma > 0.05:
            blurred = cv2.GaussianBlur(
                x, (0, 0), sigmaX=float(sigma), borderType=cv2.BORDER_REFLECT
            )
            x = np.asarray(blurred, dtype=np.float32).reshape(
                image.shape[0], image.shape[1], channels
            )
        if self.noise_sigma > 0:
            x = x + rng.normal(0.0, self.noise_sigma, size=x.shape).astype(np.float32)
        out = np.clip(np.rint(x), 0, 255).astype(np.uint8)
        out = out[..., 0] if grey else out
        if self.jpeg_quality is not None:
            bgr = out if grey else cv2.cvtColor(out, cv2.COLOR_RGB2BGR)
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(self.jpeg_quality)])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            flag = cv2.IMREAD_GRAYSCALE if grey else cv2.IMREAD_COLOR
            dec = cv2.imdecode(buf, flag)
            out = dec if grey else cv2.cvtColor(dec, cv2.COLOR_BGR2RGB)
        return np.ascontiguousarray(out, dtype=np.uint8)
