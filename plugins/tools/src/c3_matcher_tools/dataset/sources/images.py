"""Where a recorded flight's images come from: a folder of photos (file-name order; each
photo's EXIF/XMP metadata read with ``exifread``, the tools' ``logs`` extra) or a video
(OpenCV; every ``step``-th frame, its time from the video's own clock).

EXIF/XMP read per photo: capture time (``DateTimeOriginal`` + ``SubSecTimeOriginal``, UTC
unless ``OffsetTimeOriginal`` says otherwise), GNSS position (``GPSLatitude``/``GPSLongitude``/
``GPSAltitude``, the altitude above sea level), and from the XMP packet the height above the
take-off point (``RelativeAltitude``) and the gimbal's angles (``GimbalRollDegree``,
``GimbalPitchDegree``, ``GimbalYawDegree``: pitch -90 looks straight down) or, failing them, the
aircraft's (``FlightRollDegree``...), as DJI and others write them.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import logging
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import cv2

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.image_names import is_utf8
from c3_matcher_tools.dataset.sources.quiet import quiet
from c3_matcher_tools.dataset.sources.track import Shot, constant, logs_library

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "ImageProblem",
    "check_frame_step",
    "check_images_path",
    "copy_reason",
    "find_image_problem",
    "folder_shots",
    "image_problem",
    "read_images",
    "read_photo_metadata",
    "readable_shots",
    "unique_photos",
]

PHOTO_METADATA = "photo metadata (EXIF)"
"""What reading a photo's metadata is called where its reader (the logs extra) is missing."""
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v")
_XMP = re.compile(rb"<x:xmpmeta.*?</x:xmpmeta>", re.DOTALL)
XMP_KEYS = (
    "RelativeAltitude",
    "AbsoluteAltitude",
    "GimbalRollDegree",
    "GimbalPitchDegree",
    "GimbalYawDegree",
    "FlightRollDegree",
    "FlightPitchDegree",
    "FlightYawDegree",
)


def _ratio(value: Any) -> float:
    return float(value.num) / float(value.den) if value.den else math.nan


def _dms(tag: Any, ref: Any) -> float | None:
    if tag is None:
        return None
    d, m, s = (_ratio(v) for v in tag.values[:3])
    value = d + m / 60.0 + s / 3600.0
    return -value if ref is not None and str(ref.values).strip().upper() in ("S", "W") else value


def _xmp(data: bytes) -> dict[str, float]:
    """The XMP packet's numeric drone fields (any namespace prefix), parsed as XML."""
    import xml.etree.ElementTree as ET

    match = _XMP.search(data)
    if match is None:
        return {}
    try:
        root = ET.fromstring(match.group(0))
    except ET.ParseError:
        return {}
    out: dict[str, float] = {}
    for element in root.iter():
        items = list(element.attrib.items())
        if element.text and element.text.strip():
            items.append((element.tag, element.text))
        for key, value in items:
            local = key.rsplit("}", 1)[-1]
            if local in XMP_KEYS:
                try:
                    out[local] = float(str(value).strip())
                except ValueError:
                    continue
    return out


def read_photo_metadata(path: Path) -> dict[str, Any]:
    """``t_s`` (UTC seconds), ``lat``, ``lon``, ``alt_m``, ``relative_alt_m`` and the XMP
    angles of one photo, each only when the photo states it (see the module docstring)."""
    exifread = logs_library("exifread", path, PHOTO_METADATA)
    data = path.read_bytes()
    with _quiet_logger("exifread"):  # it logs "File format not recognized." and the like
        tags = exifread.process_file(io.BytesIO(data), details=False)
    out: dict[str, Any] = {}
    stamp = tags.get("EXIF DateTimeOriginal") or tags.get("Image DateTime")
    if stamp is not None:
        try:
            when = datetime.strptime(str(stamp.values).strip(), "%Y:%m:%d %H:%M:%S")
        except ValueError:
            when = None
        if when is not None:
            offset = tags.get("EXIF OffsetTimeOriginal")
            tz = UTC
            if offset is not None:
                m = re.fullmatch(r"([+-])(\d\d):(\d\d)", str(offset.values).strip())
                if m:
                    sign = -1 if m.group(1) == "-" else 1
                    tz = _tz(sign, int(m.group(2)), int(m.group(3)))
            t = when.replace(tzinfo=tz).timestamp()
            sub = tags.get("EXIF SubSecTimeOriginal")
            if sub is not None and str(sub.values).strip().isdigit():
                digits = str(sub.values).strip()
                t += int(digits) / 10 ** len(digits)
            out["t_s"] = t
    lat = _dms(tags.get("GPS GPSLatitude"), tags.get("GPS GPSLatitudeRef"))
    lon = _dms(tags.get("GPS GPSLongitude"), tags.get("GPS GPSLongitudeRef"))
    if lat is not None and lon is not None:
        out["lat"], out["lon"] = lat, lon
        alt = tags.get("GPS GPSAltitude")
        if alt is not None:
            ref = tags.get("GPS GPSAltitudeRef")
            below = ref is not None and str(ref.values).strip() in ("1", "[1]")
            out["alt_m"] = -_ratio(alt.values[0]) if below else _ratio(alt.values[0])
    xmp = _xmp(data)
    if "RelativeAltitude" in xmp:
        out["relative_alt_m"] = xmp["RelativeAltitude"]
    out.update({k: v for k, v in xmp.items() if k != "RelativeAltitude"})
    return out


