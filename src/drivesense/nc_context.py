"""The NC's context as channels: the tool, the program and its block, the overrides, the execution state and
an in-cut flag.

A controller knows what the drive signals can only guess: that the feed
override was turned, that the program moved on to the next block, that the
tool changed, that the axes stand in a feed hold.  drivesense carries that
knowledge as ordinary channels of a trace or a stream (dimensionless, one
value per sample, held between the controller's reports), so that they travel
through files, column maps, MTConnect, OPC UA and MQTT like any signal:

================== =====================================================================================
channel            meaning
================== =====================================================================================
``tool_number``    the tool in the spindle (the T word) [-]
``program_number`` the running program: its number, or :func:`program_code` of its name [-]
``block_number``   the block (N word) or line of the program being executed [-]
``feed_override``  the path feed override as a ratio, 1.0 = 100 % (a ``%`` column converts) [-]
``spindle_override`` the spindle speed override as a ratio [-]
``execution``      the execution state, as :func:`execution_code` (the MTConnect ``Execution`` values) [-]
``in_cut``         1 where the controller or the CAM program says the tool is in the material, else 0 [-]
================== =====================================================================================

Controllers name the same things differently (Sinumerik ``actToolIdent``,
``actBlockNo``; Fanuc ``tool number``, ``sequence number``; MTConnect
``ToolNumber``, ``Line``/``BlockNumber``, ``PathFeedrateOverride``,
``RotaryVelocityOverride``, ``Execution``, ``Program``); a column map or a
source's channel map names them once.
"""

from __future__ import annotations

import math
import zlib

from drivesense.errors import InvalidSignalError

__all__ = ["CONTEXT_CHANNELS", "CHANGE_CHANNELS", "COUNT_CHANNELS", "NAMED_CHANNELS", "EXECUTION_STATES", "ACTIVE", "execution_code", "program_code",
           "context_value", "has_context", "context_at"]

#: The context channels, in a fixed order.
CONTEXT_CHANNELS = ("tool_number", "program_number", "block_number", "feed_override", "spindle_override",
                    "execution", "in_cut")

#: Context channels whose every change is a commanded change of the process (the detectors hold off after it).
CHANGE_CHANNELS = ("tool_number", "program_number", "block_number", "feed_override", "spindle_override")

#: Context channels whose values are counts or codes: a file column of them needs no unit (the overrides do:
#: a ratio or a percentage).
COUNT_CHANNELS = ("tool_number", "program_number", "block_number", "execution", "in_cut")

#: Context channels whose values may come as names (a state, a program), coded by :func:`context_value`.
NAMED_CHANNELS = ("execution", "program_number")

#: MTConnect's ``Execution`` values; a state's code is its index.
EXECUTION_STATES = ("READY", "ACTIVE", "INTERRUPTED", "FEED_HOLD", "STOPPED", "OPTIONAL_STOP", "PROGRAM_STOPPED",
                    "PROGRAM_COMPLETED", "WAIT", "PROGRAM_OPTIONAL_STOP")

#: Code of the one state in which the program runs (and the detectors judge).
ACTIVE = float(EXECUTION_STATES.index("ACTIVE"))

#: Largest program code from a name: names hash into [2^20, 2^24), exact in float32 and above usual numbers.
_CODE_BASE = 1 << 20
_CODE_SPAN = (1 << 24) - _CODE_BASE


def execution_code(state) -> float:
    """The code of an execution state: an MTConnect ``Execution`` value (any case) or its code.

    Parameters
    ----------
    state : str or int or float
        ``"ACTIVE"``, ``"feed_hold"``... or the code itself [-].

    Returns
    -------
    float

    Raises
    ------
    InvalidSignalError
        For a name or code that is not a known state.

    Examples
    --------
    >>> execution_code("ACTIVE"), execution_code("feed_hold")
    (1.0, 3.0)
    """
    if isinstance(state, str):
        name = state.strip().upper().replace(" ", "_")
        if name in EXECUTION_STATES:
            return float(EXECUTION_STATES.index(name))
        try:
            state = float(name)
        except ValueError:
            raise InvalidSignalError(f"channel 'execution': unknown state {state!r} (known: "
                                     f"{', '.join(EXECUTION_STATES)})") from None
    code = float(state)
    if not (code.is_integer() and 0 <= code < len(EXECUTION_STATES)):
        raise InvalidSignalError(f"channel 'execution': code {state!r} is not one of 0..{len(EXECUTION_STATES) - 1} "
                                 f"({', '.join(f'{k}={s}' for k, s in enumerate(EXECUTION_STATES))})")
    return code


def program_code(program) -> float:
    """A program as a number: a number stays itself, a name becomes a stable code (the same on every host).

    Names map by CRC-32 into [2^20, 2^24): exact in single precision, so a
    change of program is a change of the channel wherever it travels.  The
    name itself belongs in the provenance, not in the channel.

    Parameters
    ----------
    program : str or int or float
        ``"O1234"``, ``"PART_A.MPF"``, ``4711``... [-]

    Returns
    -------
    float

    Raises
    ------
    InvalidSignalError
        For an empty name or a number that is not finite.

    Examples
    --------
    >>> program_code(4711), program_code("4711"), program_code("PART_A.MPF") == program_code("PART_A.MPF")
    (4711.0, 4711.0, True)
    """
    if isinstance(program, str):
        text = program.strip()
        if not text:
            raise InvalidSignalError("channel 'program_number': an empty cell is no program (leave the column "
                                     "out, or repeat the program's name on every row)")
        try:
            value = float(text)
        except ValueError:
            return float(_CODE_BASE + zlib.crc32(text.encode("utf-8")) % _CODE_SPAN)
        program = value
    value = float(program)
    if not math.isfinite(value):
        raise InvalidSignalError(f"channel 'program_number': {program!r} is not a program")
    return value


def context_value(channel: str, value) -> float:
    """One reported context value as the channel's number (states and program names coded; overrides as given).

    Parameters
    ----------
    channel : str
        One of :data:`CONTEXT_CHANNELS`.
    value : str or number
        The value a controller reported.

    Raises
    ------
    InvalidSignalError
        For a channel outside the context, or a value it cannot take.
    """
    if channel == "execution":
        return execution_code(value)
    if channel == "program_number":
        return program_code(value)
    if channel not in CONTEXT_CHANNELS:
        raise InvalidSignalError(f"{channel!r} is not an NC context channel (known: {', '.join(CONTEXT_CHANNELS)})")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidSignalError(f"channel {channel!r}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise InvalidSignalError(f"channel {channel!r}: {value!r} is not a finite number")
    return number


def has_context(channels) -> bool:
    """Whether any of ``channels`` (names) is an NC context channel.

    Parameters
    ----------
    channels : iterable of str
        Channel names (a mapping's keys count).
    """
    return any(c in CONTEXT_CHANNELS for c in channels)


def context_at(arrays, index: int) -> dict:
    """The context channels' values at sample ``index`` of ``arrays`` (those present), for an event's evidence.

    Counts and codes come back as ints, the overrides as floats.

    Parameters
    ----------
    arrays : mapping of str to ndarray
        A chunk's channels [SI unit of each channel; the context channels dimensionless].
    index : int
        Sample within the chunk (clipped to it).
    """
    out: dict = {}
    for name in CONTEXT_CHANNELS:
        values = arrays.get(name)
        if values is None or len(values) == 0:
            continue
        value = float(values[min(max(int(index), 0), len(values) - 1)])
        out[name] = int(value) if name in COUNT_CHANNELS and value.is_integer() else value
    return out
