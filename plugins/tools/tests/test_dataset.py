"""Flight datasets: rendering over real NAIP imagery, the format, ground truth, cross-date."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import haversine_m
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.flight import render_flight
from c3_matcher_tools.dataset.flight_scene import (
    grid_convergence_deg,
    grid_units_per_m,
    store_reference,
)
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import FORMAT, FlightDataset, FrameRecord, load_dataset
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.dataset.truth import inlier_errors_px
from c3_matcher_tools.geodesy import WGS84_A, WGS84_E2
from c3_matcher_tools.sim import load_orthophoto
from c3_matcher_tools.testing.geotiff import projected_keys, write_geotiff
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.geo import GeoGrid, read_geotiff_grid
from c3_matcher_tools.tilestore.projection import Projection

REPO = Path(__file__).resolve().parents[3]
NAIP = REPO / "data" / "imagery" / "naip_timeseries"
NAIP_2020 = NAIP / "m_4709963_se_14_1_20200831.tif"
NAIP_2010 = NAIP / "m_4709963_se_14_1_20100629.tif"


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("store") / "naip2020.mbtiles"
    build_mbtiles(NAIP_2020, path, zoom=15, tile_format="jpg")
    return path


def _render(store: Path, out: Path, frames_tif: Path, **kw: object) -> Path:
    spec = FlightSpec(frames_tif, store, n_frames=6, absent_share=1 / 3, seed=3, **kw)  # type: ignore[arg-type]
    return render_flight(spec, out, name="t")


def _ncc(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    x = a[mask].astype(np.float64)
    y = b[mask].astype(np.float64)
    x, y = x - x.mean(), y - y.mean()
    return float((x * y).sum() / math.sqrt((x * x).sum() * (y * y).sum()))


def _gt_correlation(root: Path) -> list[float]:
    """NCC between each frame (undistorted) and its true tile warped by the GT homography."""
    ds = load_dataset(root)
    k, dist = ds.calibration.K, ds.calibration.distortion
    out = []
    with ds.open_store() as st:
        for f in ds.frames:
            if f.true_index is None:
                continue
            c = f.candidates[f.true_index]
            tile = cv2.cvtColor(
                st.handle(c.tile_id, ds.candidate_size_px).decode(), cv2.COLOR_RGB2GRAY
            )
            frame = cv2.cvtColor(ds.nav_frame(f).image, cv2.COLOR_RGB2GRAY)
            und = cv2.undistort(frame, k, dist)
            size = ds.calibration.image_size
            warped = cv2.warpPerspective(tile, c.h_tile_to_undistorted, size)
            valid = cv2.warpPerspective(np.full_like(tile, 255), c.h_tile_to_undistorted, size)
            mask = (cv2.erode(valid, np.ones((9, 9), np.uint8)) > 0) & (und > 0)
            blur = (3, 3)
            out.append(
                _ncc(cv2.GaussianBlur(und, blur, 0), cv2.GaussianBlur(warped, blur, 0), mask)
            )
    return out


def test_flight_format_candidates_and_truth(store: Path, tmp_path: Path) -> None:
    root = _render(store, tmp_path / "flight", NAIP_2020)
    ds = load_dataset(root)
    assert ds.meta["format"] == FORMAT and len(ds.frames) == 6
    assert ds.meta["gt_fit_max_residual_px"] < 0.05
    absent = [f for f in ds.frames if not f.true_tile_present]
    assert len(absent) == 2 and sorted(f.index for f in absent) == ds.meta["absent_frames"]
    positions = set()
    for f in ds.frames:
        assert len(f.candidates) == 3 and sum(c.is_true for c in f.candidates) <= 1
        for c in f.candidates:
            if not c.is_true:
                assert c.distance_m >= 350.0
        tilt = math.degrees(
            math.acos(
                math.cos(math.radians(f.attitude_deg[0]))
                * math.cos(math.radians(f.attitude_deg[1]))
            )
        )
        assert tilt <= 20.0 + 1e-6
        positions.add(f.true_index)
        assert ds.nav_frame(f).image.shape == (240, 320, 3)
    assert len(positions - {None}) >= 2  # the true tile is not always in the same slot
    with ds.open_store() as st:
        rerank = ds.rerank(ds.frames[0], st)
        assert [c.tile_id for c in rerank.candidates] == [
            c.tile_id for c in ds.frames[0].candidates
        ]
    assert min(_gt_correlation(root)) > 0.8


def test_cross_date_ground_truth_from_the_geotiff_grids(store: Path, tmp_path: Path) -> None:
    # The 2010 and 2020 grids' origins differ by 1 m east and north (0.4 frame px). The flight
    # is flown in metres, so the same seed flies over the same ground: the ground truth of a
    # candidate must be the same homography whichever date the frames were rendered from.
    same = load_dataset(_render(store, tmp_path / "same", NAIP_2020))
    cross = load_dataset(_render(store, tmp_path / "xdate", NAIP_2010))
    assert cross.meta["frames_source"] == NAIP_2010.name
    assert cross.meta["tiles_source"] == NAIP_2020.name
    grid = np.array([[0.0, 0.0], [447.0, 0.0], [0.0, 447.0], [447.0, 447.0], [224.0, 224.0]])
    compared = 0
    for a, b in zip(same.frames, cross.frames, strict=True):
        assert a.true_tile_present == b.true_tile_present
        by_id = {c.tile_id: c for c in a.candidates}
        for cb in b.candidates:
            ca = by_id.get(cb.tile_id)
            if ca is None:  # distractor draws may differ (footprints differ by sub-pixels)
                continue
            assert ca.is_true == cb.is_true
            pa = cv2.perspectiveTransform(grid[None], ca.h_tile_to_undistorted)[0]
            pb = cv2.perspectiveTransform(grid[None], cb.h_tile_to_undistorted)[0]
            assert np.max(np.linalg.norm(pa - pb, axis=1)) < 0.05
            compared += 1
    assert compared >= sum(f.true_tile_present for f in same.frames)
    assert min(_gt_correlation(same.root)) > 0.8


def test_inlier_errors_are_zero_on_exact_correspondences(store: Path, tmp_path: Path) -> None:
    ds = load_dataset(_render(store, tmp_path / "f", NAIP_2020))
    f = next(f for f in ds.frames if f.true_index is not None)
    h = f.candidates[f.true_index].h_tile_to_undistorted
    tile_pts = np.array([[100.0, 120.0], [200.0, 210.0], [300.0, 150.0]])
    und = cv2.perspectiveTransform(tile_pts[None], h)[0]
    from c3_matcher import camera as cam

    query = cam.distort_points(und, ds.calibration)
    corr = np.hstack([query, tile_pts]).astype(np.float32)
    assert np.max(inlier_errors_px(h, ds.calibration, corr)) < 0.01
    corr[:, 0] += 3.0
    assert np.allclose(inlier_errors_px(h, ds.calibration, corr), 3.0, atol=0.01)


def test_impossible_flights_are_refused_with_the_parameter(store: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="candidate_size_px"):
        _render(store, tmp_path / "a", NAIP_2020, candidate_size_px=128)
    with pytest.raises(InvalidInputError, match="trajectory"):
        _render(store, tmp_path / "b", NAIP_2020, orbit_radius_m=3000.0)
    with pytest.raises(InvalidInputError, match="pattern"):
        FlightSpec(NAIP_2020, store, pattern="zigzag")


def test_load_dataset_names_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="dataset.json"):
        load_dataset(tmp_path)
    (tmp_path / "dataset.json").write_text('{"format": "other"}')
    with pytest.raises(InvalidInputError, match="format"):
        load_dataset(tmp_path)


def test_store_copy_is_self_contained(store: Path, tmp_path: Path) -> None:
    root = _render(store, tmp_path / "copy", NAIP_2020)
    with MBTilesStore(root / "tiles.mbtiles") as st:
        assert st.metadata["c3_source"] == NAIP_2020.name


def test_progress_bar_reports_to_its_stream() -> None:
    stream = io.StringIO()
    bar = ProgressBar("job", stream=stream, every=2)
    for i in range(1, 6):
        bar(i, 5)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("job [") and "1/5" in lines[0] and "5/5" in lines[-1]


def test_a_tangent_plane_stores_reference_is_reused_and_bad_metadata_named(store: Path) -> None:
    def georeference(projection: Projection) -> dict[str, str]:
        return {"c3_georeference": json.dumps(projection.to_dict())}

    plane = Projection("local_tangent_plane", ref_lat=51.83, ref_lon=4.97, ref_en=(1.0, 2.0))
    assert store_reference(georeference(plane), store) == (51.83, 4.97)
    assert store_reference(georeference(Projection("utm", zone=14)), store) is None
    assert store_reference({}, store) is None  # a store another tool built
    with MBTilesStore(store) as built:  # a UTM GeoTIFF's store
        assert store_reference(built.metadata, store) is None
    bad = {"c3_georeference": '{"kind": "lambert"}'}
    with pytest.raises(InvalidInputError, match=r"naip2020\.mbtiles.*unknown projection 'lambert'"):
        store_reference(bad, store)


def _regeoreferenced(path: Path, epsg: int, centre_en: tuple[float, float], scale: float) -> Path:
    """The NAIP 2020 pixels written as a GeoTIFF of EPSG ``epsg`` whose centre is at projected
    ``centre_en`` with a ``scale`` units/px pixel scale: a grid the shipped imagery lacks."""
    rgb = load_orthophoto(NAIP_2020).rgb
    h, w = rgb.shape[:2]
    top_left = (centre_en[0] - w / 2 * scale, centre_en[1] + h / 2 * scale)
    keys = projected_keys(epsg)
    return write_geotiff(path, rgb, scale=(scale, scale), top_left=top_left, keys=keys)


def _flight_over(tif: Path, out: Path, **kw: object) -> FlightDataset:
    """Three frames, each with its true tile, rendered over ``tif`` into ``out`` (its zoom-15
    store built beside it once)."""
    store = tif.with_suffix(".mbtiles")
    if not store.exists():
        build_mbtiles(tif, store, zoom=15, tile_format="jpg")
    spec = FlightSpec(tif, store, n_frames=3, absent_share=0.0, seed=5, **kw)  # type: ignore[arg-type]
    return load_dataset(render_flight(spec, out))


def _tile_bearing_error_deg(ds: FlightDataset, frame: FrameRecord) -> float:
    """How far (deg, clockwise) the true tile's up (true north: a web-mercator tile) lies from
    the north of the frame's recorded attitude, from its ground-truth homography: 0 when the
    recorded yaw is from true north."""
    from c3_matcher import camera as cam

    assert frame.true_index is not None
    truth = frame.candidates[frame.true_index]
    r_wc = cam.rotation_world_from_camera(frame.attitude, ds.calibration)
    a = r_wc @ np.linalg.inv(ds.calibration.K) @ truth.h_tile_to_undistorted
    c = ds.candidate_size_px / 2

    def ground(x: float, y: float) -> np.ndarray:  # (north, east) / height of a tile px
        ray = a @ np.array([x, y, 1.0])
        return np.asarray(ray[:2] / ray[2])

    up = ground(c, c - 10) - ground(c, c)
    right = ground(c + 10, c) - ground(c, c)
    errors = [math.atan2(up[1], up[0]), math.atan2(right[1], right[0]) - math.pi / 2]
    return math.degrees(float(np.mean(np.angle(np.exp(1j * np.array(errors))))))


def test_recorded_yaw_is_from_true_north_on_a_grid_with_convergence(tmp_path: Path) -> None:
    # UTM 14N 250 km east of its central meridian at 47 N: grid north is 2.4 deg east of true
    # north. The frames are rendered in the grid; their recorded yaw (and heading) must be from
    # true north, as an autopilot's, so the matcher's rectified frame is north-up like the tiles.
    utm = Projection("utm", zone=14)
    e, n = utm.from_lonlat([-99.0 + 3.3], [47.0])
    tif = _regeoreferenced(tmp_path / "utm_edge.tif", 32614, (float(e[0]), float(n[0])), 5.0)
    grid = read_geotiff_grid(tif)
    w, h = grid.size
    convergence = grid_convergence_deg(grid, ((w - 1) / 2, (h - 1) / 2))
    lon, lat = grid.centre_lonlat()
    assert convergence == pytest.approx((lon + 99.0) * math.sin(math.radians(lat)), abs=0.02)
    assert convergence > 2.3
    ds = _flight_over(tif, tmp_path / "flight")
    errors = [_tile_bearing_error_deg(ds, f) for f in ds.frames]
    assert len(errors) == 3 and max(abs(e) for e in errors) < 0.05, errors


def test_speed_and_radius_are_ground_metres_on_a_mercator_grid(tmp_path: Path) -> None:
    # web mercator at 47 N: 1.47 projected units per ground metre. A 60 m step (30 m/s x 2 s)
    # flown in projected units was 40.9 m on the ground.
    lat0 = 47.0
    merc = Projection("web_mercator")
    e, n = merc.from_lonlat([-98.9], [lat0])
    scale = 5.0 / math.cos(math.radians(lat0))  # 5 m on the ground, like the NAIP pixels
    tif = _regeoreferenced(tmp_path / "merc.tif", 3857, (float(e[0]), float(n[0])), scale)
    line = _flight_over(tif, tmp_path / "line", pattern="line", heading_deg=30.0)
    nadirs = np.array([[f.pose["nadir_lon"], f.pose["nadir_lat"]] for f in line.frames])
    steps = haversine_m(nadirs[:-1], nadirs[1:])
    np.testing.assert_allclose(steps, 60.0, rtol=0.005)
    orbit = _flight_over(tif, tmp_path / "orbit", orbit_radius_m=300.0)
    with MBTilesStore(tmp_path / "merc.mbtiles") as st:
        c_lon, c_lat = (float(v) for v in st.metadata["center"].split(",")[:2])
    nadirs = np.array([[f.pose["nadir_lon"], f.pose["nadir_lat"]] for f in orbit.frames])
    radii = haversine_m(nadirs, np.repeat([[c_lon, c_lat]], len(nadirs), axis=0))
    np.testing.assert_allclose(radii, 300.0, rtol=0.005)
    np.testing.assert_allclose(haversine_m(nadirs[:-1], nadirs[1:]), 60.0, rtol=0.005)


def test_grid_units_per_ground_metre_on_the_ellipsoid() -> None:
    # web mercator is the sphere's formula on WGS84 lon/lat: a/(N cos lat) units per metre east,
    # a/(M cos lat) north (0.34 % apart at 47 N); UTM 14N at its central meridian: k0 = 0.9996
    lat = 47.0
    phi = math.radians(lat)
    w2 = 1 - WGS84_E2 * math.sin(phi) ** 2
    n_radius, m_radius = WGS84_A / math.sqrt(w2), WGS84_A * (1 - WGS84_E2) / w2**1.5
    for projection, lon, expected in [
        (
            Projection("web_mercator"),
            -98.9,
            (WGS84_A / (n_radius * math.cos(phi)), WGS84_A / (m_radius * math.cos(phi))),
        ),
        (Projection("utm", zone=14), -99.0, (0.9996, 0.9996)),
    ]:
        e, n = projection.from_lonlat([lon], [lat])
        grid = GeoGrid(float(e[0]), float(n[0]), 2.0, 2.0, (10, 10), None, projection)
        units = grid_units_per_m(grid, (float(e[0]), float(n[0])))
        np.testing.assert_allclose(units, expected, rtol=1e-6)


def test_a_frame_whose_candidates_are_only_partly_labelled_has_no_truth() -> None:
    """Neither its truth nor its true tile counts (eval's C3-IT-04 and the run summary alike
    leave it out), whichever candidate says ``is_true``."""
    import uuid

    from c3_matcher.dto import TileId
    from c3_matcher_tools.dataset.format import CandidateTruth

    def frame(*labels: bool | None) -> FrameRecord:
        candidates = tuple(
            CandidateTruth(TileId(15, 47.0, -99.0 + i), 0.5, x) for i, x in enumerate(labels)
        )
        return FrameRecord(0, uuid.uuid4(), "f.jpg", 0, (0.0, 0.0, 0.0), 100.0, candidates)

    partly = frame(True, None)
    assert not partly.has_truth and not partly.true_tile_present
    labelled = frame(False, True)
    assert labelled.has_truth and labelled.true_tile_present and labelled.true_index == 1


@pytest.mark.parametrize("square", [False, True], ids=["equal-degrees", "square-on-the-ground"])
def test_a_frames_orthophoto_of_non_square_ground_pixels_is_refused(
    store: Path, tmp_path: Path, square: bool
) -> None:
    """The NAIP pixels in WGS84 degrees at 47 N: a pixel of equal degrees is 1.47 times as high
    as it is wide on the ground. The renderer takes pixels as squares, so its frames came out
    stretched east-west while their height and attitude described an upright camera. Degrees
    scaled by 1 / cos(lat) east-west are square on the ground and render."""
    from c3_matcher_tools.dataset.flight_scene import read_scene

    rgb = load_orthophoto(NAIP_2020).rgb
    h, w = rgb.shape[:2]
    lat_step = 5.0 / 111_200.0  # about 5 m of latitude
    lon_step = lat_step / math.cos(math.radians(47.02)) if square else lat_step
    top_left = (-99.1548 - w / 2 * lon_step, 47.0204 + h / 2 * lat_step)
    keys = (1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326)  # geographic, WGS84
    tif = write_geotiff(
        tmp_path / "degrees.tif", rgb, scale=(lon_step, lat_step), top_left=top_left, keys=keys
    )
    spec = FlightSpec(tif, store, n_frames=3, seed=5)
    with MBTilesStore(store) as opened:
        if square:
            assert read_scene(spec, opened).gsd == pytest.approx(5.0, rel=0.01)
            return
        with pytest.raises(InvalidInputError, match="pixels are .* wide and .* high"):
            read_scene(spec, opened)


def test_a_frame_whose_true_tile_lacks_what_it_sees_is_refused(tmp_path: Path) -> None:
    """A store built over a 1.5 km square of the sheet, a flight flown 1.45 km from its centre:
    the frames saw ground the store holds no imagery of, and their true tiles (empty) were still
    labelled present, scoring the matcher against a match nobody could make."""
    grid = read_geotiff_grid(NAIP_2020)
    rgb = load_orthophoto(NAIP_2020).rgb
    crop = np.ascontiguousarray(rgb[211:511, 317:617])
    top_left = (grid.origin_e + 317 * grid.scale_x, grid.origin_n - 211 * grid.scale_y)
    small = write_geotiff(
        tmp_path / "centre.tif",
        crop,
        scale=(grid.scale_x, grid.scale_y),
        top_left=top_left,
        keys=projected_keys(26914),
    )
    store = tmp_path / "centre.mbtiles"
    build_mbtiles(small, store, zoom=15, tile_format="jpg")
    spec = FlightSpec(
        NAIP_2020,
        store,
        n_frames=2,
        absent_share=0.0,
        orbit_radius_m=1450.0,
        height_m=400.0,
        candidate_size_px=256,
        seed=0,
    )
    with pytest.raises(InvalidInputError, match=r"frame 0: the store holds no imagery under"):
        render_flight(spec, tmp_path / "flight")
    assert not (tmp_path / "flight").exists()