@contextlib.contextmanager
def _quiet_logger(name: str) -> Iterator[None]:
    """The logger ``name`` silenced meanwhile: what it would say is not the import's to print
    (an image it cannot read is refused, or imported without metadata, by the import)."""
    logger = logging.getLogger(name)
    was = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = was


def check_images_path(path: Path, *, video: bool = True) -> None:
    """``InvalidInputError`` naming IMAGES unless ``path`` is a folder (or, when ``video``, a
    video file by its suffix): a path that does not exist is said to be missing."""
    if not path.exists():
        raise InvalidInputError("IMAGES", f"{path}: no such file or folder")
    if path.is_dir():
        return
    if video and path.suffix.lower() in VIDEO_SUFFIXES:
        return
    kinds = f"a folder of images or a video ({', '.join(VIDEO_SUFFIXES)})" if video else "a folder"
    raise InvalidInputError("IMAGES", f"{path}: not {kinds}")


def _tz(sign: int, hours: int, minutes: int) -> timezone:
    return timezone(sign * timedelta(hours=hours, minutes=minutes))


def folder_shots(folder: Path, *, metadata: bool = True) -> list[Shot]:
    """The photos in ``folder`` (file-name order), each with its EXIF time and metadata in
    ``own`` when ``metadata``: then refused once, naming the logs extra, where its EXIF reader
    is not installed (never taken as photos that state nothing)."""
    folder = Path(folder)
    check_images_path(folder, video=False)
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InvalidInputError("IMAGES", f"{folder}: no image ({', '.join(IMAGE_SUFFIXES)}) in it")
    odd = [p.name for p in files if not is_utf8(p.name)]
    if odd:  # a name is kept as text in the dataset, its frame id made from it
        raise InvalidInputError(
            "IMAGES",
            f"{folder}: {len(odd)} photo name(s) not UTF-8 text (a byte of another encoding), "
            f"first {odd[0]!r}: rename them",
        )
    if metadata:
        logs_library("exifread", folder, PHOTO_METADATA)
    shots = []
    for p in files:
        own: dict[str, Any] = read_photo_metadata(p) if metadata else {}
        shots.append(Shot(p.name, p.read_bytes, p.suffix.lower(), own.get("t_s"), own))
    return shots


def unique_photos(shots: Sequence[Shot]) -> tuple[list[Shot], list[tuple[str, str]]]:
    """The photos without the byte-for-byte copies of an earlier one (two files of the same
    bytes are one capture, copied), and [(copy, why skipped)] naming the photo it copies."""
    first: dict[bytes, str] = {}
    kept: list[Shot] = []
    skipped: list[tuple[str, str]] = []
    for shot in shots:
        digest = hashlib.sha256(shot.read()).digest()
        if digest in first:
            skipped.append((shot.name, copy_reason(first[digest])))
            continue
        first[digest] = shot.name
        kept.append(shot)
    return kept, skipped


def copy_reason(was: str) -> str:
    """Why :func:`unique_photos` sets aside a copy of the photo ``was``."""
    return f"a copy of {was} (the same bytes): imported once, as {was}"


UNREADABLE = "not a readable image"
"""What :func:`image_problem` says of a file that is not a readable image (then its reason)."""


@dataclass(frozen=True)
class ImageProblem:
    """Why an encoded image cannot be a frame: ``unreadable``, it is no readable image at all
    (an empty file, a cut-short copy, not an image); else it is one the camera did not take (of
    another size)."""

    reason: str
    unreadable: bool


def image_problem(data: bytes, size: tuple[int, int]) -> str | None:
    """Why the encoded image ``data`` cannot be a frame of a ``size`` (w, h) camera, or None:
    every import checks its images with this (:func:`find_image_problem`)."""
    problem = find_image_problem(data, size)
    return None if problem is None else problem.reason


