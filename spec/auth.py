"""Control tokens: reading a token file, comparing tokens, slowing down token guessing.

Pure code (no socket, no clock of its own): the server passes the source address and the
time of each TakeControl attempt [RS-7.20].
"""

from __future__ import annotations

import hmac
import ipaddress
import os
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def address_allowed(allow: Iterable[Network], host: str) -> bool:
    """Whether ``host`` (a numeric address, as a socket reports it) is in ``allow``; an empty
    allow-list allows every address [RS-7.7]."""
    nets = tuple(allow)
    if not nets:
        return True
    try:
        address = ipaddress.ip_address(host.split("%")[0])
    except ValueError:
        return False
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped  # ::ffff:10.0.0.1 from a dual-stack socket
    return any(address in net for net in nets)


def read_token_file(path: str | os.PathLike[str]) -> str:
    """The token in ``path``: the file's text with surrounding whitespace stripped.

    ValueError naming the file when it is missing, unreadable, not UTF-8, empty or only
    whitespace: an empty token would switch the protection off without anyone noticing."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read token file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"token file {path} is not UTF-8 text") from None
    token = text.strip()
    if not token:
        raise ValueError(f"token file {path} is empty (it must hold the token on one line)")
    if "\n" in token or "\r" in token:
        raise ValueError(f"token file {path} has several lines (the token is one line)")
    return token


def tokens_equal(given: str, expected: str) -> bool:
    """Constant-time comparison: the time taken does not tell how much of a guess was right."""
    # compare_digest takes str only when ASCII; bytes work for every token.
    return hmac.compare_digest(
        given.encode("utf-8", "surrogatepass"), expected.encode("utf-8", "surrogatepass")
    )


@dataclass
class _Failures:
    count: int  # consecutive failures
    last: float  # s: time of the latest failure
    not_before: float  # s: attempts before this time are refused without comparing


class AuthBackoff:
    """Per-address back-off of failed TakeControl attempts [RS-7.20].

    From its ``threshold``-th consecutive failure on, an address is blocked for ``base``
    seconds, doubling with each further failure up to ``cap``; the failures before cost
    nothing (a typo, the conformance case for a wrong token). A success, or ``forget`` seconds
    without a failure, resets the address. At most ``max_addresses`` addresses are remembered
    (the least recently failed one is forgotten first), so a flood of source addresses cannot
    grow the table without bound.
    """

    def __init__(
        self,
        base: float = 0.1,
        cap: float = 10.0,
        threshold: int = 3,
        forget: float = 600.0,
        max_addresses: int = 4096,
    ) -> None:
        if not (0 < base <= cap <= forget and threshold >= 1 and max_addresses > 0):
            msg = "need 0 < base <= cap <= forget, threshold >= 1 and max_addresses > 0"
            raise ValueError(msg)
        self.base = base
        self.cap = cap
        self.threshold = threshold
        self.forget = forget
        self.max_addresses = max_addresses
        self._failures: OrderedDict[str, _Failures] = OrderedDict()

    def wait(self, address: str, now: float) -> float:
        """Seconds until ``address`` may try again (0.0: it may try now)."""
        entry = self._failures.get(address)
        return 0.0 if entry is None else max(0.0, entry.not_before - now)

    def failed(self, address: str, now: float) -> tuple[int, float]:
        """Record a failed attempt at ``now``; returns (consecutive failures, delay in s
        before the address may try again)."""
        entry = self._failures.pop(address, None)
        if entry is None or now - entry.last > self.forget:
            entry = _Failures(0, now, now)
        entry.count += 1
        entry.last = now
        over = entry.count - self.threshold
        delay = 0.0 if over < 0 else min(self.cap, self.base * 2.0 ** min(over, 64))
        entry.not_before = now + delay
        self._failures[address] = entry  # most recent last
        while len(self._failures) > self.max_addresses:
            self._failures.popitem(last=False)
        return entry.count, delay

    def succeeded(self, address: str) -> None:
        """The address presented the right token: its failures are forgiven."""
        self._failures.pop(address, None)

    def __len__(self) -> int:
        return len(self._failures)


__all__ = ["AuthBackoff", "Network", "address_allowed", "read_token_file", "tokens_equal"]
