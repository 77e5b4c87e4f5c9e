"""A fast array on the emulator: the fast channel's readings (``drivers.sim.fast_channel``) at its sites.

The CSM truth at the sites (hardness, modulus, their per-indent sds) is the emulator's own field, clamped to
its area as a CSM indent's is; a reading is a pure function of (seed, block id, index in the array), so a
resumed array reads what an uninterrupted one would have.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.plan import Block
from drivers.sim.fast_channel import CsmAtSites, FastPhysics, FastReadings, FastTable, read_array
from drivers.sim.truth import NoiseOverride, truth_modulus_gpa, truth_modulus_noise_sd_gpa
from drivers.sim.truth_csv import CsvTruth

if TYPE_CHECKING:
    from drivers.sim.emulator import Emulator


def read_fast_block(emulator: Emulator, physics: FastPhysics, block: Block) -> FastReadings:
    """Every site's reading of the fast array ``block`` (failed indents NaN and flagged)."""
    xy = np.array([(s.x_um, s.y_um) for s in block.indents], dtype=float)
    x_min, x_max, y_min, y_max = emulator.truth.bounds_um
    cx, cy = np.clip(xy[:, 0], x_min, x_max), np.clip(xy[:, 1], y_min, y_max)
    truth = emulator.truth
    csm = CsmAtSites(
        np.asarray(truth.hardness_gpa(cx, cy), dtype=float),
        np.asarray(truth.noise_sd_gpa(cx, cy), dtype=float),
        np.asarray(truth_modulus_gpa(truth, cx, cy), dtype=float),
        np.asarray(truth_modulus_noise_sd_gpa(truth, cx, cy), dtype=float),
    )
    r = read_array(physics, emulator.seed, block.block_id, cx, cy, csm, table=file_fast_table(truth))
    return FastReadings(xy[:, 0], xy[:, 1], r.hardness_gpa, r.modulus_gpa, r.depth_nm, r.failed)


def file_fast_table(truth: object) -> FastTable | None:
    """What a truth file says a fast indent reads (its fast columns), None where it says nothing: then the
    fast channel's physics. A noise override changes the CSM scatter only, so the file's columns still hold."""
    base = truth.base if isinstance(truth, NoiseOverride) else truth
    return base.fast_table if isinstance(base, CsvTruth) else None
