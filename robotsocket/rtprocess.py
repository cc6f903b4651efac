"""The robot's real-time loop in a process of its own (docs/REALTIME.md, issue 12).

Why a process: CPython hands the GIL to any waiting thread, so in one process the 4 ms tick
waits behind the request threads of 64 clients (p99 7-118 ms measured). Here the child
process runs the robot emulator's clock, the UDP trigger/data endpoint (and, for the cell,
the emulated sensor's trigger handling) with no request thread in it; the server process
keeps the TCP connections.

- **Shared memory** (:mod:`robotsocket.shared_state`): the child publishes the joints, the
  status and the motion state every cycle and after every command; the server answers
  Herej, Here, RobotStatus, GetTime and WaitEndMove from it without asking the child.
- **A pipe** (a socket pair carrying pickled ``(request ID, message)`` pairs, each message a
  dataclass of this module): every other command is forwarded as a :class:`Command`
  (service, the request the shell decoded, what the session holds) to the child's own
  :class:`~spec.server.HandlerService`, which answers exactly as in-process; its error
  packets come back with their codes. The child runs the service's urgent commands
  (EmergencyStop, StopMove, ResetMotion) and a lost controller the moment they arrive, the
  others in order on a worker, so the stopping ones overtake a slow move plan.
- **Failure**: the server process gone (pipe EOF, or a new parent pid) -> the child does the
  controlled stop of a lost controller (laser off first, [RS-7.10]), waits for the arm to
  stand, and exits. The child gone -> every command is refused with BAD_STATE, at once.

What the child builds is named by ``"module:function"`` (``build_robot`` here; the cell's in
:mod:`cell.rtcell`), so a layer above can put more into it without an upward import.
"""

from __future__ import annotations

import importlib
import itertools
import logging
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from kinematics.dynamics import dynamics_named
from kinematics.errors import KinematicsError
from kinematics.robot import get_model
from robotsocket.emulator import RobotEmulator, here_at
from robotsocket.interface import OutOfRangeError, RobotError, RobotStatus
from robotsocket.service import RobotService, error_code, status_reply, wait_reply
from robotsocket.shared_state import SharedState, Snapshot
from robotsocket.sync_service import attach_udp_sync
from spec import messages as M
from spec.errors import ErrorCode, ProtocolError
from spec.params import Joints, Location, Value
from spec.realtime import promote_current_thread
from spec.server import HandlerService, Identity, SessionView
from spec.wire import MoveOutcome

__all__ = [
    "Answer",
    "ChildParts",
    "ChildStartError",
    "Close",
    "Command",
    "ControlLost",
    "ControlReleased",
    "Err",
    "Failed",
    "ForwardedService",
    "Ok",
    "Query",
    "Ready",
    "RealtimeProcess",
    "Request",
    "RobotProcess",
    "Start",
    "Who",
    "build_robot",
]

log = logging.getLogger(__name__)

#: A forwarded command that takes longer is answered BAD_STATE (a frozen child).
COMMAND_TIMEOUT_S = 30.0
#: Start-up of the child (imports, building the emulator, binding its UDP port).
READY_TIMEOUT_S = 60.0
#: Real-time priority of the child's command threads (below the timing threads' 50): a
#: thread holding the child's GIL must not be preempted by other processes, or the timing
#: threads wait for it (priority inversion through the GIL).
COMMAND_PRIORITY = 40
#: How often the child checks that its parent still exists when the pipe is quiet.
PARENT_CHECK_S = 0.5
#: The longest the child waits for the arm to stand after its parent is gone.
STOP_WAIT_S = 10.0


class ChildStartError(RuntimeError):
    """The real-time process could not be built (bad option, port in use): one line."""


@dataclass(frozen=True)
class ServiceInfo:
    """What the server process needs to know about one of the child's services."""

    identity: Identity
    implemented: tuple[int, ...]
    urgent: frozenset[int]
    blocking: frozenset[int]


