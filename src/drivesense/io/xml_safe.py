"""Hardened XML parsing: no DTD, no entity expansion, no network, bounded size and depth.

Every XML document drivesense reads (its own experiment files, MTConnect agent
responses, XSLT sheets) goes through this module.  The rules, in order:

1. **Size**: a file or response larger than :attr:`XMLLimits.max_bytes` is
   refused before it is parsed.
2. **No DTD at all**: the prolog (everything before the root element) is
   scanned first; a ``<!DOCTYPE`` (internal subset, external DTD, entity
   declarations) is refused before libxml2 sees it.  This closes XXE (file and
   network), billion laughs, quadratic blow-up and external-DTD attacks in one
   place.  The parser is *also* configured never to resolve entities, load a
   DTD or touch the network, and the document's ``docinfo`` is checked again
   after parsing (defence in depth).
3. **Depth**: elements nested deeper than :attr:`XMLLimits.max_depth` are
   refused (libxml2 itself stops at 256 without ``huge_tree``).
4. **Text size**: ``huge_tree`` stays off, so a single text node is limited to
   libxml2's 10 MB; drivesense writes its data in smaller groups.

Errors are :class:`drivesense.errors.InvalidSignalError` (a ``ValueError``)
naming the document and line.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from ..errors import ConfigError, InvalidSignalError

__all__ = ["XMLLimits", "DEFAULT_LIMITS", "check_prolog", "parser_options", "safe_iterparse",
           "parse_bytes", "parse_file", "describe_syntax_error", "local_name"]


def local_name(tag: Any) -> str:
    """An element's tag without its ``{namespace}`` (``""`` for comments and processing instructions).

    Parameters
    ----------
    tag : str or object
        ``element.tag`` as lxml gives it.
    """
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""

_PROLOG_SCAN = 1 << 16  # bytes of prolog scanned for a DOCTYPE


@dataclass(frozen=True)
class XMLLimits:
    """Size limits applied while parsing.

    Parameters
    ----------
    max_bytes : int, optional
        Largest document accepted [bytes] (default 64 GiB for files; the
        MTConnect client uses a smaller limit for responses).
    max_depth : int, optional
        Deepest element nesting accepted (default 64; the experiment format
        needs 6 plus the depth of the free configuration content).
    max_samples : int, optional
        Largest number of samples one channel may declare (default 2**34);
        the declared count is also checked against the file size before any
        memory is allocated.
    """

    max_bytes: int = 64 * 2**30
    max_depth: int = 64
    max_samples: int = 2**34

    def __post_init__(self) -> None:
        for field in ("max_bytes", "max_depth", "max_samples"):
            value = getattr(self, field)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"XMLLimits.{field} must be a positive integer, got {value!r}")


#: The limits used when none are given.
DEFAULT_LIMITS = XMLLimits()


def parser_options() -> dict[str, Any]:
    """Keyword arguments that make an lxml parser safe (used by every parser here).

    Returns
    -------
    dict
        ``resolve_entities=False, no_network=True, load_dtd=False,
        dtd_validation=False, huge_tree=False, remove_comments=True,
        remove_pis=True``.
    """
    return dict(resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False,
                huge_tree=False, remove_comments=True, remove_pis=True)


def _decode_head(head: bytes) -> str:
    if head.startswith(b"\xef\xbb\xbf"):
        return head[3:].decode("utf-8", "replace")
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) or (len(head) > 1 and b"\x00" in head[:4]):
        codec = "utf-16" if head.startswith((b"\xff\xfe", b"\xfe\xff")) else (
            "utf-16-le" if head[1:2] == b"\x00" else "utf-16-be")
        return head[: len(head) // 2 * 2].decode(codec, "replace")
    return head.decode("utf-8", "replace")


def check_prolog(head: bytes, where: str = "document") -> None:
    """Refuse a document whose prolog holds a DOCTYPE or other markup declaration.

    Parameters
    ----------
    head : bytes
        The first bytes of the document (at least up to the root element;
        64 KiB are enough for any sane prolog).
    where : str, optional
        Name of the document, for messages.

    Raises
    ------
    InvalidSignalError
        ``<!DOCTYPE`` / ``<!ENTITY`` before the root element (naming the
        line), no root element within the scanned bytes, or an empty document.
    """
    text = _decode_head(head[:_PROLOG_SCAN])
    if not text.strip():
        raise InvalidSignalError(f"{where}: empty document")
    pos, n = 0, len(text)
    while True:
        while pos < n and text[pos] in " \t\r\n\ufeff":
            pos += 1
        if pos >= n:
            raise InvalidSignalError(f"{where}: no root element in the first {_PROLOG_SCAN} bytes "
                                     "(prolog too long, or a truncated file)")
        line = text.count("\n", 0, pos) + 1
        if text.startswith("<!--", pos):
            end = text.find("-->", pos + 4)
            pos = n if end < 0 else end + 3
        elif text.startswith("<?", pos):
            end = text.find("?>", pos + 2)
            pos = n if end < 0 else end + 2
        elif text.startswith("<!", pos):
            word = re.match(r"<!\s*([A-Za-z]*)", text[pos:pos + 20])
            kind = (word.group(1) if word else "").upper() or "markup declaration"
            raise InvalidSignalError(
                f"{where}, line {line}: <!{kind} ...> is not allowed: drivesense never reads DTDs "
                "or entity declarations (XXE / entity-expansion protection)")
        elif text.startswith("<", pos):
            return
        else:
            raise InvalidSignalError(f"{where}, line {line}: text before the root element "
                                     f"({text[pos:pos + 20]!r}); not an XML document")


def describe_syntax_error(exc: Exception, where: str, total_lines: int | None = None,
                          log: Any = None) -> str:
    """One-line message for an lxml syntax error: document, line, column, reason.

    Parameters
    ----------
    exc : lxml.etree.XMLSyntaxError
        The error raised by lxml.
    where : str
        Name of the document.
    total_lines : int, optional
        Lines in the document; an error on the last line is flagged as a
        probable truncation.
    log : lxml error log, optional
        The parser's own log (iterparse reports its first error there).

    Returns
    -------
    str
    """
    msg = getattr(exc, "msg", None) or str(exc)
    line = getattr(exc, "lineno", None) or 0
    col = exc.position[1] if getattr(exc, "position", None) else 0
    log = [e for e in (log if log is not None else []) if e.level_name in ("FATAL", "ERROR")]
    if log and (not line or msg == "no element found"):  # iterparse hides the real error in its log
        msg, line, col = log[0].message, log[0].line, log[0].column
    msg = re.sub(r"\s*\((<string>|[^()]*), line \d+\)\s*$", "", msg).strip()
    msg = re.sub(r",\s*line \d+(,\s*column \d+)?\s*$", "", msg).strip()
    hint = ""
    if re.search(r"Premature end|EndTag|end of data|Extra content|not properly terminated", msg) or (
            total_lines is not None and line >= total_lines):
        hint = " (truncated or damaged file?)"
    at = f", line {line}" + (f", column {col}" if col else "") if line else ""
    return f"{where}{at}: XML syntax error: {msg}{hint}"


def _count_lines(path: str) -> int:
    n = 1
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            n += block.count(b"\n")
    return n


def _check_docinfo(tree: Any, where: str) -> None:
    docinfo = tree.docinfo
    if docinfo.doctype or docinfo.internalDTD is not None or docinfo.externalDTD is not None:
        raise InvalidSignalError(f"{where}: a DOCTYPE is not allowed (XXE / entity-expansion protection)")


def safe_iterparse(source: str | Path | IO[bytes], *, where: str,
                   limits: XMLLimits = DEFAULT_LIMITS, events: tuple[str, ...] = ("start", "end"),
                   ) -> Iterator[tuple[str, Any]]:
    """Stream ``(event, element)`` pairs from a document, safely.

    Parameters
    ----------
    source : str, Path or binary file object
        The document; a file object must be seekable (its prolog is checked
        first, then it is rewound).
    where : str
        Name of the document, for messages.
    limits : XMLLimits, optional
        Size limits.
    events : tuple of str, optional
        lxml iterparse events (``"start"`` and ``"end"`` by default; depth is
        only checked when ``"start"`` is among them).

    Yields
    ------
    tuple of (str, lxml.etree._Element)

    Raises
    ------
    InvalidSignalError
        A DOCTYPE, a document over the size or depth limit, or a syntax error
        (naming the line).
    """
    from lxml import etree

    if isinstance(source, (str, Path)):
        size = Path(source).stat().st_size
        if size > limits.max_bytes:
            raise InvalidSignalError(f"{where}: {size} bytes, over the limit of {limits.max_bytes}")
        with open(source, "rb") as fh:
            check_prolog(fh.read(_PROLOG_SCAN), where)
        source = str(source)
    else:
        pos = source.tell()
        check_prolog(source.read(_PROLOG_SCAN), where)
        source.seek(pos)
    depth, first = 0, True
    it = etree.iterparse(source, events=events, **parser_options())
    try:
        for event, elem in it:
            if first:
                _check_docinfo(elem.getroottree(), where)
                first = False
            if event == "start":
                depth += 1
                if depth > limits.max_depth:
                    raise InvalidSignalError(f"{where}, line {elem.sourceline}: elements nested deeper "
                                             f"than {limits.max_depth} levels")
            elif event == "end":
                depth -= 1
            yield event, elem
    except etree.XMLSyntaxError as exc:
        lines = _count_lines(source) if isinstance(source, str) else None
        raise InvalidSignalError(describe_syntax_error(exc, where, lines, it.error_log)) from None


def _check_depth(root: Any, limits: XMLLimits, where: str) -> None:
    stack = [(root, 1)]
    while stack:
        elem, d = stack.pop()
        if d > limits.max_depth:
            raise InvalidSignalError(f"{where}, line {elem.sourceline}: elements nested deeper than "
                                     f"{limits.max_depth} levels")
        stack.extend((child, d + 1) for child in elem)


def parse_bytes(data: bytes, *, where: str, limits: XMLLimits = DEFAULT_LIMITS) -> Any:
    """Parse a whole (small) document from bytes into an element tree, safely.

    Parameters
    ----------
    data : bytes
        The document.
    where : str
        Name of the document (file or URL), for messages.
    limits : XMLLimits, optional
        Size limits.

    Returns
    -------
    lxml.etree._ElementTree

    Raises
    ------
    InvalidSignalError
        As :func:`safe_iterparse`.
    """
    from lxml import etree

    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ConfigError(f"{where}: parse_bytes needs bytes, got {type(data).__name__}")
    if len(data) > limits.max_bytes:
        raise InvalidSignalError(f"{where}: {len(data)} bytes, over the limit of {limits.max_bytes}")
    check_prolog(bytes(data[:_PROLOG_SCAN]), where)
    parser = etree.XMLParser(**parser_options())
    try:
        root = etree.fromstring(bytes(data), parser)
    except etree.XMLSyntaxError as exc:
        raise InvalidSignalError(describe_syntax_error(exc, where, bytes(data).count(b"\n") + 1)) from None
    tree = root.getroottree()
    _check_docinfo(tree, where)
    _check_depth(root, limits, where)
    return tree


def parse_file(path: str | Path, *, limits: XMLLimits = DEFAULT_LIMITS) -> Any:
    """Parse a whole (small) XML file into an element tree, safely.

    Parameters
    ----------
    path : str or Path
        The file.
    limits : XMLLimits, optional
        Size limits.

    Returns
    -------
    lxml.etree._ElementTree

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    InvalidSignalError
        As :func:`safe_iterparse`.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, "XML file not found", str(path))
    size = path.stat().st_size
    if size > limits.max_bytes:
        raise InvalidSignalError(f"{path.name}: {size} bytes, over the limit of {limits.max_bytes}")
    return parse_bytes(path.read_bytes(), where=path.name, limits=limits)
