"""How a simulated flight is rendered: its :class:`FlightSpec`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import check_candidate_size
from c3_matcher_tools.sim.photometric import PhotometricShift
from c3_matcher_tools.sim.render import NAV_CAMERA_DISTORTION

__all__ = ["FlightSpec"]


def _default_shift() -> PhotometricShift:
    return PhotometricShift(
        gain_range=(0.85, 1.15),
        brightness_range=(0.8, 1.2),
        gamma_range=(0.8, 1.25),
        vignetting=0.25,
        blur_sigma_range=(0.3, 0.9),
        noise_sigma=2.5,
        jpeg_quality=85,
    )


@dataclass(frozen=True)
class FlightSpec:
    """How to render a flight (see :mod:`c3_matcher_tools.dataset.flight`); lengths in ground
    metres, angles in degrees (``heading_deg`` from the frames grid's north), sizes in px."""

    frames_geotiff: Path
    store: Path
    n_frames: int = 36
    pattern: str = "orbit"
    height_m: float = 780.0
    speed_mps: float = 30.0
    frame_interval_s: float = 2.0
    heading_deg: float = 0.0
    orbit_radius_m: float = 450.0
    max_tilt_deg: float = 20.0
    yaw_jitter_deg: float = 15.0
    image_size: tuple[int, int] = (320, 240)
    focal_px: float = 300.0
    distortion: tuple[float, ...] = NAV_CAMERA_DISTORTION
    candidate_size_px: int = 448
    grid_px: int = 32
    absent_share: float = 0.1
    min_distractor_distance_m: float = 350.0
    max_distractor_nodata: float = 0.35
    photometric: PhotometricShift = field(default_factory=_default_shift)
    reference_latlon: tuple[float, float] | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.pattern not in ("orbit", "line"):
            raise InvalidInputError("pattern", f"expected orbit or line, got {self.pattern!r}")
        if self.n_frames < 1:
            raise InvalidInputError("n_frames", f"must be >= 1, got {self.n_frames}")
        if not 0.0 <= self.absent_share <= 1.0:
            raise InvalidInputError("absent_share", f"must be in [0, 1], got {self.absent_share}")
        if not 0.0 <= self.max_tilt_deg <= 45.0:
            raise InvalidInputError("max_tilt_deg", f"must be in [0, 45], got {self.max_tilt_deg}")
        check_candidate_size(self.candidate_size_px)
        if self.candidate_size_px % self.grid_px or self.grid_px <= 0:
            raise InvalidInputError(
                "grid_px", f"{self.grid_px} must be > 0 and divide {self.candidate_size_px}"
            )

    def calibration(self) -> CameraCalibration:
        w, h = self.image_size
        k = np.array(
            [
                [self.focal_px, 0, (w - 1) / 2 + 2.5],
                [0, self.focal_px, (h - 1) / 2 - 1.5],
                [0, 0, 1],
            ],
            dtype=np.float64,
        )
        return CameraCalibration(k, np.asarray(self.distortion, dtype=np.float64), (w, h))

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        out["frames_geotiff"] = Path(self.frames_geotiff).name
        out["store"] = Path(self.store).name
        return out
