"""What is on the stage: geometry and the Sample read from ``sample.toml``."""

from __future__ import annotations

from core.sample.load import check_avoided_centres, load_sample, parse_sample, sample_from_dict
from core.sample.model import (
    CircleExclusion,
    Exclusion,
    PolygonExclusion,
    Sample,
    grid_baseline_s,
)
from core.sample.template import SAMPLE_TEMPLATE

__all__ = [
    "SAMPLE_TEMPLATE",
    "CircleExclusion",
    "Exclusion",
    "PolygonExclusion",
    "Sample",
    "check_avoided_centres",
    "grid_baseline_s",
    "load_sample",
    "parse_sample",
    "sample_from_dict",
]
