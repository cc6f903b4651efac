"""The control state (spec.control) without sockets: holder, lease, controlled-stop ordering,
token back-off, the refusal messages [RS-7.3], [RS-7.4], [RS-7.10], [RS-7.13], [RS-7.20]; the
connection slots [RS-7.2], [RS-7.14], [RS-7.24]."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from spec.auth import AuthBackoff
from spec.control import Admission, ControlState, SessionView, Slots, WrongToken
from spec.errors import ErrorCode, ProtocolError


@dataclass(eq=False)
class Conn:
    """A connection as the control state needs it: compared by identity, as sessions are."""

    id: int
    peer: tuple[Any, ...] = ("10.0.0.1", 5000)
    in_control: bool = False
    control_held: bool = False
    control_lost: str | None = None


def _busy(fn: Any, *args: Any) -> str:
    with pytest.raises(ProtocolError) as err:
        fn(*args)
    assert err.value.code is ErrorCode.BUSY
    return err.value.message


def test_a_conn_is_a_session_view() -> None:
    view: SessionView = Conn(1)
    assert view.id == 1


def test_take_then_another_is_busy_naming_the_holder() -> None:
    state: ControlState[Conn] = ControlState()
    a, b = Conn(1, ("10.0.0.1", 4001)), Conn(2)
    assert state.free
    state.take(a, 0.5)
    assert state.holder is a and state.lease == 0.5 and not state.free
    assert _busy(state.take, b, 0.5) == "control is held by 10.0.0.1:4001"
    state.take(a, 2.0)  # the holder may take it again, with a new lease
    assert state.holder is a and state.lease == 2.0


def test_a_new_controller_waits_for_the_lost_ones_controlled_stop() -> None:
    """[RS-7.10] control is free only once the service's stop is done."""
    state: ControlState[Conn] = ControlState()
    a, b = Conn(1), Conn(2)
    state.take(a, 0.25)
    assert state.end(a) is a
    assert state.holder is None and state.stopping_for is a and not state.free
    assert _busy(state.take, b, 0.25) == "a controlled stop is still running"
    assert _busy(state.take, a, 0.25) == "a controlled stop is still running"
    state.stopped()
    assert state.free
    state.take(b, 0.25)
    assert state.holder is b


def test_end_of_someone_not_holding_changes_nothing() -> None:
    state: ControlState[Conn] = ControlState()
    a, b = Conn(1), Conn(2)
    assert state.end(None) is None and state.free  # nobody holds it
    state.take(a, 0.25)
    assert state.end(b) is None and state.holder is a
    assert state.end(None) is a  # None: whoever holds it (the server's shutdown)


def test_the_lease_runs_from_the_last_frame() -> None:
    """[RS-7.13] the holder's deadline is its last frame plus the lease it asked for."""
    state: ControlState[Conn] = ControlState()
    state.take(Conn(1), 0.25)
    assert state.expires_at(100.0) == 100.25


@pytest.mark.parametrize(("asked", "want"), [(None, 0.25), (0.05, 0.05), (10.0, 10.0), (1.5, 1.5)])
def test_lease_asked_or_default(asked: float | None, want: float) -> None:
    assert ControlState.check_lease(asked, 0.25, 0.05, 10.0) == want


@pytest.mark.parametrize("asked", [0.0, 0.049, 10.001, float("inf"), float("nan"), -1.0])
def test_lease_outside_the_limits_is_out_of_range(asked: float) -> None:
    with pytest.raises(ProtocolError) as err:
        ControlState.check_lease(asked, 0.25, 0.05, 10.0)
    assert err.value.code is ErrorCode.OUT_OF_RANGE
    assert err.value.message.startswith("watchdog must be within [0.05, 10] s, got ")


def test_no_token_expected_lets_any_through() -> None:
    state: ControlState[Conn] = ControlState()
    for now in range(10):
        state.authorize("10.0.0.1", "wrong", None, float(now))
    assert len(state.backoff) == 0


def test_wrong_tokens_back_off_and_the_wait_is_not_compared() -> None:
    """[RS-7.20] from the third failure on the address waits; a try during the wait is
    refused without comparing (the right token too) and not counted [RS-7.26]."""
    state: ControlState[Conn] = ControlState(AuthBackoff(base=0.1, threshold=3))
    for n in (1, 2, 3):
        with pytest.raises(WrongToken) as wrong:
            state.authorize("10.0.0.1", "guess", "secret", 0.0)
        assert wrong.value.code is ErrorCode.AUTH_FAILED and wrong.value.failures == n
    assert wrong.value.delay == pytest.approx(0.1)
    with pytest.raises(ProtocolError) as err:
        state.authorize("10.0.0.1", "secret", "secret", 0.05)
    assert not isinstance(err.value, WrongToken) and err.value.code is ErrorCode.AUTH_FAILED
    assert err.value.message == "too many wrong tokens from 10.0.0.1: retry in 0.05 s"
    state.authorize("10.0.0.2", "secret", "secret", 0.05)  # another address is not held up
    state.authorize("10.0.0.1", "secret", "secret", 0.1)  # after the wait: right, forgiven
    assert len(state.backoff) == 0


