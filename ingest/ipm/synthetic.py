"""A synthetic drive with known truth, for tests, the benchmark and the README example.

A vehicle drives at constant speed along a circular arc (a right-hand bend) on a textured
ground plane: grass, a 7 m road with edge lines and a dashed centre line, and coloured
discs (markers) at known lon/lat. With :class:`LanePaint` the road is a multi-lane one (lanes of
their own widths each way, edge lines, a solid centre line, dashed lane lines, a stop line, and
optionally a zebra crossing and a turning lane opening along a taper) and :meth:`Drive.truth`
is the painted truth the lane-marking extraction is scored against.
Its roof-mounted panoramic camera (a lever arm and a tilted mount) sees the ground and the car's
red roof. The renderer deliberately shares no code with the IPM pipeline: it builds the camera
rotation with SciPy's Euler angles from the documented composition order, follows each pixel's
ray to the roof or the ground, and places the ground in an azimuthal-equidistant frame (not
UTM), so a mistake in the pipeline's geometry cannot cancel out against the same mistake here.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TypeVar, overload

import cv2
import numpy as np
import shapely
from pyproj import Transformer
from scipy.spatial.transform import Rotation

MARKER_RGB = {"red": (225, 25, 25), "blue": (25, 60, 225), "magenta": (215, 30, 215),
              "yellow": (235, 215, 15)}
PAINT_RGB = {"white": (235, 235, 235), "yellow": (230, 185, 40)}
ROOF_RGB = (225, 25, 25)  # the markers' red: an unmasked roof would be seen as markers
SKY_TOP, SKY_HORIZON = np.array([70, 120, 200.0]), np.array([190, 210, 235.0])
#: Local metres or degrees: one point (float) or many (array), returned in the same form.
Coord = TypeVar("Coord", float, np.ndarray)


@dataclass(frozen=True)
class Camera:
    """The truth the calibration file describes: a panorama camera on a lever arm above a
    car roof, mounted with a deliberate tilt so that every angle of the contract matters."""

    image_size: tuple[int, int] = (1024, 512)
    position_m: tuple[float, float, float] = (0.1, 0.2, 2.4)
    pitch_deg: float = 4.0
    roll_deg: float = -3.0
    yaw_deg: float = 7.0
    roof_z_m: float = 1.5
    roof_xy_m: tuple[float, float, float, float] = (-0.7, -1.2, 0.7, 1.0)
    """Car roof outline (x0, y0, x1, y1) in the vehicle frame."""

    def vehicle_from_camera(self) -> np.ndarray:
        """M with d_vehicle = M · d_cam: intrinsic yaw (about z, clockwise), pitch (x), roll
        (y), as the README documents."""
        return Rotation.from_euler("ZXY", [-self.yaw_deg, self.pitch_deg, self.roll_deg],
                                   degrees=True).as_matrix()

    def calibration(self, mask_name: str | None = "mask.png") -> dict:
        """The calibration JSON document of this camera, in the angle form (pitch/roll/yaw)
        rather than a matrix, so the pipeline's own angle composition is under test; no
        ``vehicle_mask`` when ``mask_name`` is falsy."""
        doc = {"image_size": list(self.image_size), "camera_position_m": list(self.position_m),
               "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg,
               "yaw_deg": self.yaw_deg}
        if mask_name:
            doc["vehicle_mask"] = mask_name
        return doc


@dataclass(frozen=True)
class LanePaint:
    """A multi-lane road's paint, across the road from its right edge to its left edge as seen
    in the drive's direction (right-hand traffic: the ``forward`` lanes first). Widths differ
    on purpose, so a road model of equal lanes cannot score well by accident."""

    widths_m: tuple[float, ...] = (3.5, 3.0, 3.25, 3.75)
    forward: int = 2
    """Lanes in the vehicle's direction (the right-hand ones); the rest go the other way."""
    centre_colour: str = "yellow"
    line_width_m: float = 0.15
    dash_m: tuple[float, float] = (3.0, 6.0)
    """Dash and gap length of the lane lines (metres along the line)."""
    stop_at_m: float | None = 30.0
    """Distance along the vehicle's path of a stop line across the forward lanes (None: none)."""
    stop_width_m: float = 0.4
    shoulder_m: float = 0.4
    """Asphalt beyond each edge line."""
    zebra_at_m: float | None = None
    """Distance along the vehicle's path of the middle of a zebra crossing (None: none): bars
    along the road across its whole width, the lines stopping short of it."""
    zebra_bar_m: tuple[float, float] = (0.5, 0.5)
    """Width of a zebra bar and the gap to the next."""
    zebra_length_m: float = 3.0
    """How far the zebra reaches along the road (each bar's length)."""
    zebra_clear_m: float = 0.5
    """How far short of the zebra the lines stop."""
    turn_at_m: float | None = None
    """Distance along the vehicle's path where a turning lane opens on the right of the
    forward lanes (None: none): the right edge line runs out by :attr:`turn_width_m` over
    :attr:`turn_taper_m` and stays out (to the far side of the bend), a dashed line parting
    the new lane from the next one from the end of the taper on."""
    turn_width_m: float = 3.0
    turn_taper_m: float = 15.0

    def turn_out_m(self, along_m: float | np.ndarray) -> np.ndarray:
        """How far right of the right edge line the road's right edge lies, ``along_m``
        metres along the vehicle's path (0 without a turning lane)."""
        along = np.asarray(along_m, float)
        if self.turn_at_m is None:
            return np.zeros(along.shape)
        return self.turn_width_m * np.clip((along - self.turn_at_m) / self.turn_taper_m, 0, 1)

    def boundaries_m(self) -> np.ndarray:
        """Offsets of the lane boundaries (edge, lane lines, edge) from the road's right edge
        line."""
        return np.concatenate([[0.0], np.cumsum(self.widths_m)])

    def line_kind(self, i: int) -> tuple[str, str]:
        """(kind, colour) of boundary ``i``: edge lines are road edges, the line between the
        directions is solid, the others dashed."""
        if i in (0, len(self.widths_m)):
            return "road_edge", "white"
        if i == self.forward:
            return "solid", self.centre_colour
        return "dashed", "white"


