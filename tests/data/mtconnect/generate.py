"""Regenerate the recorded MTConnect documents of this folder (deterministic; run once).

A 3-axis machining centre feeding X at 5 mm/s for 2 s with the spindle at 1000 rpm:
``streams.xml`` is an agent's /sample answer for the whole buffer (irregular reporting
times, an UNAVAILABLE spindle-speed gap, conditions, messages, a 3-D path position and a
1 kHz accelerometer time series), ``current.xml`` its /current answer, ``adapter.shdr``
the adapter's SHDR log of the same cut (native units: kW, mm/min) and
``error_out_of_range.xml`` the agent's error document.
"""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
T0 = datetime(2024, 3, 5, 9, 0, 0, tzinfo=timezone.utc)
NS = "urn:mtconnect.org:MTConnectStreams:1.3"


def stamp(t: float) -> str:
    return (T0 + timedelta(microseconds=round(t * 1e6))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def events() -> list[tuple]:
    """(t [s], component, component id, category, element, item id, name, value, attrs)."""
    rng = np.random.default_rng(7)
    out: list[tuple] = []

    def add(t, comp, cid, cat, tag, did, name, value, **attrs):
        out.append((round(t, 6), comp, cid, cat, tag, did, name, value, attrs))

    add(0.0, "Device", "vmc", "Events", "Availability", "avail", "avail", "AVAILABLE")
    add(0.0, "Path", "path", "Events", "Execution", "exec", "execution", "ACTIVE")
    add(0.0, "Path", "path", "Events", "Program", "program", "program", "O1234")
    add(0.0, "Rotary", "c", "Events", "RotaryMode", "Smode", "Smode", "SPINDLE")
    add(0.0, "Linear", "x", "Condition", "Normal", "Xtravel", "Xtravel", "", type="POSITION")
    add(0.0, "Rotary", "c", "Condition", "Normal", "Scond", "Scond", "", type="SYSTEM")
    add(0.0, "Controller", "cont", "Condition", "Normal", "logic", "logic", "", type="LOGIC_PROGRAM")
    t = 0.0
    while t < 2.0:  # X position, current: irregular controller polling around 10 ms
        x = 100.0 + 5.0 * t + 0.002 * math.sin(2 * math.pi * 25 * t)
        add(t, "Linear", "x", "Samples", "Position", "Xact", "Xact", f"{x:.4f}", subType="ACTUAL")
        add(t, "Linear", "x", "Samples", "Amperage", "Xamp", "Xamp", f"{2.3 + 0.1 * math.sin(2 * math.pi * 3 * t):.4f}")
        t += 0.010 + rng.uniform(-0.002, 0.002)
    for k in range(0, 40):
        t = k * 0.05
        add(t, "Linear", "x", "Samples", "AxisFeedrate", "Xfrt", "Xfrt", f"{5.0 + rng.normal(0, 0.01):.4f}", subType="ACTUAL")
        add(t, "Path", "path", "Samples", "PathFeedrate", "pfr", "path_feedrate", f"{5.0 + rng.normal(0, 0.01):.4f}")
        add(t, "Path", "path", "Samples", "PathPosition", "ppos", "path_position",
            f"{100 + 5 * t:.4f} 50.0000 -5.0000")
        add(t, "Rotary", "c", "Samples", "Wattage", "Spower", "Spower", f"{1250 + 20 * math.sin(t):.2f}")
        add(t + 0.001, "Path", "path", "Events", "Line", "line", "line", str(10 + k // 8))
    for k in range(0, 100):
        t = k * 0.02
        if 1.0 <= t < 1.1:
            if abs(t - 1.0) < 1e-9:
                add(t, "Rotary", "c", "Samples", "RotaryVelocity", "Sspeed", "Sspeed", "UNAVAILABLE", subType="ACTUAL")
            continue
        add(t, "Rotary", "c", "Samples", "RotaryVelocity", "Sspeed", "Sspeed",
            f"{1000 + 2 * math.sin(2 * math.pi * t):.3f}", subType="ACTUAL")
        add(t + 0.003, "Linear", "y", "Samples", "Position", "Yact", "Yact", "50.0000", subType="ACTUAL")
    for k in range(0, 20):
        t = k * 0.1
        add(t, "Linear", "x", "Samples", "Load", "Xload", "Xload", f"{35 + k * 0.5:.1f}")
        add(t, "Rotary", "c", "Samples", "Load", "Sload", "Sload", f"{42 + k * 0.2:.1f}")
        tl = t + 0.099  # time series: timestamp = time of the last value
        tt = tl - (99 - np.arange(100)) / 1000.0
        vals = " ".join(f"{2000 * math.sin(2 * math.pi * 150 * v):.3f}" for v in tt)
        add(tl, "Sensor", "acc", "Samples", "AccelerationTimeSeries", "Zacc", "Zacc", vals, sampleCount="100", sampleRate="1000")
    for k in range(0, 4):
        add(k * 0.5, "Rotary", "c", "Samples", "Temperature", "Stemp", "Stemp", f"{31 + k:.1f}")
    add(0.3, "Controller", "cont", "Events", "Message", "msg", "msg", "Tool check", nativeCode="M01")
    add(1.5, "Rotary", "c", "Condition", "Warning", "Scond", "Scond", "Spindle temperature high",
        type="SYSTEM", nativeCode="OVT", nativeSeverity="2", qualifier="HIGH")
    add(1.999, "Path", "path", "Events", "Execution", "exec", "execution", "READY")
    out.sort(key=lambda e: e[0])
    return out


def streams_xml(obs: list[tuple], first: int, next_seq: int, instance: int = 1709629200) -> str:
    by_comp: dict = {}
    for seq, e in obs:
        by_comp.setdefault((e[1], e[2]), {}).setdefault(e[3], []).append((seq, e))
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<MTConnectStreams xmlns="{NS}" xmlns:m="{NS}">',
             f'  <Header creationTime="{stamp(2.1)}" sender="cell-7-agent" instanceId="{instance}" version="1.3.0" '
             f'bufferSize="4096" nextSequence="{next_seq}" firstSequence="{first}" lastSequence="{next_seq - 1}"/>',
             "  <Streams>", '    <DeviceStream name="VMC-3Axis" uuid="vmc-3axis-0042">']
    for (comp, cid), cats in by_comp.items():
        name = {"x": "X", "y": "Y", "c": "C", "path": "path", "cont": "controller", "vmc": "VMC-3Axis",
                "acc": "spindle_accelerometer"}[cid]
        lines.append(f'      <ComponentStream component="{comp}" name="{name}" componentId="{cid}">')
        for cat, items in cats.items():
            lines.append(f"        <{cat}>")
            for seq, (t, _, _, _, tag, did, dname, value, attrs) in items:
                extra = "".join(f' {k}="{v}"' for k, v in attrs.items())
                body = f">{value}</{tag}>" if value else "/>"
                lines.append(f'          <{tag} dataItemId="{did}" timestamp="{stamp(t)}" name="{dname}" '
                             f'sequence="{seq}"{extra}{body}')
            lines.append(f"        </{cat}>")
        lines.append("      </ComponentStream>")
    lines += ["    </DeviceStream>", "  </Streams>", "</MTConnectStreams>", ""]
    return "\n".join(lines)


def shdr(obs: list[tuple]) -> str:
    lines = ["* shdrVersion: 2", "* adapterVersion: 1.4"]
    pending: list[str] = []
    last_t = None
    native = {"Xfrt": 60.0, "Spower": 1e-3}  # the adapter sends mm/min and kW
    for t, _, _, cat, tag, did, name, value, attrs in obs:
        key = name
        if cat == "Condition":
            lines.append(f"{stamp(t)}|{key}|{tag.upper()}|{attrs.get('nativeCode', '')}|"
                         f"{attrs.get('nativeSeverity', '')}|{attrs.get('qualifier', '')}|{value}")
            continue
        if tag == "Message":
            lines.append(f"{stamp(t)}|{key}|{attrs['nativeCode']}|{value}")
            continue
        if tag.endswith("TimeSeries"):
            lines.append(f"{stamp(t)}|{key}|{attrs['sampleCount']}|{attrs['sampleRate']}|{value}")
            continue
        if key in native and value != "UNAVAILABLE":
            value = f"{float(value) * native[key]:.6g}"
        if t != last_t and pending:
            lines.append(f"{stamp(last_t)}|" + "|".join(pending))
            pending = []
        pending += [key, value]
        last_t = t
    if pending:
        lines.append(f"{stamp(last_t)}|" + "|".join(pending))
    return "\n".join(lines) + "\n"


def main() -> None:
    obs = list(enumerate(events(), start=1))
    n = len(obs)
    (HERE / "streams.xml").write_text(streams_xml(obs, 1, n + 1), encoding="utf-8")
    latest: dict = {}
    for seq, e in obs:
        latest[e[5]] = (seq, e)
    cur = sorted(latest.values(), key=lambda p: p[0])
    (HERE / "current.xml").write_text(streams_xml(cur, 1, n + 1), encoding="utf-8")
    (HERE / "adapter.shdr").write_text(shdr(events()), encoding="utf-8")
    (HERE / "error_out_of_range.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<MTConnectError xmlns="urn:mtconnect.org:MTConnectError:1.3">\n'
        f'  <Header creationTime="{stamp(2.1)}" sender="cell-7-agent" instanceId="1709629200" version="1.3.0" '
        'bufferSize="4096"/>\n'
        '  <Errors>\n'
        "    <Error errorCode=\"OUT_OF_RANGE\">'from' must be greater than or equal to the first sequence "
        "in the buffer</Error>\n"
        '  </Errors>\n</MTConnectError>\n', encoding="utf-8")


if __name__ == "__main__":
    main()
