"""Shared helpers of the figures: a pyplot-free :class:`~matplotlib.figure.Figure` and an atomic PNG writer.

Every figure of drivesense is a plain :class:`matplotlib.figure.Figure`
built without pyplot, so making or saving one never selects, switches or
touches the user's matplotlib backend (``fig.savefig`` attaches an Agg
canvas on demand for raster formats).
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from matplotlib.figure import Figure

__all__ = ["new_figure", "save_figure", "colour_cycle", "METHOD_COLOURS"]

#: Line colours of the estimation methods (others take matplotlib's default cycle).
METHOD_COLOURS = {"truth": "black", "current": "tab:gray", "rigid": "tab:orange", "medob": "tab:green",
                  "vibration": "tab:blue"}


def new_figure(figsize: tuple[float, float]) -> Figure:
    """A new pyplot-free figure.

    Parameters
    ----------
    figsize : tuple of float
        Width and height [inch].

    Returns
    -------
    matplotlib.figure.Figure
    """
    return Figure(figsize=figsize)


def colour_cycle() -> list[str]:
    """The colours of matplotlib's current property cycle (``axes.prop_cycle``).

    Returns
    -------
    list of str
    """
    import matplotlib

    return list(matplotlib.rcParams["axes.prop_cycle"].by_key()["color"])


def save_figure(fig: Figure, path, *, dpi: float = 110) -> Path:
    """Write a figure to a file atomically (a temporary file in the same folder, then :func:`os.replace`).

    The folder of `path` is created if missing.  The format follows the
    file's suffix (``.png``, ``.svg``, ``.pdf`` ...; matplotlib's default
    ``savefig.format`` without one).  On an error the temporary file is
    removed and an existing file at `path` is left untouched.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (as returned by the ``plot_*`` functions).
    path : str or Path
        Output file.
    dpi : float, optional
        Resolution [dots per inch]; a 10 x 7 inch figure at 110 dpi is 1100 x 770 pixels.

    Returns
    -------
    Path
        `path`.
    """
    import matplotlib

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = path.suffix[1:].lower() or matplotlib.rcParams["savefig.format"]
    # created by open() rather than mkstemp so that it gets the usual (umask) permissions
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    try:
        with open(tmp, "xb") as fh:
            fig.savefig(fh, format=fmt, dpi=dpi)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
