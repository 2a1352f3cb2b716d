"""Which ``Host`` headers the service answers: the defence against DNS rebinding.

A web page on ``attacker.example`` can make its own name resolve to 127.0.0.1 and then call the
service from the user's browser as a same-origin request: the browser sends
``Host: attacker.example:8000``.  Only the ``Host`` header tells such a request from a real one,
so every request (pages and API, ``/health`` included) must name the server by one of:

- ``localhost``, ``127.0.0.1`` or ``::1`` (any port);
- the address the server is bound to (``airpuff serve --host``);
- any IP address, when the server is bound to every address (``0.0.0.0`` or ``::``): an address
  written as such cannot be rebound to another machine, only a DNS name can;
- a name given with ``--allowed-hosts`` (or ``AIRPUFF_ALLOWED_HOSTS``), e.g. the machine's DNS
  name or a reverse proxy's; ``*`` turns the check off (for a proxy that makes it).

Anything else gets 400 (``api.app.RequestGuard``).
"""

from __future__ import annotations

import ipaddress

ALLOWED_HOSTS_ENV = "AIRPUFF_ALLOWED_HOSTS"
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
WILDCARD_ADDRESSES = ("0.0.0.0", "::", "")


def host_name(header: str) -> str:
    """The name in a ``Host`` header without its port, lower case: ``"[::1]:8000"`` -> ``"::1"``,
    ``"LocalHost.:80"`` -> ``"localhost"``."""
    text = header.strip().lower()
    if text.startswith("["):  # an IPv6 address, with or without a port
        return text[1:].split("]", 1)[0]
    if text.count(":") == 1:
        text = text.split(":", 1)[0]
    return text.rstrip(".")


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def parse_allowed_hosts(text: str | None) -> tuple[str, ...]:
    """The names of ``--allowed-hosts`` (a comma list; ``*``: any host); raises ValueError on a
    name with characters no host name has."""
    names = []
    for part in (text or "").split(","):
        name = part.strip().lower().rstrip(".")
        if not name:
            continue
        if name != "*" and (not name.isascii() or any(c in name for c in "/@ \t[]")):
            raise ValueError(f"{part.strip()!r} is not a host name or IP address")
        names.append(name)
    return tuple(names)


class HostAllowList:
    """The allow-list of a server bound to ``bind_address`` with the extra names ``extra``."""

    def __init__(self, bind_address: str, extra: tuple[str, ...] = ()):
        bound = host_name(bind_address) if bind_address else ""
        self.any_ip = bound in WILDCARD_ADDRESSES
        self.any_host = "*" in extra
        self.names = frozenset(LOOPBACK_NAMES + (() if self.any_ip else (bound,)) + tuple(extra))

    def allows(self, header: str | None) -> bool:
        if self.any_host:
            return True
        name = host_name(header or "")
        return name in self.names or (self.any_ip and _is_ip(name))

    def describe(self) -> str:
        """The accepted names, for the message of a refusal."""
        names = sorted(self.names)
        return ", ".join(names) + (", or any IP address" if self.any_ip else "")