@dataclass(frozen=True)
class Drive:
    """The bend: centre (aeqd origin) at lon0/lat0, the vehicle on a circle of ``radius_m``
    driving clockwise from azimuth ``start_deg`` (seen from the centre)."""

    lon0: float = 17.6
    lat0: float = 48.15
    radius_m: float = 40.0
    start_deg: float = 200.0
    speed_mps: float = 8.0
    road_offset_m: float = 1.75
    """Road centre line this far outside the vehicle's path (it drives in the right lane)."""
    markers: tuple[tuple[str, float, float], ...] = field(default=(
        ("red", 6.0, -3.2), ("blue", 9.0, 4.5), ("magenta", 13.0, -4.0),
        ("yellow", 17.0, 3.5), ("blue", 21.0, -3.0), ("red", 25.0, 4.2),
        ("yellow", 29.0, -4.5), ("magenta", 33.0, 3.8)))
    """(colour, distance along the path from the start, metres left (+) of the path)."""
    marker_radius_m: float = 0.3
    lanes: LanePaint | None = None
    """A multi-lane road instead of the 7 m two-lane one (see :meth:`in_lane`)."""

    @classmethod
    def in_lane(cls, lanes: LanePaint, lane: int = 1, **kwargs: object) -> Drive:
        """A drive on ``lanes`` in the middle of lane ``lane`` (0: the rightmost)."""
        b = lanes.boundaries_m()
        offset = float(b[-1] / 2 - (b[lane] + b[lane + 1]) / 2)
        return cls(lanes=lanes, road_offset_m=offset, **kwargs)  # type: ignore[arg-type]

    def _line_radius(self, offset_m: float) -> float:
        """Radius of the line ``offset_m`` left of the paint's right edge line (the bend's
        centre is on the vehicle's right, so left is outwards)."""
        assert self.lanes is not None
        return self.radius_m + self.road_offset_m - float(self.lanes.boundaries_m()[-1]) / 2 \
            + offset_m

    def _aeqd(self) -> str:
        return f"+proj=aeqd +lat_0={self.lat0} +lon_0={self.lon0} +ellps=WGS84 +units=m"

    def to_lonlat(self, east: Coord, north: Coord) -> tuple[Coord, Coord]:
        """Local metres (the renderer's aeqd frame, deliberately not the pipeline's UTM) ->
        WGS84 lon/lat."""
        return Transformer.from_crs(self._aeqd(), "EPSG:4326",
                                    always_xy=True).transform(east, north)

    def to_local(self, lon: Coord, lat: Coord) -> tuple[Coord, Coord]:
        """WGS84 lon/lat -> local aeqd metres, where :meth:`texture` is defined."""
        return Transformer.from_crs("EPSG:4326", self._aeqd(),
                                    always_xy=True).transform(lon, lat)

    @overload
    def local_pose(self, s: float) -> tuple[float, float, float]: ...

    @overload
    def local_pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def local_pose(self, s: float | np.ndarray) -> tuple[float | np.ndarray, ...]:
        """(east, north, heading_deg) after ``s`` metres along the path."""
        az = np.radians(self.start_deg) + np.asarray(s, float) / self.radius_m
        east, north = self.radius_m * np.sin(az), self.radius_m * np.cos(az)
        return east, north, (np.degrees(az) + 90) % 360

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lon, lat, heading_deg) at time ``t`` (s): the truth the pose stream samples."""
        east, north, heading = self.local_pose(np.asarray(t, float) * self.speed_mps)
        lon, lat = self.to_lonlat(east, north)
        return lon, lat, heading

    def marker_points(self) -> list[tuple[str, float, float]]:
        """(colour, east, north) of every marker."""
        out = []
        for colour, s, left in self.markers:
            east, north, heading = self.local_pose(s)
            h = math.radians(float(heading))
            # Left of a vehicle heading h is the direction h - 90°.
            out.append((colour, float(east - left * math.cos(h)),
                        float(north + left * math.sin(h))))
        return out

    def marker_lonlats(self) -> list[tuple[str, float, float]]:
        """(colour, lon, lat) of every marker: where a test expects to find them on the map."""
        out = []
        for colour, east, north in self.marker_points():
            lon, lat = self.to_lonlat(east, north)
            out.append((colour, float(lon), float(lat)))
        return out

    def from_road_centre_m(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Signed ground distance (m) of lon/lat points from the road's centre line (+ outside
        the bend): what an extracted centreline is scored by."""
        east, north = self.to_local(np.asarray(lon, float), np.asarray(lat, float))
        return np.hypot(east, north) - (self.radius_m + self.road_offset_m)

    def share_found(self, coverage: shapely.Geometry, lines: shapely.Geometry,
                    within_m: float = 1.0) -> float:
        """Share of the road's centre line inside ``coverage`` (lon/lat: what the drive saw)
        that lies within ``within_m`` of ``lines`` (lon/lat: the extracted roads)."""
        radius = self.radius_m + self.road_offset_m
        azimuth = np.radians(np.arange(0.0, 360.0, 0.05))
        lon, lat = self.to_lonlat(radius * np.sin(azimuth), radius * np.cos(azimuth))
        seen = shapely.contains_xy(coverage, lon, lat)
        local = shapely.transform(lines, lambda xy: np.column_stack(self.to_local(xy[:, 0],
                                                                                  xy[:, 1])))
        east, north = self.to_local(lon[seen], lat[seen])
        return float(shapely.dwithin(local, shapely.points(east, north), within_m).mean())

    def texture(self, east: np.ndarray, north: np.ndarray) -> np.ndarray:
        """Ground colour (..., 3) RGB float32 at local metres."""
        east, north = np.asarray(east, np.float32), np.asarray(north, np.float32)
        rgb = np.stack([70 + 22 * np.sin(east / 1.3) * np.cos(north / 1.7),
                        125 + 30 * np.sin((east + north) / 1.1),
                        55 + 20 * np.cos(north / 0.9)], axis=-1)
        r = np.hypot(east, north)
        centre = self.radius_m + self.road_offset_m
        half = 3.5 if self.lanes is None else \
            float(self.lanes.boundaries_m()[-1]) / 2 + self.lanes.shoulder_m
        # The bend's centre is on the right: a turning lane widens the road inwards.
        out = 0.0 if self.lanes is None else \
            self.lanes.turn_out_m(self.along_m(np.arctan2(east, north)))
        road = (r - centre <= half) & (centre - r <= half + out)
        asphalt = (108 + 14 * np.sin(east[road] / 0.8) * np.sin(north[road] / 1.0)
                   + 8 * np.cos((east[road] - north[road]) / 0.6))
        rgb[road] = np.stack([asphalt, asphalt, asphalt + 5], axis=-1)
        if self.lanes is None:
            along = np.arctan2(east, north) * centre
            lines = ((np.abs(r - (centre - 3.35)) < 0.075)
                     | (np.abs(r - (centre + 3.35)) < 0.075)
                     | ((np.abs(r - centre) < 0.075) & (np.mod(along, 6.0) < 3.0)))
            rgb[lines] = 235.0
        else:
            self._paint(rgb, east, north)
        for colour, me, mn in self.marker_points():
            near = (np.abs(east - me) <= self.marker_radius_m) \
                & (np.abs(north - mn) <= self.marker_radius_m)
            disc = near.copy()
            disc[near] = np.hypot(east[near] - me, north[near] - mn) <= self.marker_radius_m
            rgb[disc] = MARKER_RGB[colour]
        return rgb


    def _paint(self, rgb: np.ndarray, east: np.ndarray, north: np.ndarray) -> None:
        """Draw :attr:`lanes`' lines and stop line into ``rgb`` (in place)."""
        lanes = self.lanes
        assert lanes is not None
        r = np.hypot(east, north)
        azimuth = np.arctan2(east, north)
        clear = np.ones(r.shape, bool)
        if lanes.zebra_at_m is not None:
            turn = np.mod(azimuth - self._azimuth(lanes.zebra_at_m) + np.pi, 2 * np.pi) - np.pi
            along = np.abs(turn) * r  # metres from the zebra's middle, along the road
            clear = along > lanes.zebra_length_m / 2 + lanes.zebra_clear_m
            width, _ = lanes.zebra_bar_m
            for middle in self.zebra_bars():
                bar = np.abs(r - self._line_radius(middle)) <= width / 2
                rgb[bar & (along <= lanes.zebra_length_m / 2)] = PAINT_RGB["white"]
        along = self.along_m(azimuth)
        out = lanes.turn_out_m(along)

        def line(radius: float | np.ndarray, dashed: bool) -> np.ndarray:
            on = (np.abs(r - radius) < lanes.line_width_m / 2) & clear
            return on & (np.mod(azimuth * radius, sum(lanes.dash_m)) < lanes.dash_m[0]) \
                if dashed else on

        for i, offset in enumerate(lanes.boundaries_m()):
            kind, colour = lanes.line_kind(i)
            radius = self._line_radius(float(offset)) - (out if i == 0 else 0.0)
            rgb[line(radius, kind == "dashed")] = PAINT_RGB[colour]
        if lanes.turn_at_m is not None:  # the line parting the turning lane, once it is wide
            rgb[line(self._line_radius(0.0), True)
                & (along >= lanes.turn_at_m + lanes.turn_taper_m)] = PAINT_RGB["white"]
        if lanes.stop_at_m is not None:
            stop = self.stop_line()
            rgb[shapely.dwithin(stop, shapely.points(east, north), lanes.stop_width_m / 2)] = \
                PAINT_RGB["white"]

    def _azimuth(self, along_m: float) -> float:
        """Azimuth (radians, from the bend's centre) of the point ``along_m`` along the path."""
        return math.radians(self.start_deg) + along_m / self.radius_m

    def along_m(self, azimuth: np.ndarray) -> np.ndarray:
        """Metres along the vehicle's path (negative behind its start, half the bend either
        way) of the points at ``azimuth`` (radians, from the bend's centre)."""
        turn = np.mod(np.asarray(azimuth) - math.radians(self.start_deg) + np.pi, 2 * np.pi)
        return (turn - np.pi) * self.radius_m

    def zebra_bars(self) -> np.ndarray:
        """Offsets of the zebra bars' middles from the right edge line: one every bar and gap
        from the right edge to the left one."""
        lanes = self.lanes
        assert lanes is not None
        width, gap = lanes.zebra_bar_m
        return np.arange(width / 2, float(lanes.boundaries_m()[-1]) - width / 2 + 1e-9,
                         width + gap)

    def zebra_line(self) -> shapely.LineString:
        """The zebra crossing's line across the road (local metres), through its bars' middles
        from the outer edge of the first to that of the last."""
        lanes = self.lanes
        assert lanes is not None and lanes.zebra_at_m is not None
        az = self._azimuth(lanes.zebra_at_m)
        bars, half = self.zebra_bars(), lanes.zebra_bar_m[0] / 2
        r0, r1 = self._line_radius(bars[0] - half), self._line_radius(bars[-1] + half)
        return shapely.LineString([(r0 * math.sin(az), r0 * math.cos(az)),
                                   (r1 * math.sin(az), r1 * math.cos(az))])

    def stop_line(self) -> shapely.LineString:
        """The stop line's centre line (local metres), across the forward lanes."""
        lanes = self.lanes
        assert lanes is not None and lanes.stop_at_m is not None
        az = self._azimuth(lanes.stop_at_m)
        b = lanes.boundaries_m()
        r0 = self._line_radius(float(b[0])) - float(lanes.turn_out_m(lanes.stop_at_m))
        r1 = self._line_radius(float(b[lanes.forward]))
        return shapely.LineString([(r0 * math.sin(az), r0 * math.cos(az)),
                                   (r1 * math.sin(az), r1 * math.cos(az))])

    def truth(self, step_deg: float = 0.2) -> dict:
        """The painted truth as a GeoJSON FeatureCollection in lon/lat: every marking line
        (``kind``, ``colour``, ``width_m``; a dashed line whole, across its gaps, as an
        extraction should join it) around the full circle, the stop line, the zebra crossing
        (``crosswalk``, its line across the road, ``width_m`` its reach along it), and each lane
        (``lane`` index from the right edge, ``direction`` forward/backward, ``width_m``). With
        a turning lane the right edge line runs out along its taper and the turning lane's own
        line (``boundary`` -1) runs from the taper's end to the far side of the bend; the
        turning lane is not among the lanes."""
        lanes = self.lanes
        if lanes is None:
            raise ValueError("the drive has no lane paint")
        # Around the bend from its far side, where a turning lane (if any) ends.
        azimuth = math.radians(self.start_deg) + np.pi + np.radians(
            np.arange(0.0, 360.0 + step_deg / 2, step_deg))
        out = lanes.turn_out_m(self.along_m(azimuth))

        def ring(radius: float | np.ndarray, where: np.ndarray | None = None
                 ) -> list[list[float]]:
            az, rad = azimuth, np.broadcast_to(radius, azimuth.shape)
            if where is not None:
                az, rad = az[where], rad[where]
            lon, lat = self.to_lonlat(rad * np.sin(az), rad * np.cos(az))
            return np.column_stack([lon, lat]).tolist()

        features = []
        b = lanes.boundaries_m()
        for i, offset in enumerate(b):
            kind, colour = lanes.line_kind(i)
            features.append({"type": "Feature", "properties": {
                "feature": "marking", "kind": kind, "colour": colour,
                "width_m": lanes.line_width_m, "boundary": i},
                "geometry": {"type": "LineString", "coordinates": ring(
                    self._line_radius(float(offset)) - (out if i == 0 else 0.0))}})
        if lanes.turn_at_m is not None:
            features.append({"type": "Feature", "properties": {
                "feature": "marking", "kind": "dashed", "colour": "white",
                "width_m": lanes.line_width_m, "boundary": -1},
                "geometry": {"type": "LineString", "coordinates": ring(
                    self._line_radius(0.0),
                    self.along_m(azimuth) >= lanes.turn_at_m + lanes.turn_taper_m)}})
        across = [(self.stop_line(), "stop_line", lanes.stop_width_m)
                  if lanes.stop_at_m is not None else None,
                  (self.zebra_line(), "crosswalk", lanes.zebra_length_m)
                  if lanes.zebra_at_m is not None else None]
        for line, kind, width in filter(None, across):
            xy = np.asarray(line.coords)
            lon, lat = self.to_lonlat(xy[:, 0], xy[:, 1])
            features.append({"type": "Feature", "properties": {
                "feature": "marking", "kind": kind, "colour": "white", "width_m": width},
                "geometry": {"type": "LineString",
                             "coordinates": np.column_stack([lon, lat]).tolist()}})
        for i, width in enumerate(lanes.widths_m):
            features.append({"type": "Feature", "properties": {
                "feature": "lane", "lane": i, "width_m": width,
                "direction": "forward" if i < lanes.forward else "backward"},
                "geometry": {"type": "LineString", "coordinates": ring(
                    self._line_radius(float(b[i] + b[i + 1]) / 2))}})
        return {"type": "FeatureCollection", "features": features}


