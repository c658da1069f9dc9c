"""Malicious and broken XML: nothing is expanded, fetched or read, and every refusal names the problem.

A small HTTP server on 127.0.0.1 counts requests, so the network cases prove that
no request was ever made (not merely that the parse failed).
"""

from __future__ import annotations

import base64
import http.server
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drivesense.errors import ConfigError, InvalidSignalError
from drivesense.io.mtconnect import parse_devices, parse_streams
from drivesense.io.xml_format import read_experiment, transform_xml, write_xml
from drivesense.io.xml_safe import XMLLimits, parse_bytes
from drivesense.recording import Recording

NS = "urn:drivesense:experiment:1"


@pytest.fixture
def server():
    """A request-counting HTTP server on 127.0.0.1 that stops by itself after 30 s at the latest."""
    hits: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802
            hits.append(self.path)
            body = b'<!ENTITY x "PWNED">' if self.path.endswith(".dtd") else b"PWNED"
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    srv = http.server.HTTPServer(("127.0.0.1", 0), Handler)
    srv.timeout = 0.1
    stop = threading.Event()
    deadline = time.monotonic() + 30

    def loop():
        while not stop.is_set() and time.monotonic() < deadline:
            srv.handle_request()

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}", hits
    stop.set()
    thread.join(2)
    srv.server_close()


@pytest.fixture
def secret(tmp_path) -> Path:
    path = tmp_path / "secret.txt"
    path.write_text("TOP-SECRET-CONTENT")
    return path


def _valid(tmp_path: Path, n: int = 40, **kw) -> Path:
    rec = Recording.from_arrays({"x_current": np.linspace(0, 1, n), "force_x": np.linspace(5, -5, n)}, fs=1000.0,
                                meta={"name": "m"})
    path = tmp_path / "ok.xml"
    write_xml(rec, path, **kw)
    return path


def _all_readers(tmp_path: Path, doc: bytes) -> list[Exception]:
    """Feed `doc` to every parser that reads outside input; return the errors (all must fail)."""
    path = tmp_path / "evil.xml"
    path.write_bytes(doc)
    errors = []
    for reader in (lambda: read_experiment(path), lambda: transform_xml(path), lambda: parse_devices(path),
                   lambda: parse_streams(doc), lambda: parse_bytes(doc, where="evil")):
        with pytest.raises(InvalidSignalError) as err:
            reader()
        errors.append(err.value)
    return errors


ROOT = f'<experimentResults xmlns="{NS}" formatVersion="1.0">'


def test_xxe_local_file_is_never_read(tmp_path, secret):
    doc = (f'<?xml version="1.0"?>\n<!DOCTYPE experimentResults [\n  <!ENTITY xxe SYSTEM "{secret.as_uri()}">\n]>\n'
           f'{ROOT}<personnel><experimenter name="&xxe;"/></personnel></experimentResults>').encode()
    for err in _all_readers(tmp_path, doc):
        assert "DOCTYPE" in str(err) and "line 2" in str(err)
        assert "TOP-SECRET" not in str(err)


def test_xxe_network_entity_and_external_dtd_make_no_request(tmp_path, server):
    url, hits = server
    docs = [
        f'<!DOCTYPE r [<!ENTITY xxe SYSTEM "{url}/entity">]>{ROOT}&xxe;</experimentResults>',
        f'<!DOCTYPE experimentResults SYSTEM "{url}/evil.dtd">{ROOT}&x;</experimentResults>',
        f'<!DOCTYPE r [<!ENTITY % p SYSTEM "{url}/param.dtd"> %p;]>{ROOT}</experimentResults>',
        f'<!DOCTYPE r PUBLIC "-//EVIL//DTD//EN" "{url}/public.dtd">{ROOT}</experimentResults>',
    ]
    for doc in docs:
        for err in _all_readers(tmp_path, doc.encode()):
            assert "DOCTYPE" in str(err)
    time.sleep(0.3)
    assert hits == []


