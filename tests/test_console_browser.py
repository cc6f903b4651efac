"""The console in a real browser: Debian's chromium driven by Playwright against
``python -m welding console --emulate`` run as a subprocess. One operator session, step by
step: status updates, take control and power on (with confirmation), jog moves the arm,
E-stop stops it, a job is edited, saved and dry-run, the arm moves to a named location, a
teaching run shows its points, a calibration its result, a ΔT measurement Figs. 6 and 7,
a tracked weld its error.
Screenshots of each page go to the test's temporary folder; with CONSOLE_SCREENSHOTS=1 they
replace docs/console/*.png (the README's pictures), so a plain `make test` leaves the checkout
clean."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from welding import job as J

CHROMIUM = "/usr/bin/chromium"
if not os.path.exists(CHROMIUM):
    pytest.skip(
        f"BROWSER TESTS SKIPPED: {CHROMIUM} not installed (apt-get install chromium)",
        allow_module_level=True,
    )
pytest.importorskip("playwright", reason="the console extra is not installed")
pytest.importorskip("starlette", reason="the console extra is not installed")

from playwright.sync_api import Page, Route, WebSocket, expect, sync_playwright  # noqa: E402

#: expect()'s own default is 5 s, apart from the page's: a loaded CI machine (the clean
#: clone's make test) once took longer than that to serve the console after sign-in
expect.set_options(timeout=15_000)

DOCS_SHOTS = Path(__file__).resolve().parent.parent / "docs" / "console"
VIEWER_PASSWORD = "vera-sees-only-4711"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


@pytest.fixture
def console(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """The console on an emulated cell, as an operator starts it; (url, jobs folder)."""
    jobs = tmp_path / "jobs"
    # The console's log (verbose: every jog start and stop) goes to a file, printed after the
    # test: pytest shows it when the test failed, which says what the server saw.
    log_path = tmp_path / "console.log"
    log_file = log_path.open("w")
    users = tmp_path / "users.json"  # a viewer account besides the sign-in URL's operator
    subprocess.run(
        [sys.executable, "-m", "welding", "console", "adduser", str(users), "vera", "--role",
         "viewer", "--password-stdin"],
        input=f"{VIEWER_PASSWORD}\n", text=True, check=True, capture_output=True,
    )  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "welding", "-v", "console", "--emulate", "--port", "0",
         "--tools", str(tmp_path / "tools.json"), "--jobs", str(jobs), "--users", str(users)],
        stdout=log_file, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while not (
            url := re.search(r"console: (http://\S+/signin\?token=\S+)", log_path.read_text())
        ):
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"the console did not start: {log_path.read_text()}")
            time.sleep(0.1)
        # the banner names the emulated cell's servers, for other tools to use beside it
        banner = r"emulated cell: robot [\d.]+:\d+, sensor [\d.]+:\d+"
        assert re.search(banner, log_path.read_text())
        _LOGS[url[1]] = log_path
        yield url[1], jobs
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log_file.close()
        print("--- the console's log ---\n" + log_path.read_text(errors="replace"))


_LOGS: dict[str, Path] = {}


def _joints(page: Page) -> list[float]:
    status: dict[str, Any] = page.evaluate("fetch('/api/status').then(r => r.json())")
    return [float(q) for q in status["joints"]]


def _api(page: Page, path: str) -> Any:
    return page.evaluate(f"fetch('/api/{path}').then(r => r.json())")


def _print_console_errors(page: Page) -> None:
    """Print every error message the console sends on the status WebSocket (shown by pytest
    when the test fails: e.g. why a jog was refused)."""

    def watch(ws: WebSocket) -> None:
        ws.on("framereceived", lambda payload: _print_if_error(str(payload)))

    page.on("websocket", watch)


def _print_if_error(payload: str) -> None:
    if re.match(r'\{"type":\s*"error"', payload):
        print("console error message:", payload)


def _missing(page: Page) -> list[str]:
    """Every resource of the console's origin that answered 404 (the favicon was one)."""
    seen: list[str] = []
    page.on("response", lambda r: seen.append(r.url) if r.status == 404 else None)
    return seen


