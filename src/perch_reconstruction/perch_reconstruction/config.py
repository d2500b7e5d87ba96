"""Configuration of the reconstruction stage (ROS parameters of node perch_reconstruction)."""

from __future__ import annotations

from dataclasses import dataclass

from perch_common.config import StageNodeConfig, param


@dataclass
class ReconstructionConfig:
    """The reconstruction settings: TSDF volume, odometry, time synchronisation and cleaning."""

    # TSDF volume
    voxel_size: float = param(0.02, "TSDF voxel edge length", "m", low=0.0, high=1.0)
    block_resolution: int = param(16, "voxels per block edge of the VoxelBlockGrid", choices=(4, 8, 16, 32))
    max_blocks: int = param(15000, "memory bound: at most this many TSDF blocks (~82 kB each); frames that "
                                "would add more are skipped and counted", low=1)
    depth_min: float = param(0.1, "ignore depth closer than this", "m", low=0.0)
    depth_max: float = param(4.0, "ignore depth farther than this (sensor noise grows with range)", "m", low=0.0)
    depth_scale: float = param(0.0, "metres per raw depth unit; 0 = by encoding (16UC1 mm, 32FC1 m)", "m", low=0.0)
    trunc_voxel_multiplier: float = param(4.0, "TSDF truncation distance in voxels (4 x 2 cm keeps thin furniture)", low=0.0)
    weight_threshold: float = param(1.0, "extract surface where the TSDF weight reaches this", low=0.0)
    # Odometry (used when no poses are given)
    tracking_scale: float = param(0.25, "image scale for odometry (0.25 = 160x120 from 640x480; never below 160 px wide)",
                                  low=0.0, high=1.0)
    tracking_depth_diff: float = param(0.07, "max depth difference of an odometry correspondence", "m", low=0.0)
    tracking_min_fitness: float = param(0.2, "below this inlier share the frame is not integrated (lost)", low=0.0, high=1.0)
    # Time synchronisation
    sync_tolerance: float = param(0.005, "colour and depth stamps pair when this close", "s", low=0.0)
    pose_tolerance: float = param(0.02, "a pose stamp must lie this close to the frame stamp", "s", low=0.0)
    # Poses from /tf (when there is no pose topic): the chain from the camera frame up to the world
    # frame, moving edges from /tf (e.g. odom -> base_link) and the mount from /tf_static.
    tf_world_frame: str = param("map", "poses from /tf: the fixed frame the mesh is built in (map, odom)")
    tf_camera_frame: str = param("", "poses from /tf: the camera's frame ('' = the images' header frame_id)")
    # Cleaning (also the /perch/clean_mesh service defaults)
    merge_distance: float = param(1e-5, "vertices closer than this are merged", "m", low=0.0)
    min_piece_diameter: float = param(0.0, "connected pieces with a smaller bounding-box diagonal are removed (0: none)", "m",
                                      low=0.0)
    target_faces: int = param(100_000, "quadric edge-collapse decimation target (0 = no decimation)", low=0)
    gravity_align: bool = param(True, "rotate the mesh so gravity points along -z")
    min_up_confidence: float = param(0.5, "confidence (0..1, perch_common.up_axis) needed to trust an estimated up axis",
                                     low=0.0, high=1.0)
    seed: int = param(0, "seed of every random choice (metric sampling)", low=0)

    def validate(self) -> "ReconstructionConfig":
        """Raise ValueError naming the first unusable value; the configuration itself otherwise."""
        checks = [
            (self.voxel_size > 0, f"voxel_size must be > 0 m, got {self.voxel_size}"),
            (self.block_resolution in (4, 8, 16, 32), f"block_resolution must be 4, 8, 16 or 32, got {self.block_resolution}"),
            (self.max_blocks > 0, f"max_blocks must be > 0, got {self.max_blocks}"),
            (0 <= self.depth_min < self.depth_max, f"need 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}"),
            (self.depth_scale >= 0, f"depth_scale must be >= 0, got {self.depth_scale}"),
            (0 < self.tracking_scale <= 1, f"tracking_scale must be in (0, 1], got {self.tracking_scale}"),
            (self.min_piece_diameter >= 0, f"min_piece_diameter must be >= 0, got {self.min_piece_diameter}"),
            (self.target_faces >= 0, f"target_faces must be >= 0, got {self.target_faces}"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"reconstruction config: {message}")
        return self


@dataclass
class ReconstructionNodeConfig(ReconstructionConfig, StageNodeConfig[ReconstructionConfig]):
    """The node's parameters: the reconstruction settings plus live-input handling."""

    # read_only: subscriptions and timers made at start-up. The rest is re-read for every bag
    # reconstruction and cleaning, and for live input at the next /perch/reconstruct/reset.
    color_topic: str = param("/camera/color/image_raw", "colour images (sensor_msgs/Image rgb8/bgr8/...)",
                             read_only=True)
    depth_topic: str = param("/camera/depth/image_raw", "depth images registered to colour (16UC1 mm or 32FC1 m)",
                             read_only=True)
    camera_info_topic: str = param("/camera/depth/camera_info", "sensor_msgs/CameraInfo of the depth stream",
                                   read_only=True)
    pose_topic: str = param("/camera/pose", "world-from-camera poses (geometry_msgs/PoseStamped)", read_only=True)
    pose_type: str = param("pose", "type on pose_topic: 'pose' (PoseStamped) or 'odometry' (nav_msgs/Odometry); "
                                   "'tf': poses from /tf and /tf_static instead (tf_world_frame, tf_camera_frame)",
                           choices=("pose", "odometry", "tf"), read_only=True)
    lossless_replay: bool = param(False, "subscribe reliable + transient-local as `perch bag play` publishes "
                                      "(no frame lost); false: best effort, matching camera drivers and "
                                      "`ros2 bag play`", read_only=True)
    compressed_images: bool = param(False, "colour and depth arrive as sensor_msgs/CompressedImage", read_only=True)
    work_budget_per_frame: float = param(5.0, "work budget of a bag reconstruction: seconds per colour+depth "
                                         "frame of the bag, on top of work_budget_base (cleaning a mesh uses "
                                         "work_budget_rate per 1000 faces)", "s", low=0.0, high=3600.0)
    use_poses: bool = param(True, "live input: integrate the poses from pose_topic (false: RGB-D odometry)")
    gravity: list = param([0.0, 0.0, 0.0], "live input: gravity in the pose frame; zeros = estimate from floor/ceiling")
    queue_size: int = param(4, "frames waiting for integration; when full the OLDEST waiting frame is dropped "
                            "(counted) so the reconstruction follows the newest view", low=1, high=10000)
    camera_info_timeout: float = param(5.0, "report an error when images arrive without camera info this long", "s", low=0.0)
    pose_wait: float = param(0.5, "how long a frame waits for its pose to arrive", "s", low=0.0)
    drain_timeout: float = param(60.0, "Reconstruct waits at most this long for queued frames", "s", low=0.0)
    progress_period: float = param(1.0, "progress message period on /perch/reconstruct/progress", "s", low=0.0,
                                   read_only=True)
    frame_id: str = param("map", "frame of the returned mesh")

    def validate(self) -> "ReconstructionNodeConfig":
        """Raise ValueError naming the first unusable value; the configuration itself otherwise."""
        super().validate()
        if self.queue_size < 1:
            raise ValueError(f"reconstruction config: queue_size must be >= 1, got {self.queue_size}")
        if self.pose_type not in ("pose", "odometry", "tf"):
            raise ValueError(f"reconstruction config: pose_type must be 'pose', 'odometry' or 'tf', "
                             f"got '{self.pose_type}'")
        if len(self.gravity) != 3:
            raise ValueError(f"reconstruction config: gravity needs 3 numbers, got {list(self.gravity)}")
        return self