def test_xinclude_and_schema_location_are_not_followed(tmp_path, server, secret):
    url, hits = server
    ok = _valid(tmp_path).read_text()
    evil = ok.replace(f'xmlns="{NS}"', f'xmlns="{NS}" xmlns:xi="http://www.w3.org/2001/XInclude" '
                      f'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
                      f'xsi:schemaLocation="{NS} {url}/schema.xsd"', 1)
    evil = evil.replace("<configuration>", f'<configuration><xi:include href="{secret.as_uri()}" parse="text"/>'
                        f'<xi:include href="{url}/inc.xml"/>', 1)
    path = tmp_path / "xi.xml"
    path.write_text(evil)
    exp = read_experiment(path)
    assert not any("TOP-SECRET" in t or "PWNED" in t for t in exp.texts)
    assert "TOP-SECRET" not in transform_xml(path)
    time.sleep(0.3)
    assert hits == []


def test_billion_laughs_is_refused_without_expansion(tmp_path):
    ents = ['<!ENTITY lol0 "lol">'] + [f'<!ENTITY lol{i} "{("&lol" + str(i - 1) + ";") * 10}">' for i in range(1, 10)]
    doc = f'<?xml version="1.0"?><!DOCTYPE lolz [{"".join(ents)}]>{ROOT}&lol9;</experimentResults>'.encode()
    t = time.perf_counter()
    for err in _all_readers(tmp_path, doc):
        assert "DOCTYPE" in str(err)
    assert time.perf_counter() - t < 20  # (an expansion would be 10**9 strings: it never finishes)


def test_quadratic_blowup_is_refused(tmp_path):
    big = "A" * 100_000
    doc = (f'<!DOCTYPE r [<!ENTITY a "{big}">]>{ROOT}<personnel><experimenter name="x"/></personnel>'
           f'<configuration>{"&a;" * 20_000}</configuration></experimentResults>').encode()
    for err in _all_readers(tmp_path, doc):
        assert "DOCTYPE" in str(err)


def test_doctype_hidden_behind_bom_comments_or_utf16_is_found(tmp_path):
    for doc in [b"\xef\xbb\xbf<!-- hello -->\n<?pi x?>\n<!DOCTYPE r SYSTEM 'x.dtd'><r/>",
                '<?xml version="1.0" encoding="UTF-16"?><!DOCTYPE r [<!ENTITY a "b">]><r>&a;</r>'.encode("utf-16"),
                b"<!--" + b"x" * 70_000 + b"--><!DOCTYPE r SYSTEM 'x.dtd'><r/>"]:
        errs = _all_readers(tmp_path, doc)
        assert all("DOCTYPE" in str(e) or "prolog too long" in str(e) for e in errs)


def test_undeclared_entity_is_a_syntax_error(tmp_path):
    for err in _all_readers(tmp_path, f"{ROOT}&nbsp;</experimentResults>".encode()):
        assert re.search(r"line 1, column \d+: XML syntax error: Entity 'nbsp' not defined", str(err))


@pytest.mark.parametrize("depth, message", [(200, "nested deeper than 64"), (20_000, "line 1")])
def test_deep_nesting_is_refused(tmp_path, depth, message):
    doc = f'{ROOT}<personnel><experimenter name="a"/></personnel><configuration>' + "<a>" * depth + \
        "</a>" * depth + "</configuration></experimentResults>"
    for err in _all_readers(tmp_path, doc.encode()):
        assert message in str(err)


def test_depth_limit_is_configurable(tmp_path):
    path = _valid(tmp_path)
    with pytest.raises(InvalidSignalError, match="nested deeper than 3 levels"):
        read_experiment(path, limits=XMLLimits(max_depth=3))


def test_truncated_files_are_refused_with_line(tmp_path):
    path = _valid(tmp_path, n=300_000)
    data = path.read_bytes()
    for cut in (len(data) // 2, len(data) - 30, 200):
        bad = tmp_path / f"cut{cut}.xml"
        bad.write_bytes(data[:cut])
        with pytest.raises(InvalidSignalError, match=r"line \d+.*truncated or damaged file\?"):
            read_experiment(bad)


def _b64_edit(tmp_path: Path, fn) -> Path:
    path = _valid(tmp_path)
    text = path.read_text()
    m = re.search(r'(<dataGroup count="(\d+)">)([^<]*)<', text)
    path.write_text(text[:m.start(3)] + fn(m.group(3)) + text[m.end(3):])
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda s: s[:10] + "!" + s[11:], r"line 6, dataGroup of channel 'x_current': bad base64: character '!' at 10"),
    (lambda s: s[:10] + "é" + s[11:], r"bad base64: non-ASCII character at 10"),
    (lambda s: s[:-4] + "A===", r"bad base64: wrong padding"),
    (lambda s: s[:-1], r"bad base64: wrong padding or a truncated group"),
    (lambda s: "AAAA" + s, r"wrong length: the base64 data decode to more than the 320 bytes that count needs"),
    (lambda s: s + "AAAA", r"bad base64: wrong padding"),  # data after the padding
    (lambda s: s[:-8], r"wrong length: the base64 data decode to 315 bytes, not the 320"),
    (lambda s: s[:20] + "\n  \t" + s[20:], None),  # whitespace inside base64 is allowed
])
def test_bad_base64_and_wrong_lengths_name_the_channel(tmp_path, edit, message):
    path = _b64_edit(tmp_path, edit)
    if message is None:
        assert read_experiment(path).recordings[0].n_samples == 40
        return
    with pytest.raises(InvalidSignalError, match=message):
        read_experiment(path)


