"""Figures of drivesense, one module per concept; every ``plot_*`` function returns a Figure and writes nothing.

The figures are plain :class:`matplotlib.figure.Figure` objects built
without pyplot: making or saving one never selects or switches the user's
matplotlib backend and never opens a window.  Save them with
:func:`save_figure` (atomic; creates the folder), or show or embed them as
any matplotlib figure.

>>> from drivesense.plot import plot_trace_spectrum, save_figure
>>> fig = plot_trace_spectrum(rec, "x_current")          # doctest: +SKIP
>>> save_figure(fig, "x_current.png")                    # doctest: +SKIP
"""

from drivesense.plot.coefficients import plot_calibration
from drivesense.plot.estimates import plot_estimates, plot_force_estimate, plot_pocket_estimate
from drivesense.plot.events import plot_events
from drivesense.plot.feed_power import plot_feed_power
from drivesense.plot.figure import save_figure
from drivesense.plot.friction import plot_friction_maps
from drivesense.plot.frf import plot_frf_fit
from drivesense.plot.linear_axis import plot_identification
from drivesense.plot.sensor import plot_sensor_calibration
from drivesense.plot.stability import plot_stability_lobes
from drivesense.plot.trace import plot_trace_spectrum
from drivesense.plot.wear import plot_wear_track

__all__ = [
    "save_figure",
    "plot_estimates",
    "plot_force_estimate",
    "plot_pocket_estimate",
    "plot_friction_maps",
    "plot_frf_fit",
    "plot_calibration",
    "plot_identification",
    "plot_feed_power",
    "plot_sensor_calibration",
    "plot_wear_track",
    "plot_trace_spectrum",
    "plot_events",
    "plot_stability_lobes",
]
