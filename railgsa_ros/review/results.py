"""What a review is: its options (``ReviewOptions``) and its results (``Review``).

``build.build_review`` makes a ``Review``; ``report``, ``outputs`` and ``build.write_review``
read one. Kept apart from ``build`` so that the writers do not import the builder.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from railgsa_ros.location import Location, Reference
from railgsa_ros.models.coach import CoachModel
from railgsa_ros.offline import Source
from railgsa_ros.review.exceedances import Exceedance
from railgsa_ros.review.health import InputHealth
from railgsa_ros.review.stream import ReviewRun
from railgsa_ros.review.truth import Comparison
from railgsa_ros.review.worst import WorstSurrogate
from railgsa_ros.standards.en13848 import Limits, LimitTable
from railgsa_ros.standards.line_speed import LineSpeed
from railgsa_ros.standards.sections import Sections
from railgsa_ros.uncertainty import UncertaintyConfig
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import VehicleParams


@dataclass(frozen=True)
class ReviewOptions:
    """What to review and how: bag (and truth) paths, the uncertainty node's configuration
    (inversion included), nominal vehicle, uncertain parameters (None: no band), limit end
    ('lower'/'upper' of the standard's AL/IL ranges, without a manager's table), section length
    (m), topics, whether the IMU rate comes from the bag, the location reference (line, track,
    direction, km-post), the listing cut, the manager's limit table (None: the standard's) and
    the line's permitted speed (None: class by the measuring speed)."""

    bag: Path
    config: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    vehicle: VehicleParams | CoachModel = field(default_factory=VehicleParams)
    dists: Mapping[str, Distribution] | None = None
    truth: Path | None = None
    limit_end: str = 'lower'
    section_m: float = 200.0
    imu_topic: str = '/imu/data'
    odom_topic: str = '/odom'
    rate_from_bag: bool = True  # replace config.inversion.rate_hz by the bag's median rate
    gnss_topic: str = '/gnss/fix'
    reference: Reference = field(default_factory=Reference)
    min_probability: float = 0.0  # exceedances listed only when P(beyond the limit) >= this
    limits: LimitTable | None = None
    line_speed: LineSpeed | None = None

    @property
    def source(self) -> Source:
        """The bag and its topics."""
        return Source(self.bag, self.imu_topic, self.odom_topic, self.gnss_topic)


@dataclass(frozen=True)
class Review:
    """Everything a report shows (see ``render_html``): the options, the configuration in
    effect, the results and the wall-clock seconds per stage."""

    options: ReviewOptions
    config: UncertaintyConfig
    run: ReviewRun
    health: InputHealth
    limits: Limits
    exceedances: list[Exceedance]
    sections: Sections
    truth_sections: Sections | None
    comparison: Comparison | None
    worst: WorstSurrogate | None
    timings: dict[str, float]

    @property
    def duration_s(self) -> float:
        """Span of the IMU stamps (s)."""
        return self.health.imu.span_s

    @property
    def location(self) -> Location:
        """Where the run is (reference, odometry scale, GNSS track)."""
        return self.run.location
