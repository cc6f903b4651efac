"""Control of an endpoint as a plain object (PROTOCOL.md 7.1), the h11 split of the server.

:class:`Slots` is the connection accounting beside it: who is served, who sits on a reserved
connection for EmergencyStop only, and which one a newcomer evicts [RS-7.2], [RS-7.14],
[RS-7.24].

:class:`ControlState` holds who has control, the lease the holder asked for, the controlled
stop still running for a lost holder, and TakeControl's token back-off; it decides every
rule about them. It has no socket, thread or clock: times are arguments, and
:class:`~spec.server.FramedServer` calls it under its own lock, does the waiting and runs the
service's hooks. A holder is any :class:`~spec.server.SessionView` (the server's Session).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from spec.auth import AuthBackoff, tokens_equal
from spec.errors import ErrorCode, ProtocolError

__all__ = ["Admission", "ControlState", "SessionView", "Slots", "WrongToken"]


class SessionView(Protocol):
    """What a service's handlers and hooks see of a connection: who it is and where it stands
    with control, nothing of the server behind it. The server's Session is one; the real-time
    child's forwarded commands carry another (:class:`robotsocket.rtprocess.Who`)."""

    @property
    def id(self) -> int: ...

    @property
    def peer(self) -> tuple[Any, ...]: ...

    @property
    def in_control(self) -> bool:
        """This connection holds control."""
        ...

    @property
    def control_held(self) -> bool:
        """Some connection (this one or another) holds control."""
        ...

    @property
    def control_lost(self) -> str | None:
        """Why control was taken from this connection, None when it was not."""
        ...


H = TypeVar("H", bound=SessionView)


class WrongToken(ProtocolError):
    """TakeControl presented a wrong token [RS-7.3]: AUTH_FAILED, with the back-off it earned
    (``failures`` in a row, ``delay`` s before the address may try again) for the log."""

    def __init__(self, failures: int, delay: float) -> None:
        super().__init__("control token missing or wrong", ErrorCode.AUTH_FAILED)
        self.failures = failures
        self.delay = delay


