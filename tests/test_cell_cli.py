"""python -m cell: serve and demo as a user runs them (real subprocesses), option errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from cell.__main__ import main
from robotsocket.__main__ import main as robot_main
from sensorsocket.__main__ import main as sensor_main
from spec.exitcodes import ExitCode

if TYPE_CHECKING:
    from tests.conftest import BusyPort

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT))


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["--acquisition-ms", "0"], "--acquisition-ms"),
        (["--acquisition-ms", "150"], "--acquisition-ms"),
        (["--network-jitter-ms", "5", "--network-delay-ms", "1"], "--network-jitter-ms"),
    ],
)
def test_option_errors_name_the_option(
    argv: list[str], names: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["serve", "--clock", "sim", "--robot-port", "0", "--sensor-port", "0", *argv])
    err = capsys.readouterr().err
    assert code == 2 and names in err and len(err.strip().splitlines()) == 1


def test_serve_answers_a_robot_and_a_sensor_call_then_stops_on_sigint(
    capsys: pytest.CaptureFixture[str],
) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cell", "serve", "--clock", "sim", "--robot-port", "0",
         "--sensor-port", "0", "--frame-timeout", "1.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        described: dict[str, str] = {}
        while "true_delta_t_ms" not in described:
            line = proc.stdout.readline()
            assert line, "serve ended before describing the cell"
            key, _, value = line.partition(":")
            described[key.strip()] = value.strip()
        robot, sensor = described["robot"], described["sensor"]
        assert float(described["true_delta_t_ms"]) == pytest.approx(4.9)
        # The clients in-process (the same main() each module runs): no interpreter start-ups.
        for client_main, endpoint, command in (
            (robot_main, robot, "Herej"),
            (sensor_main, sensor, "GetSettings"),
        ):
            code = client_main(["call", endpoint, command])
            out, err = capsys.readouterr()
            assert code == 0, err
            assert isinstance(json.loads(out), dict)
            # both servers announce the --frame-timeout they apply
            assert client_main(["call", endpoint, "Hello", "1", "2", "test"]) == 0
            assert json.loads(capsys.readouterr().out)["frame_timeout"] == 1.5
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        # issue 35: the stop printed nothing and exited 0; now one line and 130, as every tool
        assert proc.returncode == ExitCode.INTERRUPTED, err
        assert err.splitlines() == [
            "python -m cell: interrupted: the emulated cell stopped (robot, sensor), its servers "
            "closed"
        ]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


@pytest.mark.slow
def test_demo_runs_end_to_end(tmp_path: Path) -> None:
    """What `make demo` shows: the robot tour, a sensor frame, ΔT through the sockets."""
    out = subprocess.run(
        [sys.executable, "-m", "cell", "demo", "--out", str(tmp_path), "--duration", "1",
         "--no-conformance"],
        capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=300,
    )  # fmt: skip
    text = out.stdout
    # A real-clock run on a busy machine may be untrusted: then the demo says so and why
    # (exit 4, UNTRUSTED), it never prints a plausible wrong ΔT as if it were fine.
    assert out.returncode in (ExitCode.OK, ExitCode.UNTRUSTED), out.stderr[-2000:]
    assert ("verdict: UNTRUSTED" in text) == (out.returncode == ExitCode.UNTRUSTED), text
    assert "EnablePower, Herej()" in text and "ΔT measured (ms)" in text and "verdict:" in text
    assert any(p.suffix == ".pgm" for p in tmp_path.iterdir())


@pytest.mark.parametrize(
    ("taken", "extra"),
    [("--robot-port", []), ("--sensor-port", ["--in-process"]), ("--udp-port", [])],
)
def test_a_port_in_use_is_named_with_its_option(
    taken: str, extra: list[str], busy_port: BusyPort
) -> None:
    port = busy_port(taken == "--udp-port")
    ports = {"--robot-port": "0", "--sensor-port": "0", "--udp-port": "0", taken: str(port)}
    done = subprocess.run(
        [sys.executable, "-m", "cell", "serve", *extra,
         *(x for option, value in ports.items() for x in (option, value))],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines()[-1].startswith("python -m cell: error: cannot bind the ")
    assert f"to 127.0.0.1:{port} ({taken}): Address already in use" in done.stderr


@pytest.mark.parametrize("taken", ["--robot-port", "--sensor-port"])
def test_a_tcp_port_in_use_is_the_only_line_even_verbose(taken: str, busy_port: BusyPort) -> None:
    port = busy_port(False)
    ports = {"--robot-port": "0", "--sensor-port": "0", "--udp-port": "0", taken: str(port)}
    done = subprocess.run(
        [sys.executable, "-m", "cell", "serve", "--verbose",
         *(x for option, value in ports.items() for x in (option, value))],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    # Both ports are bound before the real-time child starts: no start-up log before this.
    what = "robot" if taken == "--robot-port" else "sensor"
    assert done.stderr.splitlines() == [
        f"python -m cell: error: cannot bind the {what}'s TCP port to 127.0.0.1:{port}"
        f" ({taken}): Address already in use"
    ]
    assert "Traceback" not in done.stderr


def test_demo_out_that_is_a_file_is_refused_before_the_tour(tmp_path: Path) -> None:
    taken = tmp_path / "out"
    taken.write_text("a file")
    done = subprocess.run(
        [sys.executable, "-m", "cell", "demo", "--out", str(taken)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stdout == ""  # before: half the tour, then "[Errno 17] File exists"
    assert done.stderr.splitlines() == [
        f"python -m cell demo: error: argument --out: {taken} exists and is not a directory"
    ]


def test_a_host_that_is_not_this_machines_names_host() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "cell", "serve", "--host", "no-such-host.invalid",
         "--robot-port", "0", "--sensor-port", "0", "--udp-port", "0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    # before: "... the sensor's UDP trigger port ... (--udp-port): Name or service not known"
    last = done.stderr.splitlines()[-1]
    assert last.startswith(
        "python -m cell: error: cannot listen on no-such-host.invalid (--host): "
    )


def test_ctrl_c_in_the_demo_is_one_line_and_exit_130(tmp_path: Path) -> None:
    # As from a terminal: SIGINT raises KeyboardInterrupt (a test worker may ignore SIGINT).
    start = (
        "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler);"
        " runpy.run_module('cell', run_name='__main__', alter_sys=True)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", start, "demo", "--out", str(tmp_path), "--no-conformance"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith("2/4"):  # the tour is under way
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert err.splitlines()[-1:] == ["python -m cell: interrupted"] and "Traceback" not in err
