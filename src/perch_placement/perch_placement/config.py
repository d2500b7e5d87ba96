"""Configuration of the placement stage: the camera, the drone and the search (thesis defaults).

Every field becomes a ROS parameter of the perch_placement node (nested ones as `camera.width`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from perch_common.config import StageNodeConfig, param
from perch_common.transforms import parse_up_axis

# The search methods (perch_placement.search.METHODS holds one function for each).
METHOD_NAMES = ("pso", "celf", "random", "grid", "naive")
# What the search maximises (perch_placement.search.context.SearchContext.alternative_objective).
OBJECTIVES = ("fitness", "expected", "kview", "worst_case")

# Intel RealSense D435 depth stream: 1280 x 720 px, 87 x 58 degrees field of view.
D435_FX = 640.0 / math.tan(math.radians(87.0 / 2))
D435_FY = 360.0 / math.tan(math.radians(58.0 / 2))


@dataclass
class CameraSpec:
    """A stereo depth camera: pinhole intrinsics, Brown-Conrady distortion and stereo error model."""

    name: str = param("d435", "camera profile name")
    width: int = param(1280, "image width", "px", low=1)
    height: int = param(720, "image height", "px", low=1)
    fx: float = param(D435_FX, "focal length along x (87 deg horizontal FOV)", "px", low=1e-6)
    fy: float = param(D435_FY, "focal length along y (58 deg vertical FOV)", "px", low=1e-6)
    cx: float = param(640.0, "principal point x", "px")
    cy: float = param(360.0, "principal point y", "px")
    distortion: tuple = param((0.0, 0.0, 0.0, 0.0, 0.0), "Brown-Conrady coefficients, OpenCV order k1 k2 p1 p2 k3")
    baseline: float = param(0.05, "stereo baseline", "m", low=1e-6)
    subpixel_error: float = param(0.08, "disparity (sub-pixel) error", "px", low=1e-6)
    min_range: float = param(0.2, "closest usable depth (r_min)", "m", low=0.0)
    max_range: float = param(10.0, "farthest depth before the feature-size cap", "m", low=1e-6)
    min_feature_size: float = param(0.05, "smallest feature to track (L_min)", "m", low=1e-6)
    min_feature_pixels: float = param(10.0, "pixels that feature must span (p_min)", "px", low=1e-6)
    max_zoom: float = param(1.0, "largest optical zoom factor (1 = no zoom)", low=1.0, high=100.0)

    @property
    def focal(self) -> float:
        """The focal length used by the range cap and the error model: the smaller of fx, fy
        (conservative: a feature must span p_min pixels along both image axes)."""
        return min(self.fx, self.fy)

    def max_distance(self, zoom: float = 1.0) -> float:
        """R_max = min(max_range, f * zoom * L_min / p_min)."""
        return min(self.max_range, self.focal * zoom * self.min_feature_size / self.min_feature_pixels)

    def validate(self) -> "CameraSpec":
        """Raise ValueError naming every unusable value; the camera itself otherwise."""
        problems = []
        if self.width <= 0 or self.height <= 0:
            problems.append(f"image size {self.width}x{self.height} must be positive")
        if not (self.fx > 0 and self.fy > 0):
            problems.append(f"focal lengths fx={self.fx}, fy={self.fy} must be positive")
        if len(self.distortion) != 5:
            problems.append(f"distortion needs 5 coefficients (k1 k2 p1 p2 k3), got {len(self.distortion)}")
        if not (self.baseline > 0 and self.subpixel_error > 0):
            problems.append("baseline and subpixel_error must be positive")
        if not (0 <= self.min_range < self.max_distance()):
            problems.append(f"range [{self.min_range}, {self.max_distance():.3f}] m is empty "
                            "(check min_range, max_range, min_feature_size, min_feature_pixels)")
        if self.max_zoom < 1:
            problems.append(f"max_zoom {self.max_zoom} must be >= 1")
        if problems:
            raise ValueError(f"camera '{self.name}': " + "; ".join(problems))
        return self


def camera_from_fov(name: str, width: int, height: int, hfov_deg: float, vfov_deg: float, **kw) -> CameraSpec:
    """A centred pinhole camera with the given fields of view (degrees)."""
    return CameraSpec(name=name, width=width, height=height,
                      fx=width / 2 / math.tan(math.radians(hfov_deg) / 2),
                      fy=height / 2 / math.tan(math.radians(vfov_deg) / 2),
                      cx=width / 2, cy=height / 2, **kw)


# Named camera profiles (PlacementConfig.camera_profile picks one instead of the camera.* parameters).
CAMERA_PROFILES = {
    "d435": CameraSpec(),
    "d455": camera_from_fov("d455", 1280, 720, 87.0, 58.0, baseline=0.095, max_range=20.0),
    "d405": camera_from_fov("d405", 1280, 720, 87.0, 58.0, baseline=0.018, min_range=0.07, max_range=0.5),
    "zed2": camera_from_fov("zed2", 1280, 720, 110.0, 70.0, baseline=0.12, subpixel_error=0.1,
                            min_range=0.3, max_range=20.0),
}


@dataclass
class DroneSpec:
    """A perching drone carrying the camera on a pan/tilt gimbal."""

    radius: float = param(0.25, "drone radius for flight clearance", "m", low=0.0, high=5.0)
    camera_offset: float = param(0.1, "camera distance from the perch surface", "m", low=0.0, high=2.0)
    pan_range_deg: float = param(90.0, "full gimbal pan range about the drone's forward axis", "deg", low=0.0, high=360.0)
    tilt_range_deg: float = param(90.0, "full gimbal tilt range", "deg", low=0.0, high=180.0)
    gimbal_limited_targeting: bool = param(True,
        "restrict pan/tilt to a window around the direction to the target centre")
    target_deviation_deg: float = param(40.0,
        "half-width of the targeting window", "deg", low=0.0, high=180.0)
    min_spacing: float = param(1.0, "minimum distance between perched drones", "m", low=0.0, high=100.0)


@dataclass
class PsoConfig:
    """Local-best particle swarm (numpy; one batched evaluation per generation)."""

    particles: int = param(50, "swarm size", low=2, high=100000)
    iterations: int = param(40, "maximum generations", low=1, high=100000)
    inertia: float = param(0.7, "velocity inertia weight", low=0.0, high=2.0)
    cognitive: float = param(0.5, "pull towards a particle's own best", low=0.0, high=4.0)
    social: float = param(0.4, "pull towards the neighbourhood best", low=0.0, high=4.0)
    neighbours: int = param(5, "neighbourhood size (nearest particles, self included)", low=1, high=100000)
    tolerance: float = param(0.001, "convergence: least best-fitness gain ...", low=0.0)
    patience: int = param(5, "... over this many generations", low=1, high=100000)
    seeded: int = param(25,
        "particles started at the best candidates of the discrete candidate set (0: all uniform random,"
        " as the original)", low=0, high=100000)
    polish_rounds: int = param(6, "hill-climbing rounds polishing each camera's swarm best (0: none)", low=0, high=1000)
    polish_samples: int = param(32, "batched samples per hill-climbing round (polish and CELF refinement)", low=1, high=100000)
    polish_step: float = param(0.05, "first hill-climbing step (standard deviation in [0,1] coordinates)", low=1e-6, high=1.0)
    initial_speed: float = param(0.1, "initial particle velocities are uniform in +-this", low=0.0, high=1.0)
    seeded_speed: float = param(0.2, "velocity factor of seeded particles (they search near their start first)",
                                low=0.0, high=1.0)


@dataclass
class LandingError:
    """Where a perching drone really lands (perch_placement.robustness). Defaults: the issue's stated
    scale of a perching miss (centimetres to a decimetre, 10 cm / 10 deg), taken as one standard
    deviation so that the robustness figures are on the cautious side of what a dry-adhesive
    gripper's landing achieves."""

    position_sigma: float = param(0.10, "landing offset standard deviation along each in-plane axis of the perch",
                                  "m", low=0.0, high=2.0)
    yaw_sigma_deg: float = param(10.0, "landing yaw (about the surface normal) standard deviation", "deg",
                                 low=0.0, high=180.0)
    gimbal_reaim: bool = param(False, "after landing the gimbal re-aims at the planned view within its pan/tilt "
                               "range (false: it keeps its angles relative to the body and turns with the drone)")
    samples: int = param(64, "Monte-Carlo landings per assessment (common random numbers for every arrangement)",
                         low=1, high=100000)
    search_samples: int = param(8, "landings per candidate in the robust objective (common random numbers)",
                                low=1, high=10000)
    seed: int = param(0, "seed of the landing draws", low=0)