@lru_cache(maxsize=4)
def _vehicle_rays(camera: Camera, du: float, dv: float) -> np.ndarray:
    """(H, W, 3) vehicle-frame directions through each pixel at offset (du, dv) in it (the
    same for every frame of a drive: cached for the supersampling offsets)."""
    width, height = camera.image_size
    cols, rows = np.meshgrid(np.arange(width) + du, np.arange(height) + dv)
    phi = (cols / width - 0.5) * 2 * np.pi
    theta = rows / height * np.pi
    d_cam = np.stack([np.sin(theta) * np.sin(phi), np.sin(theta) * np.cos(phi),
                      np.cos(theta)], axis=-1)
    rays = (d_cam @ camera.vehicle_from_camera().T).astype(np.float32)
    rays.flags.writeable = False
    return rays


def _hit(camera: Camera, d: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where rays ``d`` from the camera meet the plane at height ``z``: (x, y, going down)."""
    cam = camera.position_m
    down = d[..., 2] < -1e-9
    t = (z - cam[2]) / np.where(down, d[..., 2], -1.0)
    return cam[0] + t * d[..., 0], cam[1] + t * d[..., 1], down


def _on_roof(camera: Camera, d: np.ndarray) -> np.ndarray:
    x, y, down = _hit(camera, d, camera.roof_z_m)
    x0, y0, x1, y1 = camera.roof_xy_m
    return down & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)


def render_frame(drive: Drive, camera: Camera, t: float, supersample: int = 2) -> np.ndarray:
    """The panorama (H, W, 3) BGR uint8 the camera takes at time ``t``."""
    east0, north0, heading = drive.local_pose(t * drive.speed_mps)
    h = math.radians(float(heading))
    offsets = (np.arange(supersample) + 0.5) / supersample
    acc = np.zeros((camera.image_size[1], camera.image_size[0], 3))
    for du in offsets:
        for dv in offsets:
            d = _vehicle_rays(camera, du, dv)
            gx, gy, down = _hit(camera, d, 0.0)
            colour = SKY_HORIZON + (SKY_TOP - SKY_HORIZON) * np.clip(d[..., 2], 0, 1)[..., None]
            roof = _on_roof(camera, d)
            ground = down & ~roof
            # Vehicle (x right, y forward) -> local east/north for heading h (clockwise).
            gx, gy = gx[ground], gy[ground]
            colour[ground] = drive.texture(east0 + gx * math.cos(h) + gy * math.sin(h),
                                           north0 - gx * math.sin(h) + gy * math.cos(h))
            colour[roof] = ROOF_RGB
            acc = acc + colour
    rgb = acc / supersample**2
    return np.clip(rgb[..., ::-1] + 0.5, 0, 255).astype(np.uint8)


def roof_mask(camera: Camera) -> np.ndarray:
    """(H, W) uint8, 255 where any part of the pixel (corners, edges, centre) sees the roof."""
    width, height = camera.image_size
    mask = np.zeros((height, width), bool)
    for du in (0.0, 0.5, 1.0):
        for dv in (0.0, 0.5, 1.0):
            mask |= _on_roof(camera, _vehicle_rays(camera, du, dv))
    return np.where(mask, 255, 0).astype(np.uint8)


def frame_times(count: int, frame_hz: float = 7.0, start_s: float = 0.513) -> np.ndarray:
    """Frame times that fall between pose samples (pose clock)."""
    return start_s + np.arange(count) / frame_hz


def write_drive(folder: Path, drive: Drive, camera: Camera, times: np.ndarray,
                pose_hz: float = 20.0, supersample: int = 2) -> dict[str, Path]:
    """Frames (JPEG) + frames.csv, poses.csv (``pose_hz`` samples spanning the frames, with
    an extra ``alt`` column) and calib.json + mask.png in ``folder``."""
    frames = folder / "frames"
    frames.mkdir(parents=True, exist_ok=True)
    with open(frames / "frames.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "file"])
        for i, t in enumerate(times):
            name = f"frame_{i:05d}.jpg"
            cv2.imwrite(str(frames / name), render_frame(drive, camera, float(t), supersample),
                        [cv2.IMWRITE_JPEG_QUALITY, 95])
            out.writerow([f"{t:.6f}", name])
    pose_t = np.arange(0.0, float(times[-1]) + 1.0, 1.0 / pose_hz)
    lon, lat, heading = drive.pose(pose_t)
    poses = folder / "poses.csv"
    with open(poses, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "lon", "lat", "heading_deg", "alt"])
        for row in zip(pose_t, lon, lat, heading, strict=True):
            out.writerow([f"{row[0]:.4f}", f"{row[1]:.9f}", f"{row[2]:.9f}", f"{row[3]:.5f}",
                          "212.0"])
    cv2.imwrite(str(folder / "mask.png"), roof_mask(camera))
    calib = folder / "calib.json"
    calib.write_text(json.dumps(camera.calibration(), indent=1))
    written = {"frames": frames, "poses": poses, "calib": calib, "mask": folder / "mask.png"}
    if drive.lanes is not None:
        written["truth"] = folder / "lanes_truth.geojson"
        written["truth"].write_text(json.dumps(drive.truth()))
    return written


def _widths(value: str) -> tuple[float, ...]:
    """``--lanes``: comma-separated lane widths, each a plausible lane (2–6 m)."""
    import argparse

    try:
        widths = tuple(float(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not lane widths like 3.5,3.0") from None
    if not widths or not all(2.0 <= w <= 6.0 for w in widths):
        raise argparse.ArgumentTypeError(f"{value!r}: every lane must be 2 to 6 m wide")
    return widths


def _size(value: str) -> tuple[int, int]:
    """``--size WxH`` of the panorama (2:1, as an equirectangular panorama is)."""
    import argparse

    try:
        width, height = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not WxH") from None
    if width != 2 * height or width < 256:
        raise argparse.ArgumentTypeError(f"{value!r}: a panorama is 2:1 and at least 256x128")
    return width, height


def main(argv: list[str] | None = None) -> None:
    """``python -m ingest.ipm.synthetic OUT [--frames N]``: write the synthetic drive of the
    tests (frames, poses, calibration, roof mask) into folder OUT, ready for ``ugvmap ingest
    ipm OUT/frames --poses OUT/poses.csv --calib OUT/calib.json --layer SLUG``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m ingest.ipm.synthetic",
        description="Write a synthetic panorama drive with known truth (a right-hand bend at "
                    "17.6 E 48.15 N) for `ugvmap ingest ipm`.")
    parser.add_argument("out", type=Path, help="folder to write frames/, poses.csv, "
                                               "calib.json and mask.png into")
    parser.add_argument("--frames", type=int, default=36,
                        help="frames at 7 Hz (default 36, about 5 s of driving)")
    parser.add_argument("--lanes", metavar="W,W,...", type=_widths,
                        help="a multi-lane road: lane widths in metres from the right edge "
                             "(e.g. 3.5,3.0,3.25,3.75), with edge lines, a solid centre line, "
                             "dashed lane lines and a stop line; writes lanes_truth.geojson")
    parser.add_argument("--forward", type=int, help="lanes in the driving direction (the "
                        "right-hand ones; default half of --lanes, rounded up)")
    parser.add_argument("--lane", type=int, default=None,
                        help="the lane the vehicle drives in, 0 = rightmost (default: the "
                             "leftmost forward lane)")
    parser.add_argument("--centre-colour", choices=sorted(PAINT_RGB), default="yellow",
                        help="colour of the solid line between the directions")
    parser.add_argument("--zebra-at", type=float, metavar="M",
                        help="a zebra crossing M metres along the vehicle's path (with --lanes; "
                             "in lanes_truth.geojson as a crosswalk)")
    parser.add_argument("--turn-lane-at", type=float, metavar="M",
                        help="a turning lane opening on the right M metres along the vehicle's "
                             "path (with --lanes): the right edge runs out by 3 m over 15 m, "
                             "a dashed line parts the new lane from there on")
    parser.add_argument("--size", type=_size, default=Camera().image_size,
                        metavar="WxH", help="panorama size (default 1024x512)")
    args = parser.parse_args(argv)
    if args.frames < 2:
        parser.error("--frames must be at least 2")
    drive = Drive()
    if args.lanes:
        forward = args.forward if args.forward is not None else (len(args.lanes) + 1) // 2
        lane = args.lane if args.lane is not None else forward - 1
        if not 1 <= forward <= len(args.lanes) or not 0 <= lane < len(args.lanes):
            parser.error("--forward and --lane must name lanes of --lanes")
        drive = Drive.in_lane(LanePaint(args.lanes, forward, args.centre_colour,
                                        zebra_at_m=args.zebra_at, turn_at_m=args.turn_lane_at),
                              lane)
    elif any(v is not None for v in (args.forward, args.lane, args.zebra_at,
                                     args.turn_lane_at)):
        parser.error("--forward, --lane, --zebra-at and --turn-lane-at need --lanes")
    written = write_drive(args.out, drive, Camera(image_size=args.size),
                          frame_times(args.frames))
    for what, path in written.items():
        print(f"{what}: {path}")


if __name__ == "__main__":
    main()
