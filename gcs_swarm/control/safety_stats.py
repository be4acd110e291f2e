"""What the safety filter did: one cycle's ``SafetyReport``, a run's
``SafetyStats`` and its ``SafetyTotals`` (re-exported by
``gcs_swarm.control.safety``). Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.limits import BoolArray, FloatArray

__all__ = ["SafetyReport", "SafetyStats", "SafetyTotals"]


@dataclass(frozen=True, eq=False)
class SafetyReport:
    """What one ``SafetyFilter.filter`` call did, per vehicle (arrays of length N).

    correction_mps2 |a - a_des|; active: constraints met with equality (the
    |a| ball counts as one); infeasible: constraints conflicted and a best
    effort was returned; violation_mps2: the worst residual b - n.a of any row
    after the best effort (0 when feasible); min_clearance_m: signed distance
    to the nearest box (inf without boxes); min_separation_m: distance to the
    nearest other vehicle (inf when alone); min_keep_out_m: signed distance to
    the nearest keep-out box (inf without any). Distances are at the input
    state.
    """

    correction_mps2: FloatArray
    active: NDArray[np.int64]
    infeasible: BoolArray
    violation_mps2: FloatArray
    min_clearance_m: FloatArray
    min_separation_m: FloatArray
    min_keep_out_m: FloatArray

    @property
    def intervened(self) -> BoolArray:
        """Vehicles whose command was changed."""
        return np.asarray(self.correction_mps2 > 0.0)


@dataclass(frozen=True)
class SafetyTotals:
    """A run's totals (``SafetyStats.totals``), for the run summary and report."""

    cycles: int
    vehicle_cycles: int
    interventions: int
    infeasible: int
    max_correction_mps2: float
    mean_correction_mps2: float
    min_clearance_m: float
    min_separation_m: float

    def __str__(self) -> str:
        share = self.interventions / self.vehicle_cycles if self.vehicle_cycles else 0.0
        return (
            f"safety filter: intervened {self.interventions}/{self.vehicle_cycles} "
            f"vehicle-cycles ({100.0 * share:.1f} %), max |a - a_des| "
            f"{self.max_correction_mps2:.3g} m/s^2, mean when active "
            f"{self.mean_correction_mps2:.3g} m/s^2, infeasible {self.infeasible}, "
            f"min clearance {self.min_clearance_m:.3f} m, "
            f"min separation {self.min_separation_m:.3f} m"
        )


@dataclass
class SafetyStats:
    """Accumulates ``SafetyReport``s over a run (mutable, owned by one caller)."""

    cycles: int = 0
    vehicle_cycles: int = 0
    interventions: int = 0
    infeasible: int = 0
    max_correction_mps2: float = 0.0
    sum_correction_mps2: float = 0.0
    min_clearance_m: float = math.inf
    min_separation_m: float = math.inf

    def update(self, report: SafetyReport) -> None:
        """Add one cycle."""
        corr = report.correction_mps2
        self.cycles += 1
        self.vehicle_cycles += int(corr.size)
        self.interventions += int(np.count_nonzero(corr > 0.0))
        self.infeasible += int(np.count_nonzero(report.infeasible))
        if corr.size:
            self.max_correction_mps2 = max(self.max_correction_mps2, float(corr.max()))
            self.sum_correction_mps2 += float(corr.sum())
            self.min_clearance_m = min(self.min_clearance_m, float(report.min_clearance_m.min()))
            self.min_separation_m = min(self.min_separation_m, float(report.min_separation_m.min()))

    def totals(self) -> SafetyTotals:
        """The totals so far."""
        mean = self.sum_correction_mps2 / self.interventions if self.interventions else 0.0
        return SafetyTotals(
            cycles=self.cycles,
            vehicle_cycles=self.vehicle_cycles,
            interventions=self.interventions,
            infeasible=self.infeasible,
            max_correction_mps2=self.max_correction_mps2,
            mean_correction_mps2=mean,
            min_clearance_m=self.min_clearance_m,
            min_separation_m=self.min_separation_m,
        )
