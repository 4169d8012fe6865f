"""The IREDES ChkSum: what it is taken over, the two ways rig software computes it, what a match proves.

The value in ``IR:GenTrailer/IR:ChkSum`` is a CRC32 (zlib / IEEE 802.3) of the whole file, written
in decimal (rig practice) or as hex digits (the schema's ``hexBinary``); both spellings are read.
Two conventions are in use for the value's own place while the CRC is taken, and both are checked:

- ``"documented"``: the IREDES schema's rule, the CRC of the file with the ChkSum text written as
  ``0``. This project's writer uses it.
- ``"empty-value"``: the CRC of the file with the ChkSum text empty (``<IR:ChkSum></IR:ChkSum>``), as
  Epiroc's office software (Surface Manager and the like) writes its files, with CRLF line ends.

Both are taken over the bytes as they are. When neither matches, the same two are taken over the
file with its line ends made all LF and all CRLF: a copy that only turned CRLF into LF (or the other
way) proves the content unchanged, since an XML parser reads the two alike (XML 1.0, end-of-line
handling), so that file is *verified*, and the result says the line ends were converted after
writing (``line_ends = "converted (CRLF -> LF)"``; ``"as written"`` when the bytes matched as they
are). Anything else is a mismatch: the content changed after the checksum was written, or the
checksum was computed some other way. The states and their policy (refuse, warn, ignore) are
:func:`verify_checksum`'s.
"""

from __future__ import annotations

import logging
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

from pipeline.core.errors import ConfigError, InputError

log = logging.getLogger("pipeline.plans.iredes")  # one logger for the IREDES reader's messages

CHECKSUM_POLICIES = ("refuse", "warn", "ignore")
# the ChkSum text while the CRC is taken, by convention name (the names the solution JSON records)
CONVENTIONS = {"documented": b"0", "empty-value": b""}
_DESCRIBED = {"documented": "the CRC32 of the file with ChkSum 0, as IREDES documents it",
              "empty-value": "the CRC32 of the file with ChkSum empty, as Epiroc's software writes it"}