def _chart(page: Page, canvas: str) -> Any:
    """What the chart library drew on ``canvas``: legend texts, point counts per series and
    tick labels per axis (None when no chart is there)."""
    return page.evaluate(
        """(id) => {
            const c = window.Chart && Chart.getChart(id);
            if (!c) return null;
            return {
                legend: c.legend.legendItems.map((i) => i.text),
                points: c.data.datasets.map((d) => d.data.length),
                xticks: c.scales.x.ticks.map((t) => t.label),
                yticks: c.scales.y.ticks.map((t) => t.label),
                xtitle: c.options.scales.x.title.text,
                ytitle: c.options.scales.y.title.text,
            };
        }""",
        canvas,
    )


def _drawn(page: Page, canvas: str, legend: list[str]) -> Any:
    """The chart on ``canvas`` has this legend, data in every series and axes with ticks."""
    page.wait_for_function("(id) => window.Chart && Chart.getChart(id)", arg=canvas)
    c = _chart(page, canvas)
    assert c["legend"] == legend, c["legend"]
    assert all(n > 0 for n in c["points"]), c
    assert len(c["xticks"]) >= 3 and len(c["yticks"]) >= 3, c
    assert "(" in c["xtitle"] and "(" in c["ytitle"], c  # the axis titles carry their units
    return c


def _confirm(page: Page, text: str = "") -> None:
    """Accept the confirmation dialog, after checking it names ``text``."""
    if text:
        expect(page.locator("#confirm-text")).to_have_text(text)
    page.locator("#confirm-yes").click()


_shots_dir: Path | None = None


@pytest.fixture(autouse=True)
def _screenshot_folder(tmp_path: Path) -> Iterator[None]:
    global _shots_dir
    _shots_dir = DOCS_SHOTS if os.environ.get("CONSOLE_SCREENSHOTS") == "1" else tmp_path
    yield
    _shots_dir = None


def _shot(page: Page, name: str) -> None:
    assert _shots_dir is not None
    _shots_dir.mkdir(parents=True, exist_ok=True)
    path = _shots_dir / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    assert path.stat().st_size > 1000, f"screenshot {name} is empty"


