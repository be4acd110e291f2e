"""Connection strings and host names in a mission file: what ``vehicles[].link``
and ``emulator.host`` accept (pymavlink's spelling, docs/mission-format.md).
Syntax only, no name lookup, so ``gcs-swarm check`` needs no network.
"""

from __future__ import annotations

import ipaddress
import re

from gcs_swarm.mission.context import did_you_mean

__all__ = ["LINK_SCHEMES", "LINK_WHAT", "check_host", "check_link"]

LINK_SCHEMES = ("udpin", "udpout", "tcp", "tcpin")
_LINK_RE = re.compile(r"(udpin|udpout|tcp|tcpin):([^:\s]+):(\d{1,5})")
#: What a link is, in error messages and the schema.
LINK_WHAT = (
    "a connection string udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or sim"
)


_HOST_LABEL_RE = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def check_host(host: str) -> str | None:
    """None if ``host`` is an IP address or a well-formed host name (RFC 1123),
    else the error message. Syntax only, no name lookup (check needs no
    network): ``999.1.1.1`` is refused, ``localhost`` passes."""
    if re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f'"{host}" is not an IPv4 address (four numbers 0..255)'
        return None
    if ":" in host:
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            return f'"{host}" is not an IPv6 address'
        return None
    labels = host.removesuffix(".").split(".")
    if len(host) > 253 or not all(_HOST_LABEL_RE.fullmatch(lab) for lab in labels):
        return f'"{host}" is not an IP address or a host name'
    return None


def check_link(text: str) -> str | None:
    """None if ``text`` is a connection string the station understands
    (pymavlink's spelling), else the error message."""
    if text == "sim":
        return None
    m = _LINK_RE.fullmatch(text)
    if m is None:
        scheme = text.split(":", 1)[0]
        hint = did_you_mean(scheme, (*LINK_SCHEMES, "sim"))
        if scheme == "udp":
            hint = ' (pymavlink\'s "udp:" listens: write "udpin:")'
        return f'expected {LINK_WHAT}, got "{text}"{hint}'
    port = int(m[3])
    if not 1 <= port <= 65535:
        return f'expected a port 1..65535 in the connection string, got "{text}"'
    bad_host = check_host(m[2])
    if bad_host is not None:
        return f"{bad_host} in the connection string"
    return None
