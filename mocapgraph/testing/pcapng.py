"""Reads the UDP datagrams and TCP segments (with capture times and addresses) out of a pcapng capture file.

Small on purpose: enough for replaying captured device traffic in tests (NatNet over UDP, QTM over
TCP), not a general packet library. Handles little- and big-endian sections, Ethernet (with 802.1Q
tags), Linux cooked (SLL) and raw-IP links, IPv4 only, unfragmented UDP and TCP; anything else is
skipped. :func:`write_ip` writes IPv4 packets as a raw-IP capture (tests build captures with it).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

SHB, IDB, EPB, SPB = 0x0A0D0D0A, 0x00000001, 0x00000006, 0x00000003
LINK_ETHERNET, LINK_RAW, LINK_SLL, LINK_IPV4 = 1, 101, 113, 228
MAX_BLOCK = 1 << 24  # a block claiming more than 16 MiB is corruption, not a packet


class PcapngError(ValueError):
    """A file that is not a readable pcapng capture (one line naming the fault)."""


@dataclass(frozen=True)
class Datagram:
    """One captured UDP datagram: capture time (ns since the epoch), addresses, payload bytes."""

    time_ns: int
    src: tuple[str, int]
    dst: tuple[str, int]
    payload: bytes


def _ip(b: bytes) -> str:
    return ".".join(str(x) for x in b)


def _udp_from_ip(pkt: bytes) -> tuple[tuple[str, int], tuple[str, int], bytes] | None:
    """IPv4 packet -> (src, dst, UDP payload), None for anything but a whole UDP datagram."""
    if len(pkt) < 20 or pkt[0] >> 4 != 4:
        return None
    ihl = (pkt[0] & 15) * 4
    frag = struct.unpack_from(">H", pkt, 6)[0]
    if pkt[9] != 17 or frag & 0x3FFF or len(pkt) < ihl + 8:  # not UDP, or a fragment
        return None
    sport, dport, ulen = struct.unpack_from(">HHH", pkt, ihl)
    payload = pkt[ihl + 8: ihl + max(ulen, 8)]
    return (_ip(pkt[12:16]), sport), (_ip(pkt[16:20]), dport), payload


def _ip_from_link(link: int, frame: bytes) -> bytes | None:
    if link == LINK_ETHERNET:
        off, etype = 14, struct.unpack_from(">H", frame, 12)[0] if len(frame) >= 14 else 0
        while etype == 0x8100 and len(frame) >= off + 4:  # VLAN tags
            etype = struct.unpack_from(">H", frame, off + 2)[0]
            off += 4
        return frame[off:] if etype == 0x0800 else None
    if link == LINK_SLL:
        return frame[16:] if len(frame) >= 16 and struct.unpack_from(">H", frame, 14)[0] == 0x0800 else None
    if link in (LINK_RAW, LINK_IPV4):
        return frame
    return None


def _resolution(options: bytes, endian: str) -> float:
    """if_tsresol option of an interface block -> seconds per timestamp unit (default 1 us)."""
    off = 0
    while off + 4 <= len(options):
        code, length = struct.unpack_from(endian + "HH", options, off)
        if code == 0:
            break
        if code == 9 and length >= 1:
            v = options[off + 4]
            return 2.0 ** -(v & 0x7F) if v & 0x80 else 10.0 ** -v
        off += 4 + ((length + 3) & ~3)
    return 1e-6


def _ip_packets(path: str | Path):
    """(capture time ns, IPv4 packet bytes) of every IPv4 packet of the capture, in file order."""
    data = Path(path).read_bytes()
    name = Path(path).name
    if not data.startswith(struct.pack("<I", SHB)):
        raise PcapngError(f"{name}: not a pcapng file (no section header block)")
    endian = "<"
    links: list[tuple[int, float]] = []
    off = 0
    while off + 12 <= len(data):
        btype = struct.unpack_from("<I", data, off)[0]
        if btype == SHB:
            magic = data[off + 8: off + 12]
            endian = {b"\x4d\x3c\x2b\x1a": "<", b"\x1a\x2b\x3c\x4d": ">"}.get(magic)
            if endian is None:
                raise PcapngError(f"{name}: section header at byte {off} has a bad byte-order magic")
            links = []  # interface ids are per section
        blen = struct.unpack_from(endian + "I", data, off + 4)[0]
        if blen < 12 or blen % 4 or blen > MAX_BLOCK or off + blen > len(data):
            raise PcapngError(f"{name}: block at byte {off} claims length {blen} "
                              f"({len(data) - off} bytes left)")
        body = data[off + 8: off + blen - 4]
        if btype == IDB and len(body) >= 8:
            link = struct.unpack_from(endian + "H", body, 0)[0]
            links.append((link, _resolution(body[8:], endian)))
        elif btype == EPB and len(body) >= 20:
            iface, ts_hi, ts_lo, caplen, _orig = struct.unpack_from(endian + "IIIII", body, 0)
            if iface < len(links) and 20 + caplen <= len(body):
                link, res = links[iface]
                ip = _ip_from_link(link, body[20: 20 + caplen])
                if ip is not None:
                    yield int(round(((ts_hi << 32) | ts_lo) * res * 1e9)), ip
        off += blen


def read_udp(path: str | Path) -> list[Datagram]:
    """Every whole IPv4 UDP datagram of the capture, in file order. PcapngError on a broken file."""
    out: list[Datagram] = []
    for t, ip in _ip_packets(path):
        udp = _udp_from_ip(ip)
        if udp is not None:
            out.append(Datagram(t, udp[0], udp[1], udp[2]))
    return out


@dataclass(frozen=True)
class Segment:
    """One captured TCP segment: capture time (ns), addresses, sequence number, flags, payload."""

    time_ns: int
    src: tuple[str, int]
    dst: tuple[str, int]
    seq: int
    flags: int
    payload: bytes


def read_tcp(path: str | Path) -> list[Segment]:
    """Every unfragmented IPv4 TCP segment of the capture, in file order. PcapngError on a broken file."""
    out: list[Segment] = []
    for t, pkt in _ip_packets(path):
        if len(pkt) < 20 or pkt[0] >> 4 != 4 or pkt[9] != 6 or struct.unpack_from(">H", pkt, 6)[0] & 0x3FFF:
            continue
        ihl = (pkt[0] & 15) * 4
        total = struct.unpack_from(">H", pkt, 2)[0] or len(pkt)
        if len(pkt) < ihl + 20:
            continue
        sport, dport, seq = struct.unpack_from(">HHI", pkt, ihl)
        thl = (pkt[ihl + 12] >> 4) * 4
        out.append(Segment(t, (_ip(pkt[12:16]), sport), (_ip(pkt[16:20]), dport), seq, pkt[ihl + 13],
                           pkt[ihl + thl: min(total, len(pkt))]))
    return out


def write_ip(path: str | Path, packets: list[tuple[int, bytes]]) -> None:
    """(capture time ns, IPv4 packet) pairs as a pcapng file (one raw-IPv4 interface, ns stamps)."""
    def block(btype: int, body: bytes) -> bytes:
        body += b"\0" * (-len(body) % 4)
        n = len(body) + 12
        return struct.pack("<II", btype, n) + body + struct.pack("<I", n)

    out = block(SHB, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1))
    out += block(IDB, struct.pack("<HHI", LINK_IPV4, 0, 0) + struct.pack("<HHB3x", 9, 1, 9) + b"\0" * 4)
    for t, ip in packets:
        out += block(EPB, struct.pack("<IIIII", 0, t >> 32, t & 0xFFFFFFFF, len(ip), len(ip)) + ip)
    Path(path).write_bytes(out)
