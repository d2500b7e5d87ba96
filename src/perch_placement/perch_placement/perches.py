"""Perch positions on regions, drone and camera poses, the gimbal window and the [0,1]^D encodings.

Drone frame: z along the region normal (into free space), x forward (walls: gravity-down projected
on the wall; ceilings and floors: towards the target centre). The camera's neutral optical axis is
the drone's z with image-down along the drone's x; the gimbal pans about the image's vertical axis,
then tilts about its horizontal axis (positive tilt looks up the image). Encodings: [region, u, v,
pan, tilt(, zoom)] (plane) or [region, face, pan, tilt(, zoom)] (mesh), all in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.polygons import to_shapely
from perch_common.types import ExclusionZone, PerchRegion, SurfaceClass
from perch_placement.config import DroneSpec

# Columns: the optical frame's x, y, z in the drone frame (x_opt = -y_drone, y_opt = x_drone, z_opt = z_drone).
DRONE_FROM_NEUTRAL = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Perch:
    """Decoded perches (batched): region index, drone pose, camera pose, gimbal and feasibility."""

    region: np.ndarray        # (B,) index into Perches.regions
    drone_position: np.ndarray  # (B,3) on the surface
    drone_rotation: np.ndarray  # (B,3,3) world-from-drone
    camera_position: np.ndarray
    camera_rotation: np.ndarray  # (B,3,3) world-from-optical
    pan: np.ndarray
    tilt: np.ndarray
    zoom: np.ndarray
    inside: np.ndarray        # (B,) position lies in its region

    def __len__(self) -> int:
        return len(self.region)

    def take(self, index) -> "Perch":
        """The perches at `index`."""
        return Perch(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


class Perches:
    """The perch regions prepared for decoding, gridding and feasibility tests."""

    def __init__(self, regions: list[PerchRegion], target_centre: np.ndarray, drone: DroneSpec,
                 up: np.ndarray = np.array([0.0, 0.0, 1.0]), encoding: str = "plane", max_zoom: float = 1.0,
                 border_margin: float = 0.0):
        if not regions:
            raise ValueError("no perch regions given: nothing to place cameras on")
        outlines = [to_shapely(r.polygons) for r in regions]
        for region, outline in zip(regions, outlines):
            if outline.is_empty:
                raise ValueError(f"perch region {region.id} has no polygon")
        # Perches keep border_margin inside their region's outline (plane encoding): outlines are exact
        # to a raster cell and the filter's geometry samples lie centimetres apart.
        shapes = [o.buffer(-border_margin) if border_margin > 0 else o for o in outlines]
        keep = [not shape.is_empty for shape in shapes]
        if not any(keep):
            raise ValueError(f"no perch region is wider than 2 x border_margin ({2 * border_margin:g} m): "
                             "nothing to place cameras on")
        self.regions = [r for r, k in zip(regions, keep) if k]
        self.border_margin = float(border_margin)
        self.drone = drone
        self.up = np.asarray(up, np.float64) / np.linalg.norm(up)
        self.target_centre = np.asarray(target_centre, np.float64)
        self.encoding = encoding
        self.max_zoom = float(max_zoom)
        self.shapes = [shape for shape, k in zip(shapes, keep) if k]
        import shapely

        for shape in self.shapes:
            shapely.prepare(shape)
        bounds = np.array([s.bounds for s in self.shapes])
        self.lo, self.hi = bounds[:, :2], bounds[:, 2:]
        areas = np.array([s.area for s in self.shapes])
        self.cdf = np.cumsum(areas) / areas.sum()
        self.normals = np.array([r.frame.normal for r in self.regions], np.float64)
        self.axis_u = np.array([r.frame.axis_u for r in self.regions], np.float64)
        self.axis_v = np.array([r.frame.axis_v for r in self.regions], np.float64)
        self.origins = np.array([r.frame.origin for r in self.regions], np.float64)
        self.shape_array = np.empty(len(self.shapes), object)
        self.shape_array[:] = self.shapes
        # Drones on walls hang head-down; elsewhere they face the target (the class the filter gave).
        self.is_wall = np.array([r.surface_class == SurfaceClass.WALL for r in self.regions], bool)
        if encoding == "mesh":
            self._prepare_faces()

    @property
    def dims(self) -> int:
        """Length D of an encoding: region selector, position (2 or 1), pan, tilt and zoom when enabled."""
        return (6 if self.encoding == "plane" else 5) - (self.max_zoom <= 1.0)

    def _prepare_faces(self) -> None:
        self.face_centroids, self.face_cdf = [], []
        for region in self.regions:
            if region.mesh.num_faces == 0:
                raise ValueError(f"perch region {region.id}: mesh encoding needs its triangulated mesh")
            areas = region.mesh.face_areas()
            self.face_centroids.append(region.mesh.face_centroids())
            self.face_cdf.append(np.cumsum(areas) / max(areas.sum(), 1e-12))

    # --- positions -------------------------------------------------------------------------

    def region_of(self, selector: np.ndarray) -> np.ndarray:
        """(B,) region index of each area-weighted selector in [0,1]."""
        return np.minimum(np.searchsorted(self.cdf, selector, side="right"), len(self.regions) - 1)

    def surface_points(self, region: np.ndarray, a: np.ndarray, b: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """World points on the regions and whether each lies inside its region."""
        if self.encoding == "plane":
            # Every region at once, as PlaneFrame.to_world (height 0) and _contains compute each.
            lo = self.lo[region]
            uv = lo + np.stack([a, b], -1) * (self.hi[region] - lo)
            points = (self.origins[region] + uv[:, :1] * self.axis_u[region] + uv[:, 1:2] * self.axis_v[region]
                      + 0.0 * self.normals[region])
            return points, self._contains_many(region, uv)
        points = np.zeros((len(region), 3))
        for r in np.unique(region):
            sel = region == r
            face = np.minimum(np.searchsorted(self.face_cdf[r], a[sel]), len(self.face_cdf[r]) - 1)
            points[sel] = self.face_centroids[r][face]
        return points, np.ones(len(region), bool)

    def _contains(self, r: int, uv: np.ndarray) -> np.ndarray:
        import shapely

        return shapely.intersects_xy(self.shapes[r], uv[:, 0], uv[:, 1])

    def _contains_many(self, region: np.ndarray, uv: np.ndarray) -> np.ndarray:
        import shapely

        return shapely.intersects_xy(self.shape_array[region], uv[:, 0], uv[:, 1])

    def packing(self, min_spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Region indices and world points of drones at least `min_spacing` apart on the regions (as
        far inside as border_margin, and 1 mm more so that decoded positions stay inside), as many as
        a packing finds (shortfall.packing)."""
        from perch_placement.shortfall import packing

        return packing([s.buffer(-1e-3) for s in self.shapes], [r.frame for r in self.regions], min_spacing)

    def grid(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        """Region indices and world points of a grid (cell centres) inside every region."""
        regions, points = [], []
        for r, shape in enumerate(self.shapes):
            lo, hi = self.lo[r], self.hi[r]
            counts = np.maximum(1, np.round((hi - lo) / spacing)).astype(int)
            axes = [lo[i] + (np.arange(counts[i]) + 0.5) * (hi[i] - lo[i]) / counts[i] for i in range(2)]
            uv = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
            uv = uv[self._contains(r, uv)]
            if len(uv) == 0:  # a sliver smaller than the spacing still gets one perch
                p = shape.representative_point()
                uv = np.array([[p.x, p.y]])
            regions.append(np.full(len(uv), r))
            points.append(self.regions[r].frame.to_world(uv))
        return np.concatenate(regions), np.concatenate(points)

    # --- poses -----------------------------------------------------------------------------

    def drone_rotations(self, region: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(B,3,3) world-from-drone rotations at the points: head-down on walls, facing the target elsewhere."""
        normal = self.normals[region]
        towards = self.target_centre - points
        forward = np.where(self.is_wall[region][:, None], -self.up, towards)
        forward = forward - (forward * normal).sum(-1, keepdims=True) * normal
        norm = np.linalg.norm(forward, axis=-1, keepdims=True)
        forward = np.where(norm > 1e-9, forward / np.maximum(norm, 1e-12), self.axis_u[region])
        # normal x forward, as np.cross computes it (without its axis shuffling)
        side = np.stack([normal[:, 1] * forward[:, 2] - normal[:, 2] * forward[:, 1],
                         normal[:, 2] * forward[:, 0] - normal[:, 0] * forward[:, 2],
                         normal[:, 0] * forward[:, 1] - normal[:, 1] * forward[:, 0]], axis=-1)
        return np.stack([forward, side, normal], axis=-1)

    def gimbal_window(self, camera_position: np.ndarray, drone_rotation: np.ndarray) -> np.ndarray:
        """(B,4) pan_lo, pan_hi, tilt_lo, tilt_hi: the gimbal range, intersected (targeting mode) with
        +-deviation around the direction to the target centre; an empty intersection collapses to the
        gimbal limit nearest that direction."""
        half_pan = np.radians(self.drone.pan_range_deg) / 2
        half_tilt = np.radians(self.drone.tilt_range_deg) / 2
        b = len(camera_position)
        window = np.tile([-half_pan, half_pan, -half_tilt, half_tilt], (b, 1)).astype(np.float64)
        if not self.drone.gimbal_limited_targeting:
            return window
        neutral = drone_rotation @ DRONE_FROM_NEUTRAL
        d = np.einsum("bk,bkj->bj", self.target_centre - camera_position, neutral)
        pan0 = np.arctan2(d[:, 0], d[:, 2])
        tilt0 = np.arctan2(-d[:, 1], np.hypot(d[:, 0], d[:, 2]))
        dev = np.radians(self.drone.target_deviation_deg)
        for col, centre, half in ((0, pan0, half_pan), (2, tilt0, half_tilt)):
            lo = np.maximum(centre - dev, -half)
            hi = np.minimum(centre + dev, half)
            empty = lo > hi
            edge = np.clip(centre, -half, half)
            window[:, col] = np.where(empty, edge, lo)
            window[:, col + 1] = np.where(empty, edge, hi)
        return window

    def mounts(self, region: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Drone rotations, camera positions and gimbal windows of drones perched at surface points."""
        rot = self.drone_rotations(region, points)
        cam = points + self.drone.camera_offset * self.normals[region]
        return rot, cam, self.gimbal_window(cam, rot)

    def pose(self, region: np.ndarray, points: np.ndarray, gimbal: np.ndarray,
             inside: np.ndarray | None = None, mounts: tuple | None = None) -> Perch:
        """Perches at surface points with gimbal coordinates (B, 2 or 3) in [0,1] (pan, tilt(, zoom))."""
        rot, cam, window = self.mounts(region, points) if mounts is None else mounts
        pan = window[:, 0] + gimbal[:, 0] * (window[:, 1] - window[:, 0])
        tilt = window[:, 2] + gimbal[:, 1] * (window[:, 3] - window[:, 2])
        zoom = 1.0 + (gimbal[:, 2] * (self.max_zoom - 1.0) if gimbal.shape[1] > 2 else 0.0)
        zoom = np.broadcast_to(zoom, (len(region),)).astype(np.float64)
        cam_rot = rot @ DRONE_FROM_NEUTRAL @ gimbal_rotation(pan, tilt)
        inside = np.ones(len(region), bool) if inside is None else inside
        return Perch(region, points, rot, cam, cam_rot, pan, tilt, zoom, inside)

    def decode(self, x: np.ndarray) -> Perch:
        """The perches (poses, gimbal angles, zoom) of encodings x (B,D) in [0,1]."""
        x = np.clip(np.asarray(x, np.float64).reshape(-1, self.dims), 0.0, 1.0)
        region = self.region_of(x[:, 0])
        if self.encoding == "plane":
            points, inside = self.surface_points(region, x[:, 1], x[:, 2])
            gimbal = x[:, 3:]
        else:
            points, inside = self.surface_points(region, x[:, 1], None)
            gimbal = x[:, 2:]
        return self.pose(region, points, gimbal, inside)

    def encode_position(self, region: int, point: np.ndarray) -> np.ndarray:
        """Plane-encoding [region, u, v] of a surface point (inverse of decode's position part)."""
        lo_cdf = self.cdf[region - 1] if region > 0 else 0.0
        uv = self.regions[region].frame.to_plane(point[None])[0]
        span = np.maximum(self.hi[region] - self.lo[region], 1e-12)
        return np.concatenate([[(lo_cdf + self.cdf[region]) / 2], np.clip((uv - self.lo[region]) / span, 0, 1)])

    # --- constraints -----------------------------------------------------------------------

    def feasible(self, perch: Perch, others: np.ndarray, exclusions: tuple[ExclusionZone, ...] = ()) -> np.ndarray:
        """Inside a region, at least min_spacing from every other drone, outside every exclusion zone."""
        ok = perch.inside.copy()
        others = np.asarray(others, np.float64).reshape(-1, 3)
        if len(others):
            gap = np.linalg.norm(perch.drone_position[:, None] - others[None], axis=-1).min(axis=1)
            ok &= gap >= self.drone.min_spacing
        for zone in exclusions:
            ok &= np.linalg.norm(perch.drone_position - np.asarray(zone.center), axis=1) >= zone.radius
        return ok


SEAT_RAYS = 7  # per side of the drone's footprint: rays that find the scanned surface under a perch
SEAT_NOISE = 1e-4  # m, smaller seat shifts are left out


def seat_on_scan(perch: Perch, scene, half_width: float, depth: float) -> Perch:
    """The perches moved along their normal onto the scanned surface under the drone.

    A region's plane is fitted to a whole surface; on a noisy scan the surface under one drone lies
    centimetres in front of or behind it (the filter judged support against that local plane). The
    perch moves to the median depth of the first hits of SEAT_RAYS x SEAT_RAYS rays over the drone's
    footprint (+-half_width) that land within `depth` of the plane; the camera moves with it. Perches
    with fewer than half their rays landing stay where they are."""
    normal = perch.drone_rotation[:, :, 2]
    axes_x, axes_y = perch.drone_rotation[:, :, 0], perch.drone_rotation[:, :, 1]
    steps = np.linspace(-half_width, half_width, SEAT_RAYS)
    a, b = (g.ravel() for g in np.meshgrid(steps, steps))
    foot = (perch.drone_position[:, None] + a[None, :, None] * axes_x[:, None] + b[None, :, None] * axes_y[:, None])
    origins = (foot + depth * normal[:, None]).reshape(-1, 3)
    hits = scene.cast(origins, np.repeat(-normal, len(a), axis=0))
    offset = np.where(hits.hit & (hits.distance <= 2 * depth), depth - hits.distance, np.nan).reshape(len(perch), -1)
    landed = np.isfinite(offset).sum(axis=1) >= 0.5 * len(a)
    shift = np.zeros(len(perch))
    if landed.any():
        shift[landed] = np.nanmedian(offset[landed], axis=1)
    shift[np.abs(shift) < SEAT_NOISE] = 0.0  # single-precision ray casting, not the scan
    move = shift[:, None] * normal
    seated = perch.take(slice(None))
    seated.drone_position = perch.drone_position + move
    seated.camera_position = perch.camera_position + move
    return seated


def gimbal_rotation(pan: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """(B,3,3) R_y(pan) @ R_x(tilt) in the optical frame."""
    cp, sp, ct, st = np.cos(pan), np.sin(pan), np.cos(tilt), np.sin(tilt)
    out = np.empty(np.shape(pan) + (3, 3))
    # R_y(pan) @ R_x(tilt) multiplied out.
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = cp, sp * st, sp * ct
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = 0.0, ct, -st
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = -sp, cp * st, cp * ct
    return out
