"""MTConnect assets in SHDR logs: cutting tools, their removal and updates.

Adapters send assets between their data lines::

    2022-08-08T13:43:36.0810790Z|@ASSET@|123456.2201|CuttingTool|--multiline--ABCD
    <CuttingTool toolId="123456" serialNumber="2201" assetId="123456.2201">...</CuttingTool>
    --multiline--ABCD
    2022-08-08T13:51:41.4582058Z|@REMOVE_ASSET@|123456.8003
    2022-08-08T13:51:34.7237196Z|@REMOVE_ALL_ASSETS@|CuttingTool

(the XML may also follow ``@ASSET@|id|type|`` on the same line), and
``@UPDATE_ASSET@|id|element|value...`` changes elements of an asset.  Asset
timestamps need not be in order: an adapter resends its tool table with the
times the tools were last changed.

:func:`read_asset_command` reads one such command (and the lines of its
multi-line block); :func:`parse_cutting_tool` takes what wear and breakage
questions need from a ``CuttingTool`` document (tool id, serial number,
status, tool number and the ``CuttingToolLifeCycle/ToolLife`` counts), through
the hardened XML parser.
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import InvalidSignalError
from .xml_safe import XMLLimits, local_name, parse_bytes

__all__ = ["ASSET_COMMANDS", "ASSET_KINDS", "read_asset_command", "parse_cutting_tool"]

#: SHDR commands this module reads.
ASSET_COMMANDS = ("@ASSET@", "@REMOVE_ASSET@", "@REMOVE_ALL_ASSETS@", "@UPDATE_ASSET@")
#: Observation kinds the commands become.
ASSET_KINDS = ("ASSET", "ASSET_REMOVED", "ASSET_UPDATED")
_MULTILINE = "--multiline--"
_LIMITS = XMLLimits(max_bytes=16 * 2**20)


def _number(text: str | None) -> float | None:
    try:
        value = float((text or "").strip())
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _child(el: Any, name: str) -> Any:
    return next((c for c in el if local_name(c.tag) == name), None)


def _text(el: Any) -> str | None:
    return (el.text or "").strip() if el is not None else None


def parse_cutting_tool(xml: str, where: str = "CuttingTool") -> dict:
    """The identity and life counts of a ``CuttingTool`` asset document.

    Parameters
    ----------
    xml : str
        The asset's XML (``<CuttingTool ...>``, with or without the MTConnect
        assets namespace).
    where : str, optional
        Where the document is (file and line), for messages.

    Returns
    -------
    dict
        ``tool_id``, ``serial_number``, ``asset_id`` (None when absent),
        ``status`` (the ``CutterStatus/Status`` values), ``program_tool_number``,
        ``program_tool_group`` and ``tool_life``: one dict per
        ``CuttingToolLifeCycle/ToolLife`` with ``type`` (``MINUTES``,
        ``PART_COUNT``, ``WEAR``), ``count_direction`` (``UP``/``DOWN``),
        ``value``, ``limit``, ``initial`` and ``warning`` (numbers in the
        life type's units, None when absent).

    Raises
    ------
    InvalidSignalError
        Broken or unsafe XML, or a root other than ``CuttingTool``.
    """
    root = parse_bytes(xml.encode("utf-8"), where=where, limits=_LIMITS).getroot()
    if local_name(root.tag) != "CuttingTool":
        raise InvalidSignalError(f"{where}: root <{local_name(root.tag)}> is not CuttingTool")
    life = _child(root, "CuttingToolLifeCycle")
    out: dict[str, Any] = {"tool_id": root.get("toolId"), "serial_number": root.get("serialNumber"),
                           "asset_id": root.get("assetId"), "status": [], "program_tool_number": None,
                           "program_tool_group": None, "tool_life": []}
    if life is None:
        return out
    status = _child(life, "CutterStatus")
    out["status"] = [_text(s) for s in (status if status is not None else ()) if local_name(s.tag) == "Status"]
    out["program_tool_number"] = _text(_child(life, "ProgramToolNumber"))
    out["program_tool_group"] = _text(_child(life, "ProgramToolGroup"))
    for el in life:
        if local_name(el.tag) == "ToolLife":
            out["tool_life"].append({"type": el.get("type"), "count_direction": el.get("countDirection"),
                                     "value": _number(el.text), "limit": _number(el.get("limit")),
                                     "initial": _number(el.get("initial")), "warning": _number(el.get("warning"))})
    return out


def _asset_body(rest: list[str], lines: list[str], index: int, at: str) -> tuple[str, int]:
    """The asset's XML (on the line or in a multi-line block) and the index of the next line."""
    body = "|".join(rest[3:])
    if not body.strip().startswith(_MULTILINE):
        return body, index
    tag = body.strip()
    for j in range(index, len(lines)):
        if lines[j].strip() == tag:
            return "\n".join(lines[index:j]), j + 1
    raise InvalidSignalError(f"{at}: asset {rest[1].strip()!r}: the multi-line block is not closed by {tag!r} "
                             "before the end of the log")


def read_asset_command(rest: list[str], lines: list[str], index: int, at: str
                       ) -> tuple[list[tuple[str, str, Any, dict]], int] | None:
    """Read one SHDR asset command.

    Parameters
    ----------
    rest : list of str
        The line's ``|``-separated fields after the timestamp (``rest[0]`` is
        the command, e.g. ``@ASSET@``).
    lines : list of str
        All lines of the log (a multi-line asset continues on the next ones).
    index : int
        Index in `lines` of the line after the command's.
    at : str
        File and line of the command, for messages.

    Returns
    -------
    (list of (kind, key, value, extra), int) or None
        The records (kind in :data:`ASSET_KINDS`, the asset id as key) and the
        index of the next line to read; None for a command this module does
        not know (nothing consumed).  An ``ASSET`` value is a dict with
        ``asset_id``, ``type`` and, for a ``CuttingTool``, the fields of
        :func:`parse_cutting_tool` (or ``error`` when its XML is broken).

    Raises
    ------
    InvalidSignalError
        A command without its asset id, or a multi-line block never closed.
    """
    cmd = rest[0].strip()
    if cmd not in ASSET_COMMANDS:
        return None
    if cmd == "@REMOVE_ALL_ASSETS@":
        kind = rest[1].strip() if len(rest) > 1 else ""
        return [("ASSET_REMOVED", "*", None, {"all": True, "type": kind or None})], index
    if len(rest) < 2 or not rest[1].strip():
        raise InvalidSignalError(f"{at}: {cmd} without an asset id")
    asset_id = rest[1].strip()
    if cmd == "@REMOVE_ASSET@":
        return [("ASSET_REMOVED", asset_id, None, {"all": False, "type": None})], index
    if cmd == "@UPDATE_ASSET@":
        pairs = rest[2:]
        changes = {pairs[k].strip(): pairs[k + 1] if k + 1 < len(pairs) else None for k in range(0, len(pairs), 2)}
        return [("ASSET_UPDATED", asset_id, changes, {})], index
    if len(rest) < 4:
        raise InvalidSignalError(f"{at}: @ASSET@ {asset_id!r} needs a type and a document (id|type|XML)")
    asset_type = rest[2].strip()
    body, index = _asset_body(rest, lines, index, at)
    value: dict[str, Any] = {"asset_id": asset_id, "type": asset_type}
    if asset_type == "CuttingTool":
        try:
            value.update(parse_cutting_tool(body, f"{at} (CuttingTool XML)"), asset_id=asset_id, type=asset_type)
        except InvalidSignalError as exc:  # keep the tool's id and time; the caller warns
            value["error"] = str(exc)
    return [("ASSET", asset_id, value, {})], index
