"""A rendered flight's frames as survey-drone photos with EXIF and XMP, written with ``piexif``."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from c3_matcher.camera import rotation_world_from_body
from c3_matcher.dto import Attitude
from c3_matcher_tools.testing.flightlogs import UTC0, Pose

__all__ = ["write_exif_photos"]


def _rational(value: float, den: int = 10_000) -> tuple[int, int]:
    return round(value * den), den


def _dms(value: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    value = abs(value)
    d = int(value)
    m = int((value - d) * 60)
    s = (value - d - m / 60) * 3600
    return (d, 1), (m, 1), _rational(s, 100_000)


def write_exif_photos(
    folder: Path, poses: Sequence[Pose], *, names: str = "DJI_{:04d}.JPG", xmp: bool = True
) -> Path:
    """The frames as JPEG photos carrying what a survey drone writes: EXIF capture time (UTC,
    with sub-seconds), GPS latitude/longitude/altitude above sea level, and (``xmp``) an XMP
    packet with ``drone-dji:RelativeAltitude`` and the gimbal's roll/pitch/yaw of the camera's
    pointing (pitch -90 = straight down)."""
    import datetime

    import piexif

    from c3_matcher.camera import DEFAULT_BODY_FROM_CAMERA
    from c3_matcher_tools.dataset.sources.track import attitude_from_matrix

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    forward_from_camera = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    for i, p in enumerate(poses):
        when = datetime.datetime.fromtimestamp(UTC0 + p.t_s, datetime.UTC)
        exif = {
            "0th": {},
            "Exif": {
                piexif.ExifIFD.DateTimeOriginal: when.strftime("%Y:%m:%d %H:%M:%S").encode(),
                piexif.ExifIFD.SubSecTimeOriginal: f"{when.microsecond // 1000:03d}".encode(),
            },
            "GPS": {
                piexif.GPSIFD.GPSLatitudeRef: b"N" if p.lat >= 0 else b"S",
                piexif.GPSIFD.GPSLatitude: _dms(p.lat),
                piexif.GPSIFD.GPSLongitudeRef: b"E" if p.lon >= 0 else b"W",
                piexif.GPSIFD.GPSLongitude: _dms(p.lon),
                piexif.GPSIFD.GPSAltitudeRef: 0,
                piexif.GPSIFD.GPSAltitude: _rational(p.alt_m, 1000),
            },
        }
        data = p.image.read_bytes()
        target = folder / names.format(i)
        piexif.insert(piexif.dump(exif), data, str(target))
        if xmp:
            r_cam = (
                rotation_world_from_body(Attitude.from_degrees(p.roll, p.pitch, p.yaw))
                @ DEFAULT_BODY_FROM_CAMERA
            )
            g_roll, g_pitch, g_yaw = attitude_from_matrix(r_cam @ forward_from_camera.T)
            packet = (
                '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF '
                'xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
                '<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
                f'drone-dji:RelativeAltitude="+{p.height_m:.3f}" '
                f'drone-dji:GimbalRollDegree="{g_roll:+.4f}" '
                f'drone-dji:GimbalPitchDegree="{g_pitch:+.4f}" '
                f'drone-dji:GimbalYawDegree="{g_yaw:+.4f}"/></rdf:RDF></x:xmpmeta>'
            ).encode()
            head = b"http://ns.adobe.com/xap/1.0/\x00" + packet
            jpeg = target.read_bytes()
            segment = b"\xff\xe1" + struct.pack(">H", len(head) + 2) + head
            target.write_bytes(jpeg[:2] + segment + jpeg[2:])
    return folder