def find_image_problem(data: bytes, size: tuple[int, int]) -> ImageProblem | None:
    """Why the encoded image ``data`` cannot be a frame of a ``size`` (w, h) camera, or None.
    The size is read from the header first (an image of another size is never decoded, however
    large it says it is), then the image is decoded as the matcher will decode it: a copy cut
    short or damaged is not readable, and is refused before a decoder would write its own line
    to stderr. The camera's size bounds the decode, whatever the matcher's pixel limit (a
    replay of the flight applies the limit it is given)."""
    from c3_matcher.tiles import ImageDecodeError, decode_image, image_header_size

    if not data:
        return ImageProblem("an empty file, not an image", unreadable=True)
    header = image_header_size(data)
    if header is None:
        return ImageProblem(UNREADABLE, unreadable=True)
    w, h = header
    if (w, h) != tuple(size):
        return ImageProblem(
            f"is {w}x{h} px, the calibration says {size[0]}x{size[1]}", unreadable=False
        )
    try:
        decode_image(data, "image", max_pixels=w * h, as_displayed=True)
    except ImageDecodeError as exc:
        return ImageProblem(f"{UNREADABLE}: {exc.reason}", unreadable=True)
    return None


def readable_shots(
    shots: Sequence[Shot], size: tuple[int, int], skipped: Sequence[tuple[str, str]] = ()
) -> tuple[list[Shot], list[tuple[str, str]], list[tuple[str, str]]]:
    """The ``shots`` that are readable images, each checked once (:func:`find_image_problem`),
    before they meet the log: (readable shots, [(file, why)] of those that are not, ``skipped``
    with each copy of one of those (:func:`copy_reason`) said to be one). An image of a size
    other than ``size`` is refused naming it (a photo of another camera, or a calibration of
    another)."""
    kept: list[Shot] = []
    unreadable: list[tuple[str, str]] = []
    for shot in shots:
        problem = find_image_problem(shot.read(), size)
        if problem is None:
            kept.append(shot)
        elif problem.unreadable:
            unreadable.append((shot.name, problem.reason))
        else:
            raise InvalidInputError("IMAGES", f"{shot.name}: {problem.reason}")
    copies = {
        copy_reason(name): f"a copy of {name} (the same bytes), {why}" for name, why in unreadable
    }
    return kept, unreadable, [(n, copies.get(r, r)) for n, r in skipped]


def _video_frames(path: Path, step: int) -> list[Shot]:
    """Every ``step``-th frame of the video ``path`` as a JPEG (quality 95), with its time on
    the video's clock in ``own['relative_s']``; FFmpeg's own lines (a damaged packet, a file
    that is no video) kept from the terminal: the refusal says it in one line."""
    with quiet(io.StringIO()):
        return _decoded_frames(path, step)


def _decoded_frames(path: Path, step: int) -> list[Shot]:
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise InvalidInputError("IMAGES", f"{path}: not a readable video")
    shots: list[Shot] = []
    fps = capture.get(cv2.CAP_PROP_FPS) or 0.0
    index = 0
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            if index % step == 0:
                ms = capture.get(cv2.CAP_PROP_POS_MSEC)
                t = index / fps if fps > 0 else ms / 1e3
                good, jpeg = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 95])
                if not good:
                    raise InvalidInputError("IMAGES", f"{path}: frame {index} cannot be encoded")
                data = jpeg.tobytes()
                shots.append(
                    Shot(
                        f"{path.name}#{index}",
                        constant(data),
                        ".jpg",
                        None,
                        {"relative_s": float(t)},
                    )
                )
            index += 1
    finally:
        capture.release()
    if not shots:
        raise InvalidInputError("IMAGES", f"{path}: no frame could be read")
    return shots


def read_images(
    source: Path, step: int = 1, *, metadata: bool = True
) -> tuple[list[Shot], list[tuple[str, str]]]:
    """A folder of photos, its copies set aside (:func:`unique_photos`), each with its EXIF
    when ``metadata`` (:func:`folder_shots`; False where the photos pair with the log by trigger
    or file order, never by their own time), or every ``step``-th frame of a video file:
    (images, [(image, why skipped)]). The caller has checked ``step`` (``--frame-step``,
    :func:`check_frame_step`: refused with a folder)."""
    source = Path(source)
    check_images_path(source)
    if source.is_file():
        return _video_frames(source, step), []
    return unique_photos(folder_shots(source, metadata=metadata))


def check_frame_step(step: int, *, video: bool) -> None:
    """``InvalidInputError`` naming ``--frame-step`` unless ``step`` >= 1, and 1 unless the
    images are a video's (or a bag's) frames: a folder's photos are taken as they are."""
    if step < 1:
        raise InvalidInputError("--frame-step", f"must be >= 1, got {step}")
    if step != 1 and not video:
        raise InvalidInputError(
            "--frame-step",
            f"takes every N-th frame of a video or of a bag's image topic, not of a folder of "
            f"images (got {step}): leave out the photos not wanted",
        )