@pytest.mark.slow  # about 25 s: a whole operator session in the browser
def test_operator_session_in_chromium(console: tuple[str, Path], tmp_path: Path) -> None:
    url, jobs = console
    with sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            str(tmp_path / "profile"),  # a fresh profile
            executable_path=CHROMIUM,
            headless=True,
            args=ARGS,
            viewport={"width": 1280, "height": 900},
        )
        try:
            page = ctx.new_page()
            page.set_default_timeout(15_000)
            _print_console_errors(page)
            missing = _missing(page)
            # the sign-in page, before the URL is used
            page.goto(url.split("/signin")[0] + "/signin")
            expect(page.locator("input[type=password]")).to_be_visible()
            _shot(page, "signin")
            # the printed one-time sign-in URL signs the operator in and opens the console
            page.goto(url + "#status")
            expect(page.locator("#user")).to_have_text("token (operator)")

            # status streams in (the robot clock advances on the page)
            expect(page.locator("#link")).to_have_text("connected")
            expect(page.locator("#st-time")).to_have_text(re.compile(r"\d+\.\d+ s"))
            t0 = page.locator("#st-time").inner_text()
            expect(page.locator("#st-time")).not_to_have_text(t0)
            expect(page.locator("#st-rate")).to_have_text(re.compile(r"(1\d|2\d) /s"))

            # laser, gas and crossjet are shown, as `welding status` shows them
            expect(page.locator("#st-outputs")).to_have_text("laser off, gas off, crossjet off")
            # nothing that moves can be pressed before control: each button says why
            jog = page.locator("#jog-j1-plus")
            for button in ("#power-on", "#move-go", "#estop-reset"):
                expect(page.locator(button)).to_be_disabled()
            expect(page.locator("#power-on")).to_have_attribute("title", "take control first")
            expect(jog).to_be_disabled()
            expect(page.locator("#estop")).to_be_enabled()
            # the jog starts slow: 2 %, not the 10 % that turned J1 55 degrees in 1.5 s
            expect(page.locator("#jog-speed")).to_have_value("2")

            # control, then power on after a confirmation
            page.locator("#take").click()
            expect(page.locator("#st-owner")).to_have_text("this console (token)")
            expect(page.locator("#message")).to_have_text("control taken")
            expect(page.locator("#take")).to_be_disabled()
            expect(jog).to_have_attribute("title", "switch arm power on first")
            page.locator("#power-on").click()
            expect(page.locator("#confirm")).to_be_visible()
            _confirm(page)
            expect(page.locator("#st-power")).to_have_text("on")
            expect(page.locator("#message")).to_have_text("power on")
            expect(jog).to_be_enabled()
            expect(page.locator("#power-on")).to_be_disabled()

            # a step jog: one click, one step of exactly 1 degree, no hold
            page.locator("#jog-step").select_option("1")
            before = _joints(page)[0]
            jog.click()
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^moving"))
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^still"))
            assert abs(_joints(page)[0] - before - 1.0) < 0.01
            page.locator("#jog-step").select_option("")

            # jog: the arm moves while the button is held and stops on release
            before = _joints(page)[0]
            page.locator("#jog-j1-plus").hover()
            page.mouse.down()
            expect(page.locator("#st-motion")).to_contain_text("jogging")
            page.wait_for_timeout(800)
            page.mouse.up()
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^still"))
            assert _joints(page)[0] - before > 0.5
            _shot(page, "status")

            # E-stop while a jog is held
            page.locator("#jog-j1-minus").hover()
            page.mouse.down()
            expect(page.locator("#st-motion")).to_contain_text("jogging")
            page.evaluate("document.getElementById('estop').click()")
            expect(page.locator("#st-estop")).to_have_text("ENGAGED")
            expect(page.locator("#message")).to_have_text("EMERGENCY STOP sent")
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^still"))
            page.mouse.up()
            expect(jog).to_be_disabled()  # engaged: no jog until reset and power on
            page.locator("#estop-reset").click()
            _confirm(page)
            expect(page.locator("#st-estop")).to_have_text("clear")
            # the E-stop's banner went with the E-stop (it stayed after the reset)
            expect(page.locator("#message")).not_to_contain_text("EMERGENCY STOP")
            page.locator("#power-on").click()
            _confirm(page)
            expect(page.locator("#st-power")).to_have_text("on")

            # a long error, an unreachable robot or a long message does not move the jog
            # buttons (a held pointer would leave its button: the jog would stop)
            tops = page.evaluate(
                """() => {
                    const top = () => $("jog-j1-plus").getBoundingClientRect().top;
                    const before = top();
                    showStatus({ ...status, last_error: 7, last_message: "long ".repeat(80) });
                    const error = top();
                    showStatus({ ...status, connected: false, error: "gone ".repeat(80) });
                    const unreachable = top();
                    say("a long message ".repeat(40), "error");
                    return [before, error, unreachable, top()];
                }"""
            )
            assert tops[0] == tops[1] == tops[2] == tops[3], tops

            # the link drops: the jog buttons say so (instead of doing nothing), and the page
            # reconnects
            page.evaluate("ws.close()")
            expect(jog).to_have_attribute("title", re.compile("the link to the console is down"))
            expect(page.locator("#link")).to_have_text("connected")
            expect(jog).to_be_enabled()
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^still"))

            # jobs: edit the seam's velocity, validate, save, dry run with progress
            page.locator("nav a[data-page=jobs]").click()
            expect(page.locator("#job-file")).to_have_text("demo.xml")
            # where each item goes, as the job file says (demo_job's points)
            where = page.locator("#job-items td.where")
            expect(where.nth(0)).to_have_text("(-40.0, 0.0, 30.0) mm, laser in workpiece")
            expect(where.nth(1)).to_have_text(
                "(-40.0, 0.0, 0.0) mm, laser in workpiece → (0.0, 0.0, 0.0) mm; 1 segment"
            )
            page.locator("input[data-i='1'][data-k='velocity']").fill("30")
            page.locator("input[data-i='1'][data-k='velocity']").dispatch_event("change")
            page.locator("#job-check").click()
            expect(page.locator("#job-problems")).to_contain_text("ok, job 'demo'")
            page.locator("#job-save").click()
            expect(page.locator("#message")).to_have_text("demo.xml saved")
            seam = J.load(jobs / "demo.xml").item("seam")
            assert isinstance(seam, J.Path) and seam.velocity == 30.0
            page.locator("#job-dry").click()
            _confirm(page)
            expect(page.locator("tr.current")).to_have_count(1)
            expect(page.locator("#job-dry")).to_be_disabled()  # one job at a time
            _shot(page, "jobs")
            expect(page.locator("#job-progress")).to_have_attribute("data-state", "done")
            # said once ("done done" before), and the start's banner replaced by the end
            expect(page.locator("#job-progress")).to_have_text("dry run demo.xml: done")
            expect(page.locator("#message")).to_have_text("dry run demo.xml: done")

            # move to a named location: the stitch, where the sensor sees the seam
            page.locator("nav a[data-page=status]").click()
            # the job's locations arrive only after the operator picked one (as on a busy
            # PC): refilling the list must keep "spot", not fall back to the first entry
            held: list[Route] = []

            def hold(route: Route) -> None:
                held.append(route)

            page.route("**/api/jobs/demo.xml", hold)
            expect(page.locator("#move-name option")).to_have_count(4)
            page.locator("#move-job").select_option("demo.xml")
            page.locator("#move-name").select_option("spot")
            page.wait_for_function("document.querySelector('#move-name option') !== null")
            page.evaluate("document.querySelectorAll('#move-name option')[0].dataset.old = '1'")
            for _ in range(500):
                if held:
                    break
                page.wait_for_timeout(10)
            for route in held:
                route.continue_()
            page.unroute("**/api/jobs/demo.xml")
            expect(page.locator("#move-name option[data-old]")).to_have_count(0)  # refilled
            expect(page.locator("#move-name")).to_have_value("spot")
            page.locator("#move-go").click()
            _confirm(page, "Move the arm to spot?")
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^moving"))
            expect(page.locator("#st-motion")).to_have_text(re.compile(r"^still"))

            # sensor view: the live stripe image and profile
            page.locator("nav a[data-page=sensor]").click()
            expect(page.locator("#sensor-index")).to_have_text(re.compile(r"#\d+"))
            _drawn(page, "sensor-profile", ["stripe profile", "seam point (GetData)"])
            # frames keep coming (the screenshot then shows the rate, not the first frame's)
            expect(page.locator("#sensor-rate")).to_have_text(re.compile(r"[1-9]\d*\.\d frames/s"))
            try:
                expect(page.locator("#sensor-seam")).to_contain_text("seam (S frame)")
            except AssertionError as exc:  # seen once under a full run's load: say where
                raise AssertionError(
                    f"{exc}\nstatus {_api(page, 'status')}\nsensor {_api(page, 'sensor/settings')}"
                ) from None
            _shot(page, "sensor")

            # teaching: points appear in the top view
            page.locator("nav a[data-page=teach]").click()
            page.locator("#teach-length").fill("20")
            page.locator("#teach-start").click()
            _confirm(page)
            expect(page.locator("#teach-info")).to_have_attribute("data-state", "done")
            assert int(page.locator("#teach-info").get_attribute("data-count") or 0) >= 3
            _drawn(page, "teach-plot", ["taught seam points"])
            _shot(page, "teach")

            # sensor tool calibration from where teaching ended (over the straight seam). A
            # short run on the real-time cell may be refused as too uncertain: the page must
            # then say why; a result can be saved into the tool database.
            page.locator("nav a[data-page=calibration]").click()
            page.locator("#cal-poses").fill("10")
            page.locator("#cal-repeats").fill("4")
            page.locator("#cal-start").click()
            _confirm(page)
            expect(page.locator("#cal-info")).to_have_attribute(
                "data-state", re.compile("done|failed"), timeout=30_000
            )
            # the start's banner is gone with the run: its end replaced it
            expect(page.locator("#message")).to_contain_text("sensor tool calibration: ")
            if page.locator("#cal-info").get_attribute("data-state") == "done":
                expect(page.locator("#cal-result")).to_contain_text("± 1σ")
                page.locator("#cal-save").click()
                expect(page.locator("#message")).to_have_text(
                    "sensor_cal saved in the tool database"
                )
            else:
                expect(page.locator("#cal-info")).to_contain_text("is uncertain by")
                expect(page.locator("#cal-save")).to_be_disabled()  # nothing to save
            # the laser tool, with the emulated spot detector: 20 poses x 4 pass
            page.locator("#cal-which").select_option("laser-tool")
            expect(page.locator("#cal-tool")).to_have_value("laser")
            page.locator("#cal-poses").fill("20")
            page.locator("#cal-start").click()
            _confirm(page)
            expect(page.locator("#cal-info")).to_have_attribute(
                "data-state", "done", timeout=60_000
            )
            expect(page.locator("#message")).to_contain_text("laser tool calibration: done")
            # one unit per column in every row, residuals in µm
            expect(page.locator("#cal-result")).to_contain_text("x (mm)")
            expect(page.locator("#cal-result")).to_contain_text("rx (°)")
            expect(page.locator("#cal-result")).to_contain_text(re.compile(r"rms \d+\.\d µm"))
            _drawn(page, "cal-plot", ["residual per pose"])
            _shot(page, "calibration")
            page.locator("#cal-save").click()
            expect(page.locator("#message")).to_have_text("laser_cal saved in the tool database")

            # ΔT (section VI) from where teaching ended, the seam in view: Figs. 6 and 7
            page.locator("nav a[data-page=deltat]").click()
            page.locator("#dt-duration").fill("3")
            page.locator("#dt-start").click()
            _confirm(page)
            expect(page.locator("#dt-info")).to_have_attribute("data-state", "done", timeout=30_000)
            expect(page.locator("#dt-result")).to_contain_text(re.compile(r"ΔT\s*\d+\.\d+ ms"))
            _drawn(page, "dt-fig6", ["robot yᴿ (from the joint log)",
                                     "sensor yˢ (seam points, at trigger time)"])  # fmt: skip
            shown = re.search(r"ΔT\s*(\d+\.\d+) ms", page.locator("#dt-result").inner_text())
            assert shown
            fig7 = _drawn(page, "dt-fig7", ["MSE(ΔT)", f"minimum: ΔT = {shown[1]} ms"])
            assert fig7["points"][1] == 2
            _shot(page, "deltat")

            # a tracked weld on the emulated cell: its tracking error plotted
            page.locator("nav a[data-page=track]").click()
            page.locator("#tr-start").click()
            expect(page.locator("#tr-info")).to_have_attribute("data-state", "done", timeout=60_000)
            expect(page.locator("#tr-result")).to_contain_text("tracking error")
            # on the real clock in its own real-time child, with the verdict a real cell has
            expect(page.locator("#tr-result")).to_contain_text("real (real-time child)")
            expect(page.locator("#tr-result")).to_contain_text("WITHIN TOLERANCE 0.1 mm")
            # the measured points drawn last, over the lines
            _drawn(page, "tr-top", ["true seam", "nominal path (untracked)", "laser",
                                    "measured seam points"])  # fmt: skip
            _drawn(page, "tr-error", ["laser − seam, lateral"])
            _shot(page, "track")

            # ILC on the elastic arm: the error falls from trial to trial, plotted as it comes
            page.locator("nav a[data-page=ilc]").click()
            page.locator("#ilc-length").fill("40")
            page.locator("#ilc-trials").fill("3")
            page.locator("#ilc-start").click()
            expect(page.locator("#ilc-info")).to_have_attribute(
                "data-state", "done", timeout=90_000
            )
            expect(page.locator("#ilc-result")).to_contain_text("trial 3")
            conv = _drawn(page, "ilc-conv", ["max error", "rms error"])
            assert conv["points"] == [3, 3]
            _drawn(page, "ilc-profiles", ["trial 1", "trial 2", "trial 3"])
            ilc_text = page.locator("#ilc-result").inner_text()
            maxes = [float(m) for m in re.findall(r"trial \d\s+max (\d+\.\d) µm", ilc_text)]
            assert len(maxes) == 3 and maxes[0] > maxes[1] > maxes[2], maxes
            _shot(page, "ilc")

            # tools and frames: add one through the table, a bad one is refused
            page.locator("nav a[data-page=tools]").click()
            page.locator("#new-name").fill("torch2")
            page.locator("#new-kind").select_option("laser")
            page.locator("#new-loc").fill("0, 0, 150, 0, 0, 0")
            page.locator("#new-add").click()
            expect(page.locator("tr[data-name=torch2]")).to_have_count(1)
            page.locator("#new-name").fill("torch3")
            page.locator("#new-loc").fill("0, 0, 150")
            page.locator("#new-add").click()
            expect(page.locator("#message")).to_contain_text("expected 6 numbers")

            # a calibrated tool's row saved unedited keeps its full precision (the fields
            # show it rounded)
            def laser_cal() -> list[float]:
                tools = _api(page, "tools")["entries"]
                return next(e["location"] for e in tools if e["name"] == "laser_cal")

            calibrated = laser_cal()
            assert any(round(v, 3) != v for v in calibrated), calibrated
            page.locator("tr[data-name=laser_cal] button.save").click()
            expect(page.locator("#message")).to_have_text("laser_cal saved")
            assert laser_cal() == calibrated
            # locations in their units at 1 µm / 0.001 deg, in full (not cut off)
            laser = page.locator("tr[data-name=laser_cal] input.coord")
            expect(laser).to_have_count(6)
            for i in range(6):
                value = laser.nth(i).input_value()
                assert re.fullmatch(r"-?\d+\.\d{3}", value), value
                assert laser.nth(i).evaluate("e => e.scrollWidth <= e.clientWidth")
            _shot(page, "tools")

            page.locator("nav a[data-page=audit]").click()
            expect(page.locator("#audit-table")).to_contain_text("jog start")
            _shot(page, "audit")
            assert missing == [], missing  # nothing the page loads is a 404 (the favicon was)

            # a viewer (signed in last: the browser keeps one session cookie per console)
            # sees the same page with every button that acts disabled, the E-stop not
            page.goto(url.split("/signin")[0] + "/signin")
            page.locator("#signin-name").fill("vera")
            page.locator("#signin-password").fill(VIEWER_PASSWORD)
            page.locator("#signin-go").click()
            expect(page.locator("#user")).to_have_text("vera (viewer)")
            expect(page.locator("#link")).to_have_text("connected")
            page.locator("nav a[data-page=status]").click()
            for button in ("#take", "#release", "#power-off", "#jog-j1-plus", "#move-go"):
                expect(page.locator(button)).to_be_disabled()
                expect(page.locator(button)).to_have_attribute(
                    "title", "operators only: vera is a viewer"
                )
            expect(page.locator("#estop")).to_be_enabled()
        finally:
            ctx.close()