@pytest.mark.parametrize(
    ("lost", "holder", "want"),
    [
        ("watchdog: no frame for 0.25 s", True, "control was lost: watchdog: no frame for 0.25 s"),
        (None, True, "another client holds control"),
        (None, False, "take control"),
    ],
)
def test_refusal_says_why(lost: str | None, holder: bool, want: str) -> None:
    """[RS-7.4] the NOT_IN_CONTROL message: the loss first, then someone else, then none."""
    state: ControlState[Conn] = ControlState()
    if holder:
        state.take(Conn(9), 0.25)
    assert state.refusal(lost) == want


# (operation, connection index): take, end (lost or released), stopped
_OPS = st.lists(
    st.tuples(st.sampled_from(["take", "end", "end_any", "stopped"]), st.integers(0, 2)),
    max_size=40,
)


@given(_OPS)
def test_at_most_one_holder_and_none_during_a_controlled_stop(ops: list[tuple[str, int]]) -> None:
    """Whatever the order of events: one holder at most; nobody takes control while a
    controlled stop runs; only the holder's end stops anything; free means neither."""
    state: ControlState[Conn] = ControlState()
    conns = [Conn(i) for i in range(3)]
    for op, i in ops:
        who = conns[i]
        before_holder, before_stopping = state.holder, state.stopping_for
        if op == "take":
            try:
                state.take(who, 0.25)
            except ProtocolError as exc:
                assert exc.code is ErrorCode.BUSY
                assert before_stopping is not None or before_holder not in (None, who)
                assert (state.holder, state.stopping_for) == (before_holder, before_stopping)
            else:
                assert before_stopping is None and before_holder in (None, who)
                assert state.holder is who
        elif op in ("end", "end_any"):
            ended = state.end(who if op == "end" else None)
            if before_holder is None or (op == "end" and before_holder is not who):
                assert ended is None
                assert (state.holder, state.stopping_for) == (before_holder, before_stopping)
            else:
                assert ended is before_holder and state.holder is None
                assert state.stopping_for is ended
        else:
            state.stopped()
            assert state.stopping_for is None and state.holder is before_holder
        assert state.free == (state.holder is None and state.stopping_for is None)
        assert state.holder is None or state.stopping_for is None


def _join(slots: Slots[Conn], conn: Conn, *, clients: int = 2, per: int = 2, res: int = 2) -> Any:
    admission = slots.admit(conn.peer[0], clients, per, res)
    return admission, slots.add(conn, admission, res)


def test_served_up_to_the_limit_then_reserved_then_the_oldest_reserved_is_evicted() -> None:
    """[RS-7.2] over the limit is BUSY; [RS-7.14] kept on a reserved slot, the oldest of which
    makes room for a newcomer."""
    slots: Slots[Conn] = Slots()
    a, b, c, d, e = (Conn(i, (f"10.0.0.{i}", 1)) for i in range(5))
    assert _join(slots, a) == (Admission(False, False, False), None)
    assert _join(slots, b) == (Admission(False, False, False), None)
    assert _join(slots, c) == (Admission(True, False, True), None)
    assert _join(slots, d) == (Admission(True, False, True), None)
    assert _join(slots, e) == (Admission(True, False, True), c)
    assert slots.served == {a, b} and list(slots.reserved) == [d, e]
    slots.remove(c)  # the evicted one's reader ends its session later: nothing to do
    slots.remove(a)
    assert slots.all() == [b, d, e]
    assert _join(slots, c)[0] == Admission(False, False, False)  # a slot came free


def test_one_address_cannot_take_every_slot() -> None:
    """[RS-7.24] an address at its limit is crowded even with slots free."""
    slots: Slots[Conn] = Slots()
    one = [Conn(i, ("10.0.0.1", i)) for i in range(3)]
    for conn in one[:2]:
        _join(slots, conn, clients=8)
    assert _join(slots, one[2], clients=8)[0] == Admission(True, True, True)
    assert _join(slots, Conn(9, ("10.0.0.2", 1)), clients=8)[0].full is False


def test_without_reserved_slots_a_full_server_holds_nothing_more() -> None:
    slots: Slots[Conn] = Slots()
    _join(slots, Conn(1), clients=1, res=0)
    late = Conn(2, ("10.0.0.2", 1))
    assert _join(slots, late, clients=1, res=0) == (Admission(True, False, False), None)
    assert late not in slots.all()


@given(st.lists(st.tuples(st.booleans(), st.integers(0, 3), st.integers(0, 9)), max_size=60))
def test_slots_never_exceed_their_limits(ops: list[tuple[bool, int, int]]) -> None:
    """Joins and leaves in any order: served at most the client limit and the per-address
    limit, reserved at most the reserved slots, no connection in both."""
    slots: Slots[Conn] = Slots()
    conns = [Conn(i, (f"10.0.0.{i % 4}", i)) for i in range(10)]
    for join, host, i in ops:
        conn = conns[i]
        if join and conn not in slots.all():
            conn = conns[i] = Conn(i, (f"10.0.0.{host}", i))
            _join(slots, conn, clients=5, per=3, res=2)
        else:
            slots.remove(conn)
        assert len(slots.served) <= 5 and len(slots.reserved) <= 2
        assert not slots.served & set(slots.reserved)
        for h in range(4):
            assert sum(1 for c in slots.served if c.peer[0] == f"10.0.0.{h}") <= 3
