"""Every public callable documents every parameter in its numpydoc docstring (as python-control checks).

The walk covers every public module of drivesense (``pkgutil.walk_packages``;
private ``_x`` modules and the ``cli`` package are skipped), every name in each
module's ``__all__`` that drivesense defines, and for classes the constructor
and every public method, including those inherited from drivesense base
classes (not those of ``object``, builtins, xarray, ...).

A parameter counts as documented when its name has an entry in the
"Parameters" (or "Other Parameters") section; a class's constructor
parameters may also be documented in the class's "Attributes" section
(dataclasses) or in the docstring of the drivesense class whose ``__init__`` it
inherits, and a dataclass's field in the docstring of the drivesense dataclass
that declares it (a subclass need not repeat its base's parameter list).  ``self``/``cls``, ``_private`` parameters and ``*args``/``**kwargs``
need no entry.

The second test asks numeric parameters for a unit: an entry whose type says
``float``, ``ndarray`` or ``array_like`` must state a unit in brackets in its
description (``[m]``, ``[Hz]``, ``[-]`` for dimensionless quantities).

All failures are collected and reported in one assertion message.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import pkgutil
import re
from collections.abc import Iterator

import drivesense

SKIP_PACKAGES = ("drivesense.cli",)
#: Type words that make a parameter numeric for the unit check...
NUMERIC = re.compile(r"\b(float|ndarray|array_like)\b")
#: ... unless its elements are counts, indices or flags (``ndarray of int``, ``array_like of bool``).
NOT_A_QUANTITY = re.compile(r"\bof (int|bool|str)\b(?! to)")
#: A unit in brackets, not an index (``x[0]``) and not a link target.
UNIT = re.compile(r"(?<![\w`\]\)])\[[^\[\]\n]+\]")
SECTION_RULE = re.compile(r"^\s*-{3,}\s*$")


# ----------------------------------------------------------------------- numpydoc parsing
def parse_sections(doc: str) -> dict[str, list[str]]:
    """Split a cleaned docstring into ``{section title: lines}`` (the summary under ``""``)."""
    lines = inspect.cleandoc(doc or "").splitlines()
    sections: dict[str, list[str]] = {"": []}
    title = ""
    i = 0
    while i < len(lines):
        if (i + 1 < len(lines) and lines[i].strip() and SECTION_RULE.match(lines[i + 1])
                and len(lines[i + 1].strip()) >= len(lines[i].strip()) - 1):
            title = lines[i].strip()
            sections.setdefault(title, [])
            i += 2
            continue
        sections[title].append(lines[i])
        i += 1
    return sections


@dataclasses.dataclass
class Entry:
    """One entry of a numpydoc parameter list."""

    names: tuple[str, ...]
    type: str
    description: str


def parse_entries(section: list[str]) -> list[Entry]:
    """Entries of a "Parameters"-like section: ``name : type`` at the section's indentation."""
    body = list(section)
    indents = [len(ln) - len(ln.lstrip()) for ln in body if ln.strip()]
    if not indents:
        return []
    base = min(indents)
    entries: list[Entry] = []
    for ln in body:
        if not ln.strip():
            if entries:
                entries[-1].description += "\n"
            continue
        indent = len(ln) - len(ln.lstrip())
        if indent == base:
            head, sep, typ = ln.strip().partition(" :")
            if not sep:
                head, typ = ln.strip().rstrip(":"), ""
            names = tuple(n.strip().lstrip("*") for n in head.split(",") if n.strip())
            entries.append(Entry(names, typ.strip(), ""))
        elif entries:
            entries[-1].description += ln.strip() + " "
    return entries


def documented_entries(doc: str, sections=("Parameters", "Other Parameters")) -> dict[str, Entry]:
    parsed = parse_sections(doc)
    out: dict[str, Entry] = {}
    for title in sections:
        for entry in parse_entries(parsed.get(title, [])):
            for name in entry.names:
                out.setdefault(name, entry)
    return out


# ----------------------------------------------------------------------- the walk
def public_modules() -> Iterator[str]:
    yield "drivesense"
    for info in pkgutil.walk_packages(drivesense.__path__, "drivesense."):
        parts = info.name.split(".")
        if any(p.startswith("_") for p in parts[1:]):
            continue
        if any(info.name == s or info.name.startswith(s + ".") for s in SKIP_PACKAGES):
            continue
        yield info.name


def _own(obj) -> bool:
    return (getattr(obj, "__module__", None) or "").split(".")[0] == "drivesense"


def _constructor_docs(cls) -> list[str]:
    """Docstrings that may document the constructor: the class, its ``__init__``, and the class defining it."""
    docs = [inspect.getdoc(cls) or ""]
    for base in inspect.getmro(cls):
        if "__init__" in vars(base) or "__new__" in vars(base):
            if _own(base):
                docs.append(inspect.getdoc(base) or "")
                init = vars(base).get("__init__")
                if init is not None:
                    docs.append(inspect.getdoc(init) or "")
            break
    if dataclasses.is_dataclass(cls):             # inherited fields: documented where they are declared
        docs += [inspect.getdoc(b) or "" for b in inspect.getmro(cls)[1:] if _own(b) and dataclasses.is_dataclass(b)]
    return docs