class ControlState(Generic[H]):
    """Who holds control, the holder's lease and the controlled-stop ordering.

    The life of control: :meth:`take` makes a holder (refused while another holds it or
    while a lost holder's controlled stop runs [RS-7.10]); :meth:`end` takes it away (lost or
    released) and marks the controlled stop as running; :meth:`stopped` says the service's
    stop is done, and only then is control :attr:`free` again.
    """

    def __init__(self, backoff: AuthBackoff | None = None) -> None:
        #: Failed TakeControl attempts per address [RS-7.20].
        self.backoff = backoff if backoff is not None else AuthBackoff()
        self.holder: H | None = None
        #: The lease (s) of the holder, set at TakeControl [RS-7.13].
        self.lease = 0.0
        #: The lost (or released) holder whose controlled stop is still running [RS-7.10].
        self.stopping_for: H | None = None

    @property
    def free(self) -> bool:
        """Nobody holds control and no controlled stop is still running."""
        return self.holder is None and self.stopping_for is None

    def authorize(self, address: str, token: str, expected: str | None, now: float) -> None:
        """TakeControl's token check [RS-7.3] with the back-off per address [RS-7.20]:
        returns when ``token`` is ``expected`` (or none is expected), raises AUTH_FAILED when
        it is wrong (:class:`WrongToken`) or the address must still wait (not compared)."""
        if expected is None:
            return
        wait = self.backoff.wait(address, now)
        if wait > 0.0:
            # [RS-7.20] refused without comparing, and not counted as a failure [RS-7.26].
            raise ProtocolError(
                f"too many wrong tokens from {address}: retry in {wait:.2f} s",
                ErrorCode.AUTH_FAILED,
            )
        if tokens_equal(token, expected):
            self.backoff.succeeded(address)
            return
        raise WrongToken(*self.backoff.failed(address, now))

    @staticmethod
    def check_lease(asked: float | None, default: float, low: float, high: float) -> float:
        """The lease TakeControl gets: the one asked for, or ``default``; OUT_OF_RANGE outside
        [``low``, ``high``] [RS-7.13]."""
        lease = default if asked is None else asked
        if not low <= lease <= high:
            # [RS-7.13] the lease a client asks for must be within the server's limits.
            raise ProtocolError(
                f"watchdog must be within [{low:g}, {high:g}] s, got {lease!r}",
                ErrorCode.OUT_OF_RANGE,
            )
        return lease

    def take(self, who: H, lease: float) -> None:
        """``who`` holds control with ``lease`` (from :meth:`check_lease`); BUSY while a
        controlled stop runs or another holds control. A holder may take it again."""
        if self.stopping_for is not None:
            # A new controller starts after the lost one's controlled stop (laser off
            # first), never in the middle of it [RS-7.10].
            raise ProtocolError("a controlled stop is still running", ErrorCode.BUSY)
        holder = self.holder
        if holder is not None and holder is not who:
            raise ProtocolError(
                f"control is held by {holder.peer[0]}:{holder.peer[1]}", ErrorCode.BUSY
            )
        self.holder = who
        self.lease = lease

    def end(self, who: H | None) -> H | None:
        """Control of ``who`` (None: whoever holds it) ends; returns the holder it was taken
        from, None when ``who`` did not hold it. Until :meth:`stopped`, control is not free:
        the service switches off what needs an owner first [RS-7.10], [RS-7.21]."""
        holder = self.holder
        if holder is None or (who is not None and holder is not who):
            return None
        self.holder = None
        self.stopping_for = holder
        return holder

    def stopped(self) -> None:
        """The controlled stop (or the release's outputs off) of the last holder is done."""
        self.stopping_for = None

    def expires_at(self, alive_at: float) -> float:
        """When the holder whose last frame arrived at ``alive_at`` loses control [RS-7.13]."""
        return alive_at + self.lease

    def refusal(self, lost: str | None) -> str:
        """Why a command that needs control is refused to a connection that does not hold it
        [RS-7.4] (``lost``: why control was taken from that connection)."""
        if lost is not None:
            return f"control was lost: {lost}"
        if self.holder is not None:
            return "another client holds control"
        return "take control"


@dataclass(frozen=True)
class Admission:
    """What :meth:`Slots.admit` decided for a new connection."""

    #: Over the client limit or its address's: BUSY, not served [RS-7.2], [RS-7.24].
    full: bool
    #: Over its address's limit [RS-7.24].
    crowded: bool
    #: Kept open on a reserved slot, for EmergencyStop only [RS-7.14].
    reserved: bool


class Slots(Generic[H]):
    """The connections a server holds: the served ones and the reserved ones (over the client
    limit, kept for EmergencyStop [RS-7.14]), oldest reserved first. The limits are arguments,
    so a policy replaced while serving applies to the next connection."""

    def __init__(self) -> None:
        self.served: set[H] = set()
        self.reserved: deque[H] = deque()

    def admit(self, host: str, max_clients: int, per_address: int, reserved: int) -> Admission:
        """Decide for a new connection from ``host`` (it is not added: :meth:`add`)."""
        mine = sum(1 for s in self.served if s.peer[0] == host)
        crowded = mine >= per_address  # [RS-7.24]
        full = crowded or len(self.served) >= max_clients
        return Admission(full, crowded, full and reserved > 0)

    def add(self, session: H, admission: Admission, reserved: int) -> H | None:
        """Hold ``session`` as ``admission`` says; returns the reserved connection it evicts
        (the oldest, when all ``reserved`` slots are taken), which the caller closes."""
        if not admission.full:
            self.served.add(session)
            return None
        if not admission.reserved:
            return None
        evicted = self.reserved.popleft() if len(self.reserved) >= reserved else None
        self.reserved.append(session)
        return evicted

    def remove(self, session: H) -> None:
        """``session`` closed (served, reserved or already evicted)."""
        self.served.discard(session)
        if session in self.reserved:
            self.reserved.remove(session)

    def all(self) -> list[H]:
        """Every connection held, served first."""
        return [*self.served, *self.reserved]