@dataclass
class ChildParts:
    """What a builder puts into the child: the robot (its state is published), the services
    the server forwards to (by name), how to start and stop the real-time parts, named
    queries the parent may call, and facts sent to the parent once at start-up."""

    robot: RobotEmulator
    services: dict[str, HandlerService]
    start: Callable[[], object]
    stop: Callable[[], None]
    queries: dict[str, Callable[..., Any]] = field(default_factory=dict)
    facts: dict[str, Any] = field(default_factory=dict)


def build_robot(config: dict[str, Any]) -> ChildParts:
    """The emulator, its service and the UDP synchronisation endpoint of
    ``python -m robotsocket serve``: the real-time child's parts, and the same parts run
    in-process (simulated clock, ``--in-process``). ``config["clock"]`` defaults to real,
    ``config["dynamics"]`` to off (:func:`kinematics.dynamics.dynamics_named`)."""
    try:
        dynamics = dynamics_named(config.get("dynamics", "off"), config["model"])
    except ValueError as exc:
        raise ChildStartError(str(exc)) from None
    robot = RobotEmulator(
        config["model"],
        clock=config.get("clock", "real"),
        encoder_latency=config["encoder_latency_s"],
        dynamics=dynamics,
    )
    service = RobotService(robot)
    endpoint = None
    if config["udp_port"] is not None:
        host, port = config["host"], config["udp_port"]
        try:
            _, endpoint = attach_udp_sync(service, robot, host=host, port=port)
        except OSError as exc:
            raise ChildStartError(
                f"cannot listen on {host}:{port} (--udp-port): {exc.strerror}"
            ) from None
        endpoint.allow = tuple(config["allow"])  # [RS-7.7]
        endpoint.sensor_only = not config["data_from_any"]  # [SY-3.7]

    def start() -> None:
        robot.start()
        if endpoint is not None:
            endpoint.start()

    def stop() -> None:
        if endpoint is not None:
            if endpoint.dropped:
                log.info("udp datagrams dropped: %s", dict(endpoint.dropped))
            endpoint.stop()
        robot.close()
        j = robot.jitter()
        if j["count"]:
            log.info(
                "tick jitter: p50 %.3f ms, p99 %.3f ms, max %.3f ms over %d ticks",
                j["p50"] * 1e3, j["p99"] * 1e3, j["max"] * 1e3, int(j["count"]),
            )  # fmt: skip

    facts = {
        "udp_address": endpoint.address if endpoint is not None else None,
        "period": robot.period,
    }
    return ChildParts(robot, {"robot": service}, start, stop, {"jitter": robot.jitter}, facts)


# --- the pipe's messages ------------------------------------------------------------------------
#
# The parent sends (request ID, request) and the child answers (request ID, Ok | Err), once per
# request, whatever its kind: a caller never waits out its timeout. Start-up is one Start from
# the parent and one Ready or Failed from the child, before any request.


@dataclass(frozen=True)
class Who:
    """A forwarded command's session as the server process saw it when it forwarded the
    command: the :class:`~spec.server.SessionView` the child's handlers see."""

    id: int
    peer: tuple[Any, ...]
    in_control: bool
    #: Some session (this one or another) holds control.
    control_held: bool
    control_lost: str | None = None

    @classmethod
    def of(cls, session: SessionView) -> Who:
        return cls(
            session.id, session.peer, session.in_control, session.control_held, session.control_lost
        )


@dataclass(frozen=True)
class Command:
    """Execute ``request`` (decoded and checked by the server process's shell) on service
    ``service`` for the session ``who``."""

    service: str
    request: M.Request[Any]
    who: Who


@dataclass(frozen=True)
class ControlLost:
    """The controller of ``service`` is gone: its controlled stop [RS-7.10]."""

    service: str
    why: str = ""


@dataclass(frozen=True)
class ControlReleased:
    """The controller of ``service`` gave control back [RS-7.21]."""

    service: str


@dataclass(frozen=True)
class Query:
    """Call the builder's named query with ``args``."""

    name: str
    args: tuple[Any, ...] = ()


@dataclass(frozen=True)
class Close:
    """Stop the loops and exit; answered once they stopped."""


Request = Command | ControlLost | ControlReleased | Query | Close