EVIL_PAGE = """<!doctype html><title>evil</title><script>
const target = "TARGET";
const routes = ["/api/control", "/api/power", "/api/estop/reset", "/api/move", "/api/tools",
  "/api/jobs/demo.xml/run", "/api/teach", "/api/delta-t", "/api/calibrate", "/api/track",
  "/api/ilc", "/api/sensor/settings", "/api/abort"];
const bodies = { "/api/control": {take: true}, "/api/power": {on: true},
  "/api/jobs/demo.xml/run": {dry_run: false} };
window.done = (async () => {
  for (const r of routes) {
    await fetch(target + r, { method: "POST", mode: "no-cors", credentials: "include",
      body: JSON.stringify(bodies[r] || {}) }).catch(() => {});
  }
  const f = document.createElement("form");
  f.method = "POST"; f.action = target + "/api/control"; f.target = "sink";
  f.enctype = "text/plain";
  const i = document.createElement("input"); i.name = '{"take":true,"x":"'; i.value = '"}';
  f.appendChild(i); document.body.appendChild(f);
  // the form's answer loads into the sink frame: wait for that load, not for a time (a
  // cross-origin document's location throws; the initial about:blank does not count)
  const sink = document.querySelector("iframe[name=sink]");
  const posted = new Promise((res) => {
    sink.onload = () => {
      try { if (sink.contentWindow.location.href === "about:blank") return; } catch (e) {}
      res("answered");
    };
    setTimeout(() => res("no answer to the form POST in 15 s"), 15000);
  });
  f.submit();
  await new Promise((res) => {
    const ws = new WebSocket(target.replace("http", "ws") + "/ws");
    ws.onopen = () => {
      ws.send(JSON.stringify({ type: "jog", mode: "joint", axis: 1, direction: 1, speed: 100 }));
      const t = setInterval(() => ws.send(JSON.stringify({ type: "hold" })), 100);
      setTimeout(() => { clearInterval(t); res("opened"); }, 2000);
    };
    ws.onerror = ws.onclose = () => res("refused");
  }).then((v) => { window.wsResult = v; });
  const form = await posted;
  return form === "answered" ? "done" : form;
})();
</script><iframe name="sink"></iframe>"""


