"""Benchmarks: `perch bench mission`, `memory`, `scans` and `soak`."""


def camera_count(text: str) -> int:
    """argparse type of a benchmark's --cameras: as perch plan's (0: the node's default, at most MAX_CAMERAS).
    Imported when a value is given: perch plan's module takes a moment to load."""
    from perch_operator.cli.plan import camera_count as plan_camera_count

    return plan_camera_count(text)
