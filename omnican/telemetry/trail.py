"""The path the base rolled so far, as the odometry saw it: what Foxglove's 3D panel draws
behind the base (``/odom/path``, ``nav_msgs/msg/Path``).

Pure. Bounded whatever the run's length: a point is kept each ``spacing_m`` of travel or
``spacing_rad`` of turn; when ``max_points`` are kept, every second one goes and the
spacing doubles, so the trail always covers the whole run, coarser as it grows (a
message of it stays a few tens of kB, sent once per :data:`PERIOD_S`). A pose more than
:data:`JUMP_M` from the one before it (the odometry reset to another place: no base
rolls that far in one sample) starts a new trail rather than drawing a line across.
"""

from __future__ import annotations

import math

from omnican.core.odometry import Pose2D

SPACING_M = 0.02  # a point each 2 cm of travel ...
SPACING_RAD = math.radians(10.0)  # ... or 10 degrees of turn
MAX_POINTS = 500
PERIOD_S = 0.5  # how often the trail is published (it changes slowly)
JUMP_M = 1.0


class Trail:
    """Stamped poses along the run, oldest first (see the module docstring)."""

    def __init__(self, spacing_m: float = SPACING_M, spacing_rad: float = SPACING_RAD,
                 max_points: int = MAX_POINTS) -> None:
        if max_points < 2:
            raise ValueError("a trail keeps at least 2 points")
        self._spacing = (spacing_m, spacing_rad)
        self.spacing_m, self.spacing_rad = self._spacing
        self.max_points = max_points
        self.points: list[tuple[int, Pose2D]] = []
        self._last: Pose2D | None = None

    def add(self, stamp_ns: int, pose: Pose2D) -> bool:
        """Keep ``pose`` if the base moved far enough since the last point kept; True
        when it was kept."""
        points, last_seen, self._last = self.points, self._last, pose
        if last_seen is not None and math.hypot(pose.x - last_seen.x,
                                                pose.y - last_seen.y) > JUMP_M:
            points.clear()
            self.spacing_m, self.spacing_rad = self._spacing
        if points:
            last = points[-1][1]
            if (math.hypot(pose.x - last.x, pose.y - last.y) < self.spacing_m
                    and abs(pose.theta - last.theta) < self.spacing_rad):
                return False
        if len(points) >= self.max_points:
            # Thin out: keep the first and every second one after it; the run stays whole.
            del points[1::2]
            self.spacing_m *= 2.0
            self.spacing_rad *= 2.0
        points.append((stamp_ns, pose))
        return True