@dataclass(frozen=True)
class Ok:
    """A request done; ``value`` is its result (a command's reply parameters)."""

    value: Any = ()


@dataclass(frozen=True)
class Err:
    """A request refused or failed, with the wire code the server replies with."""

    code: int
    message: str


Answer = Ok | Err


@dataclass(frozen=True)
class Start:
    """The parent's first message: the builder (``"module:function"``) and its config."""

    target: str
    config: dict[str, Any]


@dataclass(frozen=True)
class Ready:
    """The child's first message when it was built: its services and the builder's facts."""

    infos: dict[str, ServiceInfo]
    facts: dict[str, Any]


@dataclass(frozen=True)
class Failed:
    """The child's first message when it could not be built (one line)."""

    message: str


# --- the child ----------------------------------------------------------------------------------


def _no_session(why: str = "") -> Who:
    """The session a control hook sees in the child: control ended for ``why``."""
    return Who(0, ("", 0), False, False, why or None)


class _ChildHost:
    """The child's side of the pipe: runs forwarded commands, publishes the state."""

    def __init__(
        self, conn: Connection, parts: ChildParts, state: SharedState, parent: int
    ) -> None:
        self.conn = conn
        self.parts = parts
        self.state = state
        self.parent = parent
        self.close_rid = 0
        self._rest_published = False
        self._send_lock = threading.Lock()
        self._queues: dict[str, queue.SimpleQueue[tuple[int, Command] | None]] = {}
        for name in parts.services:
            q: queue.SimpleQueue[tuple[int, Command] | None] = queue.SimpleQueue()
            self._queues[name] = q
            threading.Thread(target=self._work, args=(q,), name=f"rt-{name}", daemon=True).start()

    def publish(self) -> None:
        self.parts.robot.publish(self.state.write)

    def on_cycle(self, *_: object) -> None:
        """Publish each cycle, except the cycles a robot at rest runs after an idle wait: they
        change nothing but the cycle number (the server reads the time from the clock)."""
        rest = self.parts.robot.at_rest()
        if not (rest and self._rest_published):
            self.publish()
        self._rest_published = rest

    def _send(self, rid: int, answer: Answer) -> None:
        with self._send_lock:
            try:
                self.conn.send((rid, answer))
            except OSError:
                pass  # the parent is gone: serve() notices and stops the arm

    def _work(self, q: queue.SimpleQueue[tuple[int, Command] | None]) -> None:
        promote_current_thread(COMMAND_PRIORITY)
        while (item := q.get()) is not None:
            self._execute(*item)

    def _execute(self, rid: int, cmd: Command) -> None:
        service = self.parts.services[cmd.service]
        answer: Answer
        try:
            answer = Ok(service.handle(cmd.who, cmd.request))
        except ProtocolError as exc:
            answer = Err(int(exc.code), exc.message)
        except Exception as exc:
            log.exception("forwarded command 0x%04x failed", cmd.request.command)
            answer = Err(int(ErrorCode.INTERNAL_ERROR), f"internal error: {exc!r}")
        self.publish()  # before the reply: a poll after it sees the command's effect
        self._send(rid, answer)

    def _control_ended(self, rid: int, name: str, lost: bool, why: str = "") -> None:
        service = self.parts.services[name]
        hook = service.on_control_lost if lost else service.on_control_released
        hook(_no_session(why))
        self.publish()
        self._send(rid, Ok())

    def _query(self, rid: int, query: Query) -> None:
        try:
            self._send(rid, Ok(self.parts.queries[query.name](*query.args)))
        except Exception as exc:  # noqa: BLE001 - every query is answered, never a wait
            self._send(rid, Err(int(ErrorCode.INTERNAL_ERROR), repr(exc)))

    def serve(self) -> str:
        """Answer the parent until it says close (returns "close") or is gone."""
        got = promote_current_thread(COMMAND_PRIORITY)
        log.info("command threads: scheduling %s", got)
        while True:
            try:
                if not self.conn.poll(PARENT_CHECK_S):
                    if os.getppid() != self.parent:
                        return "the server process is gone (new parent)"
                    continue
                rid, msg = self.conn.recv()
            except (EOFError, OSError):
                return "the server process is gone (pipe closed)"
            if isinstance(msg, Close):
                self.close_rid = rid
                return "close"
            try:
                self._dispatch(rid, msg)
            except Exception as exc:  # every message is answered, never a wait
                log.exception("pipe message %s failed", type(msg).__name__)
                self._send(rid, Err(int(ErrorCode.INTERNAL_ERROR), f"internal error: {exc!r}"))

    def _dispatch(self, rid: int, msg: object) -> None:
        """Answer ``msg`` now, or queue it on its service's worker (which answers it)."""
        match msg:
            case Command(service=name, request=request) if name in self.parts.services:
                if request.command in self.parts.services[name].urgent:
                    self._execute(rid, msg)  # overtakes queued commands
                else:
                    self._queues[name].put((rid, msg))
            case ControlLost(service=name, why=why) if name in self.parts.services:
                self._control_ended(rid, name, True, why)
            case ControlReleased(service=name) if name in self.parts.services:
                self._control_ended(rid, name, False)
            case Query():
                self._query(rid, msg)
            case _:  # every message is answered: a caller never waits out its timeout
                what = f"unknown message {type(msg).__name__} {msg!r:.80}"
                self._send(rid, Err(int(ErrorCode.INTERNAL_ERROR), what))

    def controlled_stop(self, why: str) -> None:
        """[RS-7.10] as for a lost controller: laser off first, the arm decelerates along its
        path, the triggers stop; then wait for the arm to stand."""
        log.warning("%s: controlled stop", why)
        for service in self.parts.services.values():
            try:
                service.on_control_lost(_no_session(why))
            except Exception:
                log.exception("controlled stop failed")
        robot = self.parts.robot
        stood = robot.wait_end_move(STOP_WAIT_S)
        self.publish()
        q = ", ".join(f"{v:.3f}" for v in robot.herej())
        log.warning("arm %s at [%s]", "stopped" if stood else "NOT stopped", q)