def _methods(cls) -> Iterator[tuple[str, object, str]]:
    """``(name, callable, qualified owner)`` of public methods, own and inherited from drivesense bases."""
    seen = set()
    for base in inspect.getmro(cls):
        if not _own(base):
            continue
        for name, raw in vars(base).items():
            if name.startswith("_") or name in seen:
                continue
            seen.add(name)
            if isinstance(raw, property) or not (inspect.isfunction(raw)
                                                 or isinstance(raw, (classmethod, staticmethod))):
                continue
            yield name, getattr(cls, name), f"{base.__module__}.{base.__qualname__}.{name}"


def callables() -> tuple[list[tuple[str, object, list[str], bool]], list[str]]:
    """``(qualified name, callable, docstrings, is_method)`` for every public callable, and import failures."""
    out, failures, seen = [], [], set()
    for modname in public_modules():
        try:
            module = importlib.import_module(modname)
        except ModuleNotFoundError as exc:       # an optional third-party dependency
            if (exc.name or "").split(".")[0] == "drivesense":
                failures.append(f"{modname}: import failed: {exc}")
            continue
        except Exception as exc:                  # noqa: BLE001 - report, do not hide
            failures.append(f"{modname}: import failed: {type(exc).__name__}: {exc}")
            continue
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            if obj is None or not _own(obj):
                continue
            if inspect.isclass(obj):
                key = f"{obj.__module__}.{obj.__qualname__}"
                if key in seen:
                    continue
                seen.add(key)
                out.append((key, obj, _constructor_docs(obj), False))
                for _, meth, mkey in _methods(obj):
                    if mkey in seen:
                        continue
                    seen.add(mkey)
                    out.append((mkey, meth, [inspect.getdoc(meth) or ""], True))
            elif inspect.isfunction(obj):
                key = f"{obj.__module__}.{obj.__qualname__}"
                if key not in seen:
                    seen.add(key)
                    out.append((key, obj, [inspect.getdoc(obj) or ""], False))
    return out, failures


def public_parameters(obj) -> list[inspect.Parameter]:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return []
    return [p for p in sig.parameters.values()
            if p.name not in ("self", "cls") and not p.name.startswith("_")
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


def _entries_for(obj, docs: list[str]) -> dict[str, Entry]:
    sections = ("Parameters", "Other Parameters") + (("Attributes",) if inspect.isclass(obj) else ())
    found: dict[str, Entry] = {}
    for doc in docs:
        for k, v in documented_entries(doc, sections).items():
            found.setdefault(k, v)
    return found


@functools.cache
def walk() -> tuple[list, list[str]]:
    """The walk, once per session (imports every public module)."""
    return callables()


# ----------------------------------------------------------------------- the tests
def test_parser_reads_numpydoc_parameter_lists():
    doc = '''Summary.

    Parameters
    ----------
    fs : float
        Sample rate [Hz].
    start, end : float, optional
        Window; ``x[0]`` is not a unit.
    flag
        No type.
    **kwargs
        Passed on.

    Returns
    -------
    out : ndarray
        Not a parameter.
    '''
    entries = documented_entries(doc)
    assert set(entries) == {"fs", "start", "end", "flag", "kwargs"}
    assert entries["fs"].type == "float" and UNIT.search(entries["fs"].description)
    assert entries["end"].type == "float, optional" and not UNIT.search(entries["end"].description)
    assert NUMERIC.search(entries["start"].type) and not NUMERIC.search("int or str")
    assert NOT_A_QUANTITY.search("ndarray of int, optional") and not NOT_A_QUANTITY.search("mapping of str to ndarray")


def test_walk_finds_the_public_api():
    found, import_failures = walk()
    names = {k for k, *_ in found}
    assert not import_failures, "\n".join(import_failures)
    assert "drivesense.recording.Recording" in names and "drivesense.recording.Recording.slice_time" in names
    assert "drivesense.testing.assert_recording_allclose" in names
    assert not any(k.startswith("drivesense.cli.") for k in names)
    assert len(found) > 200


def test_every_public_parameter_is_documented():
    problems = []
    for key, obj, docs, _ in walk()[0]:
        params = public_parameters(obj)
        if not params:
            continue
        documented = _entries_for(obj, docs)
        missing = [p.name for p in params if p.name not in documented]
        if missing:
            problems.append(f"{key}: undocumented parameter(s) {', '.join(missing)}")
    assert not problems, f"{len(problems)} callable(s) with undocumented parameters:\n" + "\n".join(problems)


def _unit_problems() -> list[str]:
    problems = []
    for key, obj, docs, _ in walk()[0]:
        documented = _entries_for(obj, docs)
        for p in public_parameters(obj):
            entry = documented.get(p.name)
            if entry is None or not NUMERIC.search(entry.type) or NOT_A_QUANTITY.search(entry.type):
                continue
            if not (UNIT.search(entry.description) or UNIT.search(entry.type)):
                problems.append(f"{key}: parameter '{p.name}' ({entry.type}) states no unit in brackets")
    return problems


def test_numeric_parameters_state_a_unit():
    problems = _unit_problems()
    assert not problems, f"{len(problems)} numeric parameter(s) without a unit:\n" + "\n".join(problems)