@dataclass
class PlacementConfig:
    """Everything the placement search needs besides the scene."""

    num_cameras: int = param(5, "cameras to add", low=0, high=100)
    method: str = param("pso", "search: pso | celf | random | grid | naive", choices=METHOD_NAMES)
    encoding: str = param("plane",
        "position encoding: plane (in-plane coordinates) | mesh (area-weighted face selector)", choices=("plane", "mesh"))
    target_points: int = param(100, "target points sampled in the target volume (N)", low=1, high=100000)
    seed: int = param(0, "seed of the target samples and of the search", low=0)
    up_axis: str = param("+z", "gravity up direction")
    occlusion_epsilon: float = param(1e-3, "ignored length at both ends of a sight line", "m", low=0.0, high=0.1)
    candidate_spacing: float = param(0.15,
        "candidate grid spacing on the regions (CELF and the optimality bound)", "m", low=0.01, high=10.0)
    candidate_angles: int = param(7, "candidate pan and tilt steps (each)", low=1, high=64)
    refine_rounds: int = param(6, "CELF: hill-climbing rounds refining each chosen camera (0: none)", low=0, high=1000)
    reference_spacing: float = param(0.05, "exhaustive reference grid spacing", "m", low=0.005, high=10.0)
    reference_angles: int = param(13, "exhaustive reference pan and tilt steps (each)", low=1, high=64)
    compute_bound: bool = param(True, "report the greedy online optimality bound")
    border_margin: float = param(0.03, "perches keep this far inside their region's outline (outlines are exact to "
                                 "a raster cell; 0: up to the outline)", "m", low=0.0, high=1.0)
    seat_depth: float = param(0.05, "placed perches move along their normal onto the median of the scanned surface "
                              "under the drone, searched this far either side of the region's plane (0: off)", "m",
                              low=0.0, high=0.5)
    camera_profile: str = param("",
        "named camera profile (d435, d455, d405, zed2) overriding camera.*; empty: use camera.*",
        choices=("",) + tuple(CAMERA_PROFILES))
    kview_k: int = param(2, "k-view coverage: a point needs this many cameras ...", low=1, high=100)
    kview_angle_deg: float = param(30.0, "... with at least one pair of views this far apart at the point", "deg",
                                   low=0.0, high=180.0)
    objective: str = param("fitness",
        "what each camera's search maximises: fitness (the nominal one) | expected (mean fitness under the "
        "landing error) | kview (fitness + kview_weight x k-view coverage) | worst_case (fitness + "
        "resilience_weight x coverage after losing the worst camera)", choices=OBJECTIVES)
    kview_weight: float = param(0.5, "weight of k-view coverage in the kview objective", low=0.0, high=100.0)
    resilience_weight: float = param(0.5, "weight of the worst single-loss coverage in the worst_case objective",
                                     low=0.0, high=100.0)
    certificate: bool = param(True, "report the LP upper bound on the best coverage over the candidate set")
    certificate_seconds: float = param(2.0, "CPU seconds the certificate may take (its linear program included)",
                                       "s", low=0.01, high=3600.0)
    camera: CameraSpec = field(default_factory=CameraSpec)
    drone: DroneSpec = field(default_factory=DroneSpec)
    pso: PsoConfig = field(default_factory=PsoConfig)
    landing: LandingError = field(default_factory=LandingError)

    def resolved(self) -> "PlacementConfig":
        """The configuration with the camera profile applied, checked."""
        cfg = self
        if self.camera_profile:
            if self.camera_profile not in CAMERA_PROFILES:
                raise ValueError(f"camera_profile '{self.camera_profile}': use one of "
                                 f"{', '.join(CAMERA_PROFILES)} or leave it empty")
            cfg = replace(self, camera=CAMERA_PROFILES[self.camera_profile], camera_profile="")
        if cfg.encoding not in ("plane", "mesh"):
            raise ValueError(f"encoding '{cfg.encoding}': use plane or mesh")
        if cfg.target_points < 1:
            raise ValueError("target_points must be >= 1")
        if cfg.pso.particles < 2 or cfg.pso.iterations < 1:
            raise ValueError("pso needs >= 2 particles and >= 1 iteration")
        cfg.camera.validate()
        parse_up_axis(cfg.up_axis)
        return cfg

    def validate(self) -> "PlacementConfig":
        """Raise ValueError naming what is wrong (the profile, the camera, the up axis)."""
        self.resolved()
        return self


@dataclass
class PlacementNodeConfig(PlacementConfig, StageNodeConfig[PlacementConfig]):
    """The perch_placement node's parameters: the placement settings plus the node's own."""

    scene_cache_faces: int = param(1_000_000, "faces the ray-cast scenes kept for re-plans may hold together "
                                   "(about 150 bytes each); a larger mesh's scene is freed after its request",
                                   low=0, read_only=True)   # the cache is made when the node starts
