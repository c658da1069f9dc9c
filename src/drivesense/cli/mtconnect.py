"""``drivesense mtconnect probe|import``: MTConnect ingest."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich import box
from rich.markup import escape
from rich.table import Table

from drivesense.cli.common import console, friendly, key_column, show_warnings, write_json

__all__ = ["register", "mtconnect_app"]

mtconnect_app = typer.Typer(no_args_is_help=True,
                            help="MTConnect: list an agent's data items, import Streams documents, SHDR logs or "
                                 "a live agent into a recording.")


def _devices(source: Optional[str], timeout: float):
    """The Devices document of ``probe SOURCE`` or ``import --devices``: a file or an agent URL."""
    from drivesense.io.mtconnect import parse_devices
    from drivesense.io.mtconnect_client import MTConnectClient, is_agent_url

    if source is None:
        return None
    return MTConnectClient(source, timeout=timeout).probe() if is_agent_url(source) else parse_devices(Path(source))


@mtconnect_app.command("probe")
@friendly
def probe(
    source: Annotated[str, typer.Argument(help="Devices document (.xml) or agent URL (http://host:5000).")],
    json_path: Annotated[Optional[Path], typer.Option("--json", help="Write the data items as JSON here.")] = None,
    timeout: Annotated[float, typer.Option(help="HTTP timeout [s].")] = 10.0,
) -> None:
    """List the data items and the drivesense channel each maps to."""
    model = _devices(source, timeout)
    rows = []
    for item in model.items:
        scale = item.scale()
        rows.append({"id": item.id, "name": item.name, "component": f"{item.component} {item.component_name}".strip(),
                     "category": item.category, "type": item.type, "sub_type": item.sub_type,
                     "units": item.units, "channel": item.channel if item.category == "SAMPLE" else "",
                     "si_unit": scale[1] if scale and item.category == "SAMPLE" else ""})
    for dev in model.devices:
        console.print(f"device {dev['name']} ({dev['uuid']}) {dev['manufacturer']} {dev['model']}".rstrip(),
                      markup=False, highlight=False)
    table = Table(title=f"{len(rows)} data item(s)", box=box.SIMPLE, padding=(0, 1))
    key_column(table, "id", [r["id"] for r in rows])            # the keys: never cut, whatever the width
    key_column(table, "channel", [r["channel"] for r in rows])
    table.add_column("units -> SI", overflow="fold")
    table.add_column("component: category type/sub_type", overflow="fold")
    for r in rows:
        units = f"{r['units']} -> {r['si_unit']}" if r["si_unit"] else r["units"]
        what = f"{r['component']}: {r['category']} {r['type']}" + (f"/{r['sub_type']}" if r["sub_type"] else "")
        table.add_row(*(escape(c) for c in (r["id"], r["channel"], units, what)))
    console.print(table)
    write_json(json_path, {"devices": model.devices, "data_items": rows})


@mtconnect_app.command("import")
@friendly
def import_(
    source: Annotated[str, typer.Argument(help="Streams document (.xml), SHDR log, or agent URL.")],
    out: Annotated[Path, typer.Option("--out", help="Output recording: .nc (lossless) or .csv.")],
    devices: Annotated[Optional[str], typer.Option(help="Devices document (/probe) file or agent URL, for channel "
                                                        "names and units.")] = None,
    fs: Annotated[Optional[float], typer.Option(help="Output rate [Hz] (default: the densest reporting rate).")]
    = None,
    method: Annotated[str, typer.Option(help="Resampling: linear or hold (zero-order hold).")] = "linear",
    count: Annotated[int, typer.Option(help="URL: observations per /sample request.")] = 1000,
    max_requests: Annotated[int, typer.Option(help="URL: most requests.")] = 100,
    timeout: Annotated[float, typer.Option(help="URL: HTTP timeout [s].")] = 10.0,
) -> None:
    """Resample MTConnect observations explicitly onto a uniform grid and save a recording."""
    from drivesense.cli.common import save_recording
    from drivesense.io.mtconnect_client import MTConnectClient, is_agent_url
    from drivesense.io.mtconnect_resample import read_mtconnect

    url = is_agent_url(source)
    model = _devices(devices, timeout)
    if url:
        rec = MTConnectClient(source, timeout=timeout).collect(count=count, max_requests=max_requests, fs=fs,
                                                               method=method, devices=model)
    else:
        with show_warnings():
            rec = read_mtconnect(Path(source), model, fs=fs, method=method)
    save_recording(rec, out)
    console.print(f"wrote {out}: {rec!r}", markup=False, highlight=False)
    console.print(rec.meta["provenance"][-1], markup=False, highlight=False)
    mtc = rec.meta["mtconnect"]
    if mtc.get("assets") or mtc.get("asset_removals"):
        tools = sum(a["type"] == "CuttingTool" for a in mtc.get("assets", []))
        console.print(f"assets: {len(mtc.get('assets', []))} sent ({tools} CuttingTool), "
                      f"{len(mtc.get('asset_removals', []))} removal(s), {len(mtc.get('asset_updates', []))} "
                      "update(s) (see meta mtconnect.assets)", markup=False, highlight=False)


def register(root: typer.Typer) -> None:
    """Add the ``mtconnect`` command group to the root application."""
    root.add_typer(mtconnect_app, name="mtconnect")