def child_main(argv: list[str]) -> int:
    """The child's entry, with arguments FD STATE_PATH: read (builder, config) from the
    pipe on FD, build, say ready, serve."""
    # Ctrl-C in a terminal reaches the whole process group: the server process stops the
    # child (close), a lost server makes it stop the arm; never a KeyboardInterrupt here.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn = Connection(int(argv[0]))
    start: Start = conn.recv()
    target, config = start.target, start.config
    logging.basicConfig(
        level=config.get("log_level", logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s[rt]: %(message)s",
        stream=sys.stderr,
    )
    parent = os.getppid()
    state = SharedState.attach(argv[1])
    module, func = target.split(":")
    try:
        parts: ChildParts = getattr(importlib.import_module(module), func)(config)
    except (ChildStartError, ValueError, KinematicsError, OSError) as exc:
        conn.send(Failed(str(exc)))
        return 2
    host = _ChildHost(conn, parts, state, parent)
    parts.robot.cycle_hooks.append(host.on_cycle)
    parts.start()
    state.set_start_ns(parts.robot.clock_start_ns)
    host.publish()
    infos = {
        name: ServiceInfo(s.identity, s.implemented(), s.urgent, s.blocking)
        for name, s in parts.services.items()
    }
    conn.send(Ready(infos, parts.facts))
    log.info("real-time process pid %d serving %s", os.getpid(), ", ".join(infos))
    why = host.serve()
    if why != "close":
        host.controlled_stop(why)
    parts.stop()
    state.close()
    if why == "close":
        try:
            conn.send((host.close_rid, Ok()))
        except OSError:
            pass
    log.info("real-time process exits")
    return 0


# --- the server's side --------------------------------------------------------------------------


#: The child's command line (not ``-m``: its classes must pickle under their module's name).
_CHILD = (
    "import sys; from robotsocket.rtprocess import child_main; sys.exit(child_main(sys.argv[1:]))"
)


class RealtimeProcess:
    """The child process and the pipe to it, as the server process sees them.

    ``target`` names the builder (``"module:function"`` returning :class:`ChildParts`),
    ``config`` its (picklable) settings. Raises :class:`ChildStartError` when the child
    cannot be built. :attr:`state` is the shared state; :attr:`facts` what the builder said.
    """

    def __init__(self, target: str, config: dict[str, Any]) -> None:
        self.state = SharedState.create()
        ours, theirs = socket.socketpair()
        self._conn = Connection(ours.detach())
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _CHILD, str(theirs.fileno()), self.state.path],
            pass_fds=(theirs.fileno(),),
        )
        theirs.close()
        # the child logs what this process would log
        config = {"log_level": logging.getLogger().getEffectiveLevel(), **config}
        self._conn.send(Start(target, config))
        msg: Ready | Failed = Failed("")
        try:
            if self._conn.poll(READY_TIMEOUT_S):
                msg = self._conn.recv()
        except (EOFError, OSError):
            pass
        self.state.unlink()  # both sides have it mapped: nothing left behind after a crash
        if not isinstance(msg, Ready):
            self._kill()
            why = msg.message or f"real-time process failed (exit {self.proc.poll()})"
            raise ChildStartError(why)
        self.infos: dict[str, ServiceInfo] = msg.infos
        self.facts: dict[str, Any] = msg.facts
        self.pid = self.proc.pid
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._pending: dict[int, Future[Answer]] = {}
        self._ids = itertools.count(1)
        self.dead: str | None = None
        self._closing = False
        self._reader = threading.Thread(target=self._read, name="rt-pipe", daemon=True)
        self._reader.start()
        log.info("real-time process pid %d started", self.pid)

    def _kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self._conn.close()
        self.state.close()

    def _read(self) -> None:
        while True:
            try:
                rid, answer = self._conn.recv()
            except (EOFError, OSError):
                break
            with self._lock:
                waiter = self._pending.pop(rid, None)
            if waiter is not None:
                waiter.set_result(answer)
        code = self.proc.wait()
        with self._lock:
            if self.dead is None:
                self.dead = f"the real-time process ended (exit code {code})"
                if not self._closing:
                    log.error("%s: motion refused", self.dead)
            pending, self._pending = self._pending, {}
            gone = ProtocolError(f"robot unavailable: {self.dead}", ErrorCode.BAD_STATE)
        for waiter in pending.values():
            waiter.set_exception(gone)

    @property
    def alive(self) -> bool:
        return self.dead is None

    def check_alive(self) -> None:
        """Raise BAD_STATE when the child is gone."""
        if self.dead is not None:
            raise ProtocolError(f"robot unavailable: {self.dead}", ErrorCode.BAD_STATE)

    def _call(self, request: Request, timeout: float = COMMAND_TIMEOUT_S) -> Any:
        """Send ``request``, wait for its answer; an :class:`Err` raises as ProtocolError."""
        waiter: Future[Answer] = Future()
        with self._lock:
            self.check_alive()
            rid = next(self._ids)
            self._pending[rid] = waiter
        try:
            with self._send_lock:
                self._conn.send((rid, request))
        except OSError:
            pass  # the reader sees the EOF and fails the waiter
        try:
            reply = waiter.result(timeout)  # raises the child's death as BAD_STATE
        except TimeoutError:
            with self._lock:
                self._pending.pop(rid, None)
            raise ProtocolError(
                f"robot unavailable: the real-time process did not answer in {timeout:g} s",
                ErrorCode.BAD_STATE,
            ) from None
        if isinstance(reply, Err):
            try:
                code = ErrorCode(reply.code)
            except ValueError:
                code = ErrorCode.INTERNAL_ERROR
            raise ProtocolError(reply.message, code)
        return reply.value

    def command(
        self, name: str, request: M.Request[Any], session: SessionView
    ) -> tuple[Value, ...]:
        out: tuple[Value, ...] = self._call(Command(name, request, Who.of(session)))
        return out

    def control_lost(self, name: str, why: str = "") -> None:
        self._call(ControlLost(name, why))

    def control_released(self, name: str) -> None:
        self._call(ControlReleased(name))

    def query(self, name: str, *args: Any) -> Any:
        return self._call(Query(name, args))

    def close(self, timeout: float = 10.0) -> None:
        """Stop the child (its loops stop, it logs its tick jitter) and wait for it."""
        self._closing = True
        if self.dead is None:
            try:
                self._call(Close(), timeout=timeout)
            except ProtocolError:
                pass
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout)
        self._conn.close()
        self.state.close()