AS_WRITTEN = "as written"
_CHKSUM = re.compile(rb"(<(?:[A-Za-z_][\w.-]*:)?ChkSum(?:\s[^>]*)?>)([^<]*)(</(?:[A-Za-z_][\w.-]*:)?ChkSum\s*>)")
_HIDDEN = re.compile(rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|<\?.*?\?>", re.DOTALL)  # no element can stand in these
_WIDE_BOMS = (b"\xff\xfe", b"\xfe\xff", b"\x00\x00\xfe\xff")


@dataclass(frozen=True)
class ChecksumResult:
    """``state``: verified, unverified or ignored; ``detail``: what matched or why not;
    ``convention``: the convention that matched (None unless verified); ``line_ends``: ``"as written"``
    or ``"converted (A -> B)"`` (None unless verified)."""

    state: str
    detail: str
    convention: str | None = None
    line_ends: str | None = None


def crc32_text(value: int, fmt: str = "decimal") -> str:
    """The ChkSum spelling of a CRC32: unsigned decimal, or 8 upper-case hex digits."""
    if fmt not in ("decimal", "hex"):
        raise ConfigError(f"iredes checksum format = {fmt!r}: expected 'decimal' or 'hex'")
    return str(value) if fmt == "decimal" else f"{value:08X}"


def _chksum_matches(data: bytes) -> list[re.Match]:
    """``ChkSum`` elements in the bytes, leaving out look-alikes inside comments, CDATA and
    processing instructions (a checksum there checks nothing)."""
    hidden = [m.span() for m in _HIDDEN.finditer(data)]
    return [m for m in _CHKSUM.finditer(data) if not any(a <= m.start() < b for a, b in hidden)]


def _crc_with(data: bytes, match: re.Match, value: bytes) -> int:
    """CRC32 of ``data`` with the match's ChkSum text replaced by ``value``, without copying the file."""
    view = memoryview(data)
    crc = zlib.crc32(view[: match.start(2)])
    crc = zlib.crc32(value, crc)
    return zlib.crc32(view[match.end(2) :], crc)


def file_crc32(data: bytes, source: str = "IREDES file", convention: str = "documented") -> tuple[int, str | None]:
    """CRC32 of the file with the ChkSum text as ``convention`` writes it (``documented``: ``0``;
    ``empty-value``: nothing), and the stored text (``None`` when the file has no ChkSum element)."""
    found = _chksum_matches(data)
    if not found:
        return zlib.crc32(data), None
    if len(found) > 1:
        lines = [data.count(b"\n", 0, m.start()) + 1 for m in found]
        raise InputError(f"{source}: {len(found)} ChkSum elements (lines {lines}); an IREDES file has one")
    m = found[0]
    return _crc_with(data, m, CONVENTIONS[convention]), m.group(2).decode("utf-8", "replace").strip()


def _matches(stored: str, crc: int) -> bool:
    """Stored text equals the CRC read as decimal (Epiroc practice) or as hex (the XSD's hexBinary)."""
    s = stored.strip()
    as_dec = s.isdigit() and int(s) == crc
    as_hex = re.fullmatch(r"(0[xX])?[0-9A-Fa-f]{1,8}", s) is not None and int(s, 16) == crc
    return as_dec or as_hex


def line_end_forms(data: bytes) -> list[tuple[bytes, str]]:
    """The file with its line ends made all CRLF and all LF, each with what a conversion from that
    form to the bytes as they are would be called; a form equal to the bytes is left out."""
    crlf = data.count(b"\r\n")
    lf = data.count(b"\n") - crlf
    if crlf + lf == 0:
        return []
    now = "CRLF" if lf == 0 else "LF" if crlf == 0 else "mixed"
    as_lf = data.replace(b"\r\n", b"\n")
    forms = [(as_lf.replace(b"\n", b"\r\n"), "CRLF"), (as_lf, "LF")]
    return [(form, f"converted ({name} -> {now})") for form, name in forms if form != data]


def _match_conventions(data: bytes, stored: str) -> str | None:
    found = _chksum_matches(data)
    if len(found) != 1:
        return None
    return next((name for name, value in CONVENTIONS.items() if _matches(stored, _crc_with(data, found[0], value))),
                None)


def verify_checksum(data: bytes, source: str, policy: str, elements: Sequence[tuple[int, str]]) -> ChecksumResult:
    """The file's ChkSum state, with the convention and line ends that matched when verified.

    Verified: the one real ChkSum element matches either convention over the bytes as they are, or
    over the file with its line ends converted (then ``line_ends`` says so; see the module's notes).
    Unverified: no ChkSum element (no trailer), a ChkSum of ``0`` or empty (not computed), an encoding
    whose bytes the CRC cannot be taken over as rig software does (UTF-16/32), a ChkSum that is not a
    real element (only in a comment), or a mismatch. ``policy="refuse"`` raises :class:`InputError`
    for every unverified file, ``"warn"`` logs it and reads on, ``"ignore"`` does not look.
    ``elements``: the (line, text) of the real ``ChkSum`` elements, as the parser found them."""
    if policy not in CHECKSUM_POLICIES:
        raise ConfigError(f"iredes checksum policy = {policy!r}: expected one of {list(CHECKSUM_POLICIES)}")
    if policy == "ignore":
        return ChecksumResult("ignored", "solve.iredes.checksum=ignore")
    if len(elements) > 1:
        raise InputError(f"{source}: {len(elements)} ChkSum elements (lines {[e[0] for e in elements]}); "
                         "an IREDES file has one")
    why = None
    if data.startswith(_WIDE_BOMS) or b"\x00" in data[:4096]:
        why = "the file is UTF-16 or UTF-32; the checksum is a CRC32 over the UTF-8 bytes rig software writes"
    elif not elements:
        found = _CHKSUM.search(data)
        why = ("a ChkSum stands only inside a comment, which checks nothing" if found else
               "the file has no ChkSum (no IR:GenTrailer)")
    elif elements[0][1] in ("", "0"):
        why = f"ChkSum is {elements[0][1]!r} (not computed)"
    else:
        crc0, stored = file_crc32(data, source, "documented")
        if stored is None or stored != elements[0][1]:
            why = "the ChkSum element cannot be located in the file's bytes"
        else:
            for form, line_ends in [(data, AS_WRITTEN), *line_end_forms(data)]:
                convention = _match_conventions(form, stored)
                if convention is not None:
                    return _verified(source, stored, convention, line_ends)
            crc_empty = file_crc32(data, source, "empty-value")[0]
            why = (f"IREDES checksum mismatch: ChkSum in the file is {stored!r}, the CRC32 of the file with "
                   f"ChkSum 0 is {crc0} (hex {crc0:08X}), with ChkSum empty {crc_empty} (hex {crc_empty:08X}), "
                   "and neither matches with the line ends converted (CRLF <-> LF); the file changed after it "
                   "was written, or its ChkSum was computed some other way")
    if policy == "refuse":
        raise InputError(f"{source}: {why}; refused (solve.iredes.checksum=refuse): pass checksum='warn' "
                         "(solve.iredes.checksum=warn) to solve it as unverified")
    log.warning("%s: %s; reading it anyway, as unverified (checksum=warn)", source, why)
    return ChecksumResult("unverified", why)


def _verified(source: str, stored: str, convention: str, line_ends: str) -> ChecksumResult:
    detail = f"ChkSum {stored}: {_DESCRIBED[convention]} ({convention} convention)"
    if line_ends != AS_WRITTEN:
        detail += (f"; the line ends were {line_ends} after the file was written, its content is unchanged "
                   "(XML reads CRLF and LF alike)")
        log.info("%s: checksum verified with the line ends %s after writing; the content is unchanged", source,
                 line_ends)
    return ChecksumResult("verified", detail, convention, line_ends)
