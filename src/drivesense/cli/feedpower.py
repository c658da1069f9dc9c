"""``drivesense feedpower fit|predict``: feed-drive power to average x-force."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import check_output, console, friendly, key_column, write_json

__all__ = ["register", "feedpower_app"]

feedpower_app = typer.Typer(no_args_is_help=True,
                            help="Average x-force from the feed-drive motor's power (the paper's Sec. 6).")

_CUTS_HELP = ("CSV, one cut per row: slide_speed [mm/min] (in/min accepted), total_power [W] and tare_power [W] "
              "(hp accepted; or cutting_power), force_x [N] (lbf accepted) for fitting, optional slide_position.")
_IN_MIN = 0.0254 / 60


@feedpower_app.command("fit")
@friendly
def fit(
    cuts: Annotated[Path, typer.Argument(help=_CUTS_HELP)],
    model_path: Annotated[Path, typer.Option("--model", help="Where to write the model (JSON).")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write fit and cross-validation here.")] = None,
    plot: Annotated[Optional[Path], typer.Option(help="Write force vs cutting power per speed (Fig. 14).")] = None,
) -> None:
    """Calibrate efficiency versus slide speed from cuts with a reference force; write MODEL.json."""
    from drivesense.identify.feed_power import cross_validate, fit_feed_power, per_speed_fits, read_feed_cuts

    check_output(model_path, "--model")      # an output here: the same rule as --out
    data = read_feed_cuts(cuts)
    model = fit_feed_power(data)
    model.save(model_path)
    cv = cross_validate(data)
    table = Table(title=escape(f"Feed-drive power to x-force: {len(data)} cuts of {cuts.name}"))
    for col in ("slide speed", "cuts", "slope [N/W]", "intercept [N]", "R²", "eta(v)"):
        table.add_column(escape(col), justify="right", overflow="fold")
    for s in per_speed_fits(data):
        table.add_row(f"{s.speed * 6e4:.0f} mm/min ({s.speed / _IN_MIN:.0f} in/min)", str(s.cuts), f"{s.slope:.4g}",
                      f"{s.intercept:.3g}", f"{s.r2:.4f}", f"{model.efficiency(s.speed):.4g}")
    console.print(table)
    console.print(f"model: F_x = ({model.a0:.4g} {model.a1:+.4g} s/m * v) (P_total - P_tare) / v {model.f0:+.3g} N, "
                  f"rms error {model.rms_error:.2f} N; valid for {model.speed_range[0] * 6e4:.4g}-"
                  f"{model.speed_range[1] * 6e4:.4g} mm/min", highlight=False, markup=False)
    loso = ", ".join(f"{x['speed_m_s'] * 6e4:.0f} mm/min {100 * x['mean_error']:.1f} %" for x in cv["loso"])
    console.print(f"cross-validation: leave-one-cut-out mean error {100 * cv['loco_mean_error']:.1f} %"
                  + (f"; leave-one-speed-out {loso}" if loso else ""), highlight=False, markup=False)
    console.print(f"wrote {model_path}", markup=False)
    info = {"cuts": str(cuts), "model": model.to_dict(), "per_speed": [s.__dict__ for s in per_speed_fits(data)],
            "cross_validation": cv, "model_file": str(model_path)}
    if plot:
        from drivesense.plot import plot_feed_power, save_figure

        fig = plot_feed_power(data, model, per_speed_fits(data), title=f"Feed-drive power to x-force: {cuts.name}")
        save_figure(fig, plot)
        info["plot"] = str(plot)
        console.print(f"wrote {plot}", markup=False)
    write_json(json_path, info)


@feedpower_app.command("predict")
@friendly
def predict(
    cuts: Annotated[Path, typer.Argument(help=_CUTS_HELP)],
    model_path: Annotated[Path, typer.Option("--model", help="MODEL.json from 'feedpower fit'.")],
    out: Annotated[Path, typer.Option("--out", help="Prediction CSV to write.")],
    force_unit: Annotated[str, typer.Option(help="Unit of the force columns written: N, kN or lbf.")] = "N",
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write a JSON summary here.")] = None,
) -> None:
    """Predict the average x-force of each cut; cuts outside the calibrated range are flagged, not predicted."""
    import numpy as np

    from drivesense import units
    from drivesense.cli.common import warn
    from drivesense.identify.feed_power import FeedPowerModel, read_feed_cuts
    from drivesense.io import atomic_output

    units.unit_info(force_unit, quantity=units.FORCE, name="--force-unit")
    model = FeedPowerModel.load(model_path)
    data = read_feed_cuts(cuts)
    force = model.predict(data, skip_out_of_range=True)
    reasons = model.coverage_flags(data)
    f_out = units.from_si(force, force_unit)
    head = ["cut", "slide_speed [mm/min]", "cutting_power [W]", f"force_x_predicted [{force_unit}]"]
    tare = None
    if data.cutting_power is None and data.tare_power is None:
        tare = np.interp(data.slide_speed, model.tare_speeds, model.tare_powers)
    cols = [list(data.labels), data.slide_speed * 6e4, data.power(tare), f_out]
    flagged = [i for i, r in enumerate(reasons) if r]
    info = {"cuts": str(cuts), "model": str(model_path), "output": str(out),
            "predicted_n": [None if i in flagged else float(v) for i, v in enumerate(force)],
            "out_of_range": [{"cut": data.labels[i], "reason": reasons[i]} for i in flagged]}
    if data.force_x is not None:
        head += [f"force_x_measured [{force_unit}]", "error [%]"]
        err = 100 * (force / data.force_x - 1)
        cols += [units.from_si(data.force_x, force_unit), err]
        info["mean_abs_error"] = float(np.nanmean(np.abs(err)) / 100)
    # last column: 'ok' or why the cut was not predicted (empty cells above: pandas reads them as NaN)
    flags = ["out_of_range" if r else "ok" for r in reasons]
    head.append("flag")

    def cell(value) -> str:
        return "" if isinstance(value, float) and not np.isfinite(value) else f"{value:.6g}"

    lines = [",".join(head)] + [",".join([str(cols[0][i]), *(cell(c[i]) for c in cols[1:]), flags[i]])
                                for i in range(len(data))]
    with atomic_output(out) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    table = Table(title=escape(f"Predicted average x-force ({model_path.name})"))
    key_column(table, "cut", data.labels, justify="right")
    for h in head[1:]:
        table.add_column(escape(h), justify="right", overflow="fold")
    for i in range(len(data)):
        table.add_row(escape(str(cols[0][i])), *[f"{c[i]:.4g}" if np.isfinite(c[i]) else "-" for c in cols[1:]],
                      escape(flags[i]))
    console.print(table)
    if flagged:
        warn(f"{len(flagged)} of {len(data)} cut(s) not predicted (flag 'out_of_range' in {out}): "
             + "; ".join(f"cut {data.labels[i]}: {reasons[i]}" for i in flagged))
    if "mean_abs_error" in info:
        console.print(f"mean |error| against the measured force: {100 * info['mean_abs_error']:.1f} %", markup=False)
    console.print(f"wrote {out}", markup=False)
    write_json(json_path, info)


def register(root: typer.Typer) -> None:
    """Add the ``feedpower`` command group to the root application."""
    root.add_typer(feedpower_app, name="feedpower")
