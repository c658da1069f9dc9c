"""Figure of a stability-lobe diagram: the critical axial depth against spindle speed, with test cuts."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from drivesense.errors import ConfigError
from drivesense.plot.figure import new_figure

if TYPE_CHECKING:
    from drivesense.machine.stability import StabilityLobes

__all__ = ["plot_stability_lobes"]

_CUT_STYLE = {"stable": dict(marker="o", color="tab:green", label="stable cut"),
              "chatter": dict(marker="x", color="tab:red", label="chatter")}


def _check_cuts(cuts) -> list[tuple[float, float, str]]:
    out = []
    for i, cut in enumerate(cuts):
        try:
            rpm, depth, label = cut
            rpm, depth = float(rpm), float(depth)
        except (TypeError, ValueError):
            raise ConfigError(f"'cuts'[{i}] must be (rpm, depth_m, label), got {cut!r}") from None
        if not isinstance(label, str) or label not in _CUT_STYLE:
            raise ConfigError(f"'cuts'[{i}] label must be 'stable' or 'chatter', got {label!r}")
        out.append((rpm, depth, label))
    return out


def plot_stability_lobes(lobes: "StabilityLobes", *, cuts: Sequence | None = None,
                         title: str | None = None) -> Figure:
    """The lobe envelope (axial depth [mm] against spindle speed [min^-1]) with the unstable region shaded.

    Parameters
    ----------
    lobes : StabilityLobes
        The envelope: ``spindle_rpm`` [rev/min], ``depth_limit`` [m]
        (NaN where unknown, inf where stable at any depth), ``chatter_frequency_hz`` [Hz].
    cuts : sequence of tuple, optional
        Test cuts ``(rpm, depth_m, label)`` (speed [rev/min], axial depth
        [m], ``"stable"`` or ``"chatter"``), drawn as green circles (stable)
        and red crosses (chatter).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One panel: the envelope, the unstable region above it shaded red,
        the lowest depth of the envelope dotted, and the cuts.
    """
    rpm = np.asarray(lobes.spindle_rpm, dtype=float)
    depth = np.asarray(lobes.depth_limit, dtype=float) * 1e3
    marks = _check_cuts(cuts or ())
    finite = np.isfinite(depth)
    fig = new_figure((9, 6))
    ax = fig.subplots()
    top = 1.15 * max([min(float(depth[finite].max()), 6.0 * float(depth[finite].min())) if finite.any() else 1.0]
                     + [d * 1e3 for _, d, _ in marks])
    if finite.any():
        lowest = float(depth[finite].min())
        shown = np.where(finite, np.minimum(depth, top), np.nan)
        ax.fill_between(rpm, shown, top, where=finite, color="tab:red", alpha=0.15, lw=0, label="unstable (chatter)")
        ax.plot(rpm, shown, color="black", lw=1.2, label="stability limit")
        ax.axhline(lowest, color="0.4", ls=":", lw=1, label=f"lowest limit {lowest:.3g} mm")
    else:
        ax.plot(rpm, np.zeros_like(rpm), color="black", lw=1.2, label="stable at any depth")
    for kind, style in _CUT_STYLE.items():
        pts = [(r, d * 1e3) for r, d, lab in marks if lab == kind]
        if pts:
            ax.scatter(*zip(*pts), s=40, zorder=3, **style)
    ax.set_xlim(rpm[0], rpm[-1])
    ax.set_ylim(0.0, top)
    ax.set_xlabel("spindle speed [min$^{-1}$]")
    ax.set_ylabel("axial depth of cut [mm]")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(title or "Stability lobes (zeroth-order approximation)")
    fig.tight_layout()
    return fig