@pytest.mark.parametrize("old, new, message", [
    ('samples="40"', 'samples="41"', r"channel 'x_current': wrong length: the dataGroups hold 40 samples, samples=41"),
    ('count="40"', 'count="39"', r"wrong length"),
    ('samples="40"', 'samples="1000000000000"', r"samples=1000000000000 is more than the file can hold"),
    ('samples="40"', 'samples="-4"', r"samples='-4' is not a non-negative integer"),
    ('count="40"', 'count="x"', r"count='x' is not a non-negative integer"),
])
def test_declared_lengths_are_checked_before_allocating(tmp_path, old, new, message):
    path = _valid(tmp_path)
    path.write_text(path.read_text().replace(old, new, 1))
    with pytest.raises(InvalidSignalError, match=message):
        read_experiment(path)


def test_text_data_with_wrong_count_or_words(tmp_path):
    path = _valid(tmp_path, encoding="text")
    text = path.read_text()
    path.write_text(text.replace('encoding="text">0.0 ', 'encoding="text">0.0 0.5 ', 1))
    with pytest.raises(InvalidSignalError, match=r"wrong length: 41 values, count=40"):
        read_experiment(path)
    path.write_text(text.replace('encoding="text">0.0 ', 'encoding="text">zero ', 1))
    with pytest.raises(InvalidSignalError, match=r"value 0 \('zero'\) is not a number"):
        read_experiment(path)


def test_size_limits(tmp_path):
    path = _valid(tmp_path)
    with pytest.raises(InvalidSignalError, match=r"over the limit of 1000"):
        read_experiment(path, limits=XMLLimits(max_bytes=1000))
    with pytest.raises(InvalidSignalError, match=r"samples=40 is more than the file can hold"):
        read_experiment(path, limits=XMLLimits(max_samples=10))
    with pytest.raises(ConfigError, match="max_depth"):
        XMLLimits(max_depth=0)
    huge = ROOT + "<personnel><experimenter name='a'/></personnel><configuration>" + "x" * 11_000_000 + \
        "</configuration></experimentResults>"
    with pytest.raises(InvalidSignalError, match="XML syntax error"):
        parse_bytes(huge.encode(), where="huge")


def test_dataGroup_with_markup_inside_is_refused(tmp_path):
    path = _b64_edit(tmp_path, lambda s: s[:8] + "<b>x</b>" + s[8:])
    with pytest.raises(InvalidSignalError, match="a dataGroup holds only data, found <b>"):
        read_experiment(path)


def test_xslt_sheet_with_doctype_is_refused(tmp_path):
    path = _valid(tmp_path)
    sheet = tmp_path / "s.xsl"
    sheet.write_text('<!DOCTYPE x [<!ENTITY a SYSTEM "file:///etc/passwd">]><xsl:stylesheet version="1.0" '
                     'xmlns:xsl="http://www.w3.org/1999/XSL/Transform"><xsl:template match="/">&a;'
                     '</xsl:template></xsl:stylesheet>')
    with pytest.raises(InvalidSignalError, match="DOCTYPE"):
        transform_xml(path, sheet)


def test_mtconnect_error_and_agent_documents_go_through_the_same_guard():
    doc = b'<!DOCTYPE MTConnectStreams [<!ENTITY a "b">]><MTConnectStreams>&a;</MTConnectStreams>'
    with pytest.raises(InvalidSignalError, match="DOCTYPE"):
        parse_streams(doc)
    assert base64  # (imported for symmetry with the format tests)