@pytest.mark.slow  # about 20 s
def test_a_page_of_another_origin_cannot_drive_the_robot(
    console: tuple[str, Path], tmp_path: Path
) -> None:
    """Issue 28: the operator is signed in; a page from another origin (python3 -m
    http.server on another port) sends no-cors fetches to every state-changing route, a form
    POST and a WebSocket jog with its own holds. The robot's control holder, power, joints
    and outputs stay as they were, the console logs the refusals, and the operator's own
    page still works."""
    from robotsocket.client import RobotClient

    url, _ = console
    log_path = _LOGS[url]
    robot = re.search(r"emulated cell: robot ([\d.]+):(\d+)", log_path.read_text())
    assert robot
    base = url.split("/signin")[0]
    site = tmp_path / "evil"
    site.mkdir()
    (site / "index.html").write_text(EVIL_PAGE.replace("TARGET", base))
    evil = subprocess.Popen(
        [sys.executable, "-m", "http.server", "0", "--bind", "127.0.0.1", "-d", str(site)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert evil.stdout is not None
        line = evil.stdout.readline()
        evil_port = re.search(r"port (\d+)", line)
        assert evil_port, line
        with (
            RobotClient(robot[1], int(robot[2]), timeout=10, client_name="observer") as obs,
            sync_playwright() as pw,
        ):
            ctx = pw.chromium.launch_persistent_context(
                str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True, args=ARGS
            )
            try:
                page = ctx.new_page()
                page.set_default_timeout(15_000)
                page.goto(url + "#status")
                expect(page.locator("#user")).to_have_text("token (operator)")
                expect(page.locator("#link")).to_have_text("connected")
                outputs = obs.list_io()[0]

                def robot_state() -> Any:
                    st = obs.status()
                    return (st.controlled, st.powered, [round(float(q), 3) for q in obs.herej()],
                            {o: obs.read_io(o) for o in outputs})  # fmt: skip

                before = robot_state()
                attacker = ctx.new_page()  # same browser, the operator's cookie in its jar
                attacker.goto(f"http://127.0.0.1:{evil_port[1]}/index.html")
                assert attacker.evaluate("window.done") == "done"
                assert attacker.evaluate("window.wsResult") == "refused"
                assert robot_state() == before
                assert not before[0] and not before[1]
                text = log_path.read_text()
                assert text.count("cross-origin request from http://127.0.0.1:") >= 13, text
                assert "refused WebSocket /ws" in text
                # the operator's own page still does everything after signing in
                page.locator("#take").click()
                expect(page.locator("#st-owner")).to_have_text("this console (token)")
                assert obs.status().controlled
                page.locator("#release").click()
                expect(page.locator("#st-owner")).to_have_text("nobody")
            finally:
                ctx.close()
    finally:
        evil.terminate()
        evil.wait(10)
