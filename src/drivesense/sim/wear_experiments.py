"""The second paper's tool-wear experiments (Table 1, A-H, and the Section 4 calibration) as conditions.

What each experiment cuts -- tool, material, spindle speed, feeds, immersions, the interval between
calibrations -- and the calibration cuts it makes; :mod:`drivesense.sim.tool_life` simulates a tool's life
through them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivesense.machine.cutting_power import CutConditions

__all__ = ["PASS_LENGTH", "WearExperiment", "section4_calibration", "table1_experiments"]

_RPM = 2 * math.pi / 60
_DEG = math.pi / 180
#: Cut distance of one wear cut [m]: a pass along the paper's 6-inch bar (assumed; experiment B calibrates after
#: every pass, G and H after 4, C and D after 22).
PASS_LENGTH = 0.1524
#: The calibration feeds, as multiples of the wear feed.
_CAL_FEEDS = (0.5, 0.75, 1.0, 1.25)

@dataclass(frozen=True)
class WearExperiment:
    """One tool-wear experiment of the paper's Table 1.

    Parameters
    ----------
    name : str
        Label ("A".."H").
    tool_material : {"HSS", "carbide"}
        Cutter material.
    diameter : float
        Tool diameter [m].
    flutes : int
        Number of flutes.
    spindle_speed : float
        Spindle speed [rad/s].
    feeds : tuple of float
        Feeds per tooth [m] the tool wears (and, for continuous experiments, calibrates) at.
    angles : tuple of (float, float)
        Entry/exit angles [rad] it cuts at.
    calibration_interval : float
        Cut distance between calibrations [m]; 0 = calibrating continuously.
    calibration_material : {"steel", "aluminium"}
        Workpiece of the calibration cuts.
    paper_mode : str
        Dominant wear mode the paper reports ("FW", "CH", "FW+").
    axial_depth : float
        Axial depth of cut [m] (not in Table 1: 2.54 mm assumed).
    nominal_calibrations : float
        Median life in calibration intervals [-] (assumption, see the module notes).
    """

    name: str
    tool_material: str
    diameter: float
    flutes: int
    spindle_speed: float
    feeds: tuple
    angles: tuple
    calibration_interval: float
    calibration_material: str = "steel"
    paper_mode: str = "FW"
    axial_depth: float = 2.54e-3
    nominal_calibrations: float = 16.0

    @property
    def continuous(self) -> bool:
        """True when the tool calibrates continuously (interval 0)."""
        return self.calibration_interval == 0.0

    def cut(self, feed: float, angles: tuple) -> CutConditions:
        """The cut at one feed per tooth [m] and (entry, exit) angles [rad].

        Parameters
        ----------
        feed : float
            Feed per tooth [m].
        angles : tuple of float
            Entry and exit angle [rad].

        Returns
        -------
        CutConditions
        """
        return CutConditions(self.diameter, self.flutes, self.axial_depth, self.spindle_speed, feed, *angles)

    def calibration_cuts(self) -> list[CutConditions]:
        """The cuts of one calibration: all feeds x angles (continuous) or 4 feeds at the wear angles.

        Returns
        -------
        list of CutConditions
        """
        if self.continuous:
            return [self.cut(f, a) for a in self.angles for f in self.feeds]
        return [self.cut(m * self.feeds[0], a) for a in self.angles for m in _CAL_FEEDS]

    def wear_cut(self) -> CutConditions:
        """The nominal wear condition (middle feed and angle).

        Returns
        -------
        CutConditions
        """
        return self.cut(self.feeds[len(self.feeds) // 2], self.angles[len(self.angles) // 2])


def section4_calibration() -> WearExperiment:
    """The paper's Sec. 4 calibration test: a 12.7 mm end mill, eight radial immersions at four feeds.

    Slot; down milling at 75, 50, 25 and 7 % immersion; up milling at 75, 50 and 25 % — on the
    4-flute carbide tool of experiment C (2674 rpm), feeds 0.04-0.10 mm/tooth (assumed: the paper
    gives neither the tool nor the feeds). Calibrated continuously (every cut is a calibration cut).

    Returns
    -------
    WearExperiment
    """
    angles = ((0.0, math.pi),) + tuple((a * _DEG, math.pi) for a in (60, 90, 120, 150)) + \
        tuple((0.0, a * _DEG) for a in (120, 90, 60))
    return WearExperiment("S4", "carbide", 12.7e-3, 4, 2674 * _RPM, tuple(f * 1e-3 for f in (.04, .06, .08, .10)),
                          angles, 0.0, paper_mode="-")


def table1_experiments() -> dict[str, WearExperiment]:
    """Experiments A-H of the paper's Table 1 (SI units; distances between calibrations read as metres).

    Returns
    -------
    dict of str to WearExperiment
    """
    four = tuple((a * _DEG, math.pi) for a in (0, 60, 90, 120))
    mm = 1e-3
    return {
        "A": WearExperiment("A", "HSS", 12.7 * mm, 1, 1068 * _RPM, tuple(f * mm for f in (.019, .028, .033, .040)),
                            four, 0.0),
        "B": WearExperiment("B", "HSS", 12.7 * mm, 1, 1528 * _RPM, (.053 * mm,), ((90 * _DEG, math.pi),), 0.152),
        "C": WearExperiment("C", "carbide", 12.7 * mm, 4, 2674 * _RPM, (.076 * mm,), ((120 * _DEG, math.pi),),
                            3.39, paper_mode="CH"),
        "D": WearExperiment("D", "carbide", 12.7 * mm, 4, 4011 * _RPM, (.051 * mm,), ((120 * _DEG, math.pi),),
                            3.39, paper_mode="CH"),
        "E": WearExperiment("E", "HSS", 9.525 * mm, 1, 1068 * _RPM, tuple(f * mm for f in (.019, .028, .033, .040)),
                            four, 0.0),
        "F": WearExperiment("F", "carbide", 9.525 * mm, 1, 3055 * _RPM,
                            tuple(f * mm for f in (.027, .030, .034, .038, .041)), four, 0.0, paper_mode="CH"),
        "G": WearExperiment("G", "HSS", 7.9375 * mm, 1, 2444 * _RPM, (.0254 * mm,), ((0.0, math.pi),), 0.610,
                            "aluminium"),
        "H": WearExperiment("H", "HSS", 7.9375 * mm, 1, 3666 * _RPM, (.0254 * mm,), ((0.0, math.pi),), 0.610,
                            "aluminium", paper_mode="FW+"),
    }