class ForwardedService(HandlerService):
    """A service of the child, served in this process: every command is forwarded."""

    def __init__(self, child: RealtimeProcess, name: str) -> None:
        super().__init__()
        info = child.infos[name]
        self.child = child
        self.name = name
        self.identity = info.identity
        self.urgent = info.urgent
        self.blocking = info.blocking
        for cid in info.implemented:
            self.register(M.REQUESTS[cid], self._forward)

    def _forward(self, session: SessionView, request: M.Request[Any]) -> tuple[Value, ...]:
        return self.child.command(self.name, request, session)

    def clock(self) -> float:
        return self.child.state.now()

    def on_control_lost(self, session: SessionView) -> None:
        try:
            self.child.control_lost(self.name, session.control_lost or "")
        except ProtocolError as exc:
            log.error("controlled stop not forwarded: %s", exc.message)

    def on_control_released(self, session: SessionView) -> None:
        try:
            self.child.control_released(self.name)
        except ProtocolError as exc:
            log.error("release not forwarded: %s", exc.message)


class RobotProcess(ForwardedService):
    """The robot service of the child: the polls (Herej, Here, RobotStatus, GetTime,
    WaitEndMove) are answered from the shared state, the rest is forwarded."""

    def __init__(self, child: RealtimeProcess, name: str = "robot") -> None:
        super().__init__(child, name)
        self.model = get_model(self.identity.model)
        self.period = float(child.facts.get("period", 0.004))
        self.register(M.HerejRequest, self._herej)
        self.register(M.HereRequest, self._here)
        self.register(M.RobotStatusRequest, self._status)
        self.register(M.WaitEndMoveRequest, self._wait_end_move)

    def error_code(self, exc: Exception) -> ErrorCode | None:
        return error_code(exc) if isinstance(exc, RobotError) else None

    def snapshot(self) -> Snapshot:
        self.child.check_alive()
        return self.child.state.read()

    def _herej(self, session: SessionView, request: M.HerejRequest) -> tuple[Value, ...]:
        return (Joints(list(self.snapshot().measured)),)

    def _here(self, session: SessionView, request: M.HereRequest) -> tuple[Value, ...]:
        q = np.array(self.snapshot().measured)
        here = here_at(self.model, q, request.tool.as_tuple(), request.frame.as_tuple())
        return (Location(*here),)

    def _status(self, session: SessionView, request: M.RobotStatusRequest) -> tuple[Value, ...]:
        s = self.snapshot()
        st = RobotStatus(s.powered, s.estop, s.moving, s.queue, None, self.child.state.now())
        return status_reply(st, s.error_code, s.error_message, session)

    def _wait_end_move(
        self, session: SessionView, request: M.WaitEndMoveRequest
    ) -> tuple[Value, ...]:
        timeout = request.timeout
        if not (0.0 < timeout <= 3600.0):
            raise OutOfRangeError(f"timeout must be in (0, 3600] s, got {timeout}")
        # the child publishes every cycle: look once a cycle until settled (or standing
        # stopped) or the deadline [RS-5.50]
        deadline = self.child.state.now() + timeout
        wake = threading.Event()  # never set: a wait with a timeout, not a short sleep
        while True:
            s = self.snapshot()
            stopped = s.outcome not in (MoveOutcome.MOVING, MoveOutcome.REACHED)
            if s.settled or (stopped and not s.moving):
                try:
                    outcome = MoveOutcome(s.outcome)
                except ValueError:
                    outcome = MoveOutcome.FAILED
                return wait_reply(outcome, s.outcome_reason)
            left = deadline - self.child.state.now()
            if left <= 0.0:
                return wait_reply(MoveOutcome.MOVING, "")
            wake.wait(min(self.period, left))
