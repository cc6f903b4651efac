// The 24-Laser console page: status over one WebSocket, actions as JSON requests.
"use strict";

const $ = (id) => document.getElementById(id);
const AXES = ["x", "y", "z", "rx", "ry", "rz"];
let ws = null;
let status = {};
let updates = [];
let selection = { tool: "flange", frame: "world" };
let job = null; // the open job (JSON), edited in place
let jobFile = "";

// Text from the robot, the database or a job file goes into the page as text, never as HTML.
const esc = (v) => String(v).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);

// The banner says what the operator's last action did, and goes when that is no longer
// true: ``until(status)`` tells whether it still holds (e.g. "EMERGENCY STOP sent" while the
// E-stop is engaged). It may not hold yet when said (the status comes 20 times a second), so
// it is dropped once it has held and then stops, or if it never held within 3 s. Without
// ``until`` it holds while the robot's state (E-stop, power, control, activity) is the one
// it was said in.
let banner = null;
function stateKey(s) {
  const a = s.activity;
  return [s.connected, s.estop, s.powered, s.owner, s.controller, a && `${a.kind} ${a.state}`].join("|");
}
function say(text, kind = "info", until = null) {
  const m = $("message");
  m.textContent = m.title = text;
  m.className = kind;
  const key = stateKey(status);
  banner = { until: until || ((s) => stateKey(s) === key), bound: Boolean(until), held: false, since: performance.now() };
}
function clearBanner() {
  banner = null;
  $("message").textContent = $("message").title = "";
  $("message").className = "";
}
function clearStaleBanner(s) {
  if (!banner) return;
  if (banner.until(s)) banner.held = true;
  else if (banner.held || performance.now() - banner.since > 3000) clearBanner();
}

// --- the one way to the console: every request and the WebSocket go through here ----------

let session = null; // { user, role, csrf, controller }: who is signed in (GET /api/session)

// Every state-changing request is JSON with the session's CSRF token (the console refuses
// anything else); a 401 (not signed in, or the session expired) goes to the sign-in page.
async function request(method, path, body) {
  const opts = { method, headers: {} };
  if (method !== "GET" && method !== "HEAD") {
    if (!session) await loadSession();
    opts.body = JSON.stringify(body === undefined ? {} : body);
    opts.headers["Content-Type"] = "application/json";
    opts.headers["X-CSRF-Token"] = session.csrf;
  }
  const r = await fetch(path, opts);
  if (r.status === 401) {
    location.href = "/signin";
    throw new Error("sign in first");
  }
  return r;
}

async function loadSession() {
  const r = await fetch("/api/session");
  if (r.status === 401) {
    location.href = "/signin";
    throw new Error("sign in first");
  }
  const first = session === null;
  session = await r.json();
  $("user").textContent = `${session.user} (${session.role})`;
  document.body.dataset.role = session.role;
  $("nav-audit").hidden = session.role !== "operator";
  if (first) $("jog-speed").value = session.jog.speed; // the console's starting jog speed
  updateControls();
}

function openSocket() {
  return new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
}

async function signOut() {
  await request("POST", "/api/signout");
  location.href = "/signin";
}

async function api(method, path, body) {
  const r = await request(method, path, body);
  const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
  if (!r.ok) {
    say(data.error || `HTTP ${r.status}`, "error");
    throw new Error(data.error);
  }
  return data;
}

function confirmAction(text) {
  return new Promise((resolve) => {
    const d = $("confirm");
    $("confirm-text").textContent = text;
    d.onclose = () => resolve(d.returnValue === "ok");
    d.returnValue = "";
    d.showModal();
  });
}

// --- pages ---------------------------------------------------------------------------------

function showPage() {
  const page = (location.hash || "#status").slice(1);
  if (banner && !banner.bound) clearBanner(); // it was about the page the operator left
  document.querySelectorAll(".page").forEach((p) => p.classList.toggle("active", p.id === `page-${page}`));
  document.querySelectorAll("nav a").forEach((a) => a.classList.toggle("active", a.dataset.page === page));
  if (page === "tools") loadTools();
  if (page === "jobs") loadJobs();
  if (page === "sensor") loadSettings();
  if (page === "deltat") loadDeltaT().catch(() => {});
  if (page === "calibration") loadCalibration().catch(() => {});
  if (page === "track") loadTrack().catch(() => {});
  if (page === "ilc") loadIlc().catch(() => {});
  if (page === "audit") loadAudit().catch(() => {});
}
window.addEventListener("hashchange", showPage);

// --- status --------------------------------------------------------------------------------

function connect() {
  ws = openSocket();
  ws.onopen = () => {
    $("link").textContent = "connected";
    $("link").className = "pill ok";
    ws.send(JSON.stringify({ type: "select", ...selection }));
  };
  ws.onclose = () => {
    $("link").textContent = "disconnected";
    $("link").className = "pill bad";
    releaseJog();
    updateControls();
    loadSession().catch(() => {}); // a refused handshake (session ended): to the sign-in page
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.type === "status") showStatus(msg);
    else if (msg.type === "error") say(msg.message, "error");
  };
}

function onoff(v, on, off, bad) {
  return `<span class="${v === bad ? "bad" : "good"}">${v ? on : off}</span>`;
}

function showStatus(s) {
  status = s;
  const now = performance.now();
  updates.push(now);
  while (updates.length && updates[0] < now - 1000) updates.shift();
  $("st-rate").textContent = `${updates.length} /s`;
  updateControls();
  clearStaleBanner(s);
  if (!s.connected) {
    $("st-estop").textContent = $("st-estop").title = "robot unreachable: " + (s.error || "");
    return;
  }
  $("st-estop").title = "";
  $("st-estop").innerHTML = s.estop ? '<span class="bad">ENGAGED</span>' : '<span class="good">clear</span>';
  $("st-power").innerHTML = onoff(s.powered, "on", "off", false);
  $("st-motion").textContent = (s.moving ? "moving" : "still") + ` (queue ${s.queue})` + (s.jogging ? ", jogging" : "");
  const owners = { console: "this console", other: "another client", nobody: "nobody", lost: "LOST (lease ran out)" };
  $("st-owner").textContent = (owners[s.owner] || s.owner) + (s.controller ? ` (${s.controller})` : "");
  $("st-time").textContent = `${s.time.toFixed(3)} s`;
  // the outputs as `welding status` prints them; the laser on is hard to miss
  $("st-outputs").innerHTML = Object.entries(s.outputs || {})
    .map(([n, v]) => (v ? `<span class="${n === "laser" ? "laser-on" : "good"}">${esc(n)} ON</span>` : `${esc(n)} off`))
    .join(", ") || "–";
  $("st-error").textContent = $("st-error").title = s.last_error ? `${s.last_error}: ${s.last_message}` : "–";
  $("joints").innerHTML = s.joints.map((q, i) => `<tr><th>J${i + 1}</th><td class="num">${q.toFixed(3)}°</td></tr>`).join("");
  const pose = s.poses[`${selection.tool}@${selection.frame}`] || s.poses["flange@world"];
  if (pose) $("pose").innerHTML = pose.map((v, i) => `<tr><th>${AXES[i]}</th><td class="num">${fmtCoord(v, i)}</td></tr>`).join("");
  showActivity(s.activity);
}

// --- which buttons may be pressed now -------------------------------------------------------

// Each button's reason not to be pressed now (the first that applies), from the status, the
// session and the link: a disabled button says why on hover. E-stop and sign-out: always.
function reasons(s) {
  const a = s.activity && s.activity.state === "running" ? s.activity : null;
  const me = session ? session.user : "";
  const mine = s.owner === "console" && s.controller === me;
  const linkUp = ws && ws.readyState === WebSocket.OPEN;
  const r = {
    viewer: session && session.role !== "operator" && `operators only: ${me} is a ${session.role}`,
    link: !linkUp && "the link to the console is down (reconnecting)",
    robot: !s.connected && "the robot is unreachable",
    control: !mine && (s.owner === "console" && s.controller ? `${s.controller} holds control`
      : s.owner === "other" ? "another client holds the robot's control" : "take control first"),
    estop: s.estop && "the emergency stop is engaged: reset it first",
    power: !s.powered && "switch arm power on first",
    idle: a && `a ${a.kind.replace("_", " ")} is running`,
    still: s.moving && "the arm is moving",
    sensor: !s.sensor && "no sensor: start the console with --sensor",
  };
  const need = (...keys) => keys.map((k) => r[k]).find(Boolean) || "";
  const running = (kind) => (a && a.kind === kind ? "" : `no ${kind.replace("_", " ")} is running`);
  const act = need("viewer", "link", "robot", "control", "estop", "power", "idle");
  return {
    take: need("viewer", "link", "robot") || (mine && "you hold control") ||
      (s.owner === "console" && s.controller ? `${s.controller} holds control` : ""),
    release: need("viewer", "link", "robot") || (!mine && "you do not hold control") || need("idle"),
    "power-on": need("viewer", "link", "robot", "control", "estop") || (s.powered && "arm power is on"),
    "power-off": need("viewer", "link", "robot", "control") || (!s.powered && "arm power is off") || need("idle"),
    "estop-reset": need("viewer", "link", "robot", "control") || (!s.estop && "the emergency stop is not engaged"),
    jog: act,
    "move-go": act || need("still") || (!$("move-name").value && "pick a location"),
    "job-dry": act || (!job && "open a job"),
    "job-weld": act || (!job && "open a job"),
    "job-abort": need("viewer") || running("job"),
    "job-check": need("viewer"), "job-save": need("viewer"), "job-saveas": need("viewer"),
    "teach-start": act || need("sensor"), "teach-abort": need("viewer") || running("teach"),
    "cal-start": act || ($("cal-which").value === "sensor-tool" ? need("sensor") : ""),
    "cal-abort": need("viewer") || running("calibration"),
    "cal-save": need("viewer") || (!calibrated && "no calibration result to save yet"),
    "dt-start": act || need("sensor"), "dt-abort": need("viewer") || running("delta_t"),
    "tr-start": need("viewer", "link", "idle"), "tr-abort": need("viewer") || running("track"),
    "ilc-start": need("viewer", "link", "idle"), "ilc-abort": need("viewer") || running("ilc"),
    "set-apply": need("viewer", "link", "control", "sensor"),
    tools: need("viewer"),
  };
}

function updateControls() {
  const why = reasons(status);
  const set = (b, reason) => {
    b.disabled = Boolean(reason);
    b.title = reason || b.dataset.help || "";
  };
  for (const [id, reason] of Object.entries(why)) {
    const b = $(id);
    if (b) set(b, reason);
  }
  document.querySelectorAll(".jog button").forEach((b) => set(b, why.jog));
  document.querySelectorAll("#tools-table button, #new-add").forEach((b) => set(b, why.tools));
}

// --- control, power, E-stop ----------------------------------------------------------------

$("estop").addEventListener("click", async () => {
  releaseJog();
  await api("POST", "/api/estop");
  say("EMERGENCY STOP sent", "error", (s) => s.estop);
});
$("estop-reset").onclick = async () => {
  if (!(await confirmAction("Reset the emergency stop?"))) return;
  await api("POST", "/api/estop/reset");
  say("emergency stop reset: switch power on to move", "info", (s) => !s.estop && !s.powered);
};
const holding = (s) => s.owner === "console" && session && s.controller === session.user;
$("take").onclick = async () => {
  await api("POST", "/api/control", { take: true });
  say("control taken", "info", holding);
};
$("release").onclick = async () => {
  await api("POST", "/api/control", { take: false });
  say("control released", "info", (s) => !holding(s));
};
$("power-on").onclick = async () => {
  if (!(await confirmAction("Switch arm power ON?"))) return;
  await api("POST", "/api/power", { on: true });
  say("power on", "info", (s) => s.powered);
};
$("power-off").onclick = async () => {
  if (!(await confirmAction("Switch arm power OFF?"))) return;
  await api("POST", "/api/power", { on: false });
  say("power off", "info", (s) => !s.powered);
};

// --- jog (dead-man) ------------------------------------------------------------------------

let holdTimer = null;
let heldButton = null;

function pressJog(button, msg) {
  if (!ws || ws.readyState !== WebSocket.OPEN) {
    say("no jog: the link to the console is down (reconnecting)", "error");
    return;
  }
  releaseJog();
  const jog = { type: "jog", speed: Number($("jog-speed").value), ...selection, ...msg };
  const step = $("jog-step").value;
  if (step) {
    // one bounded move of the step: no hold, it runs to its end (E-stop stops it)
    ws.send(JSON.stringify({ ...jog, step: Number(step) }));
    return;
  }
  heldButton = button;
  button.classList.add("held");
  ws.send(JSON.stringify(jog));
  holdTimer = setInterval(() => ws.send(JSON.stringify({ type: "hold" })), 100);
}
function jogHint() {
  $("jog-hint").textContent = $("jog-step").value
    ? `Step: each click moves ${$("jog-step").value} mm (x, y, z) or degrees (joints, rx, ry, rz), once, at the speed below.`
    : "Press and hold: the arm moves while the button is held and stops on release, when the window loses focus or the connection drops (dead-man).";
}
$("jog-step").onchange = jogHint;
jogHint();

function releaseJog() {
  if (holdTimer === null) return;
  clearInterval(holdTimer);
  holdTimer = null;
  if (heldButton) heldButton.classList.remove("held");
  heldButton = null;
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: "release" }));
}
window.addEventListener("blur", releaseJog);
document.addEventListener("visibilitychange", releaseJog);
window.addEventListener("pointerup", releaseJog);

function jogRow(label, msg, id) {
  const row = document.createElement("div");
  row.className = "axis";
  row.innerHTML = `<span>${label}</span>`;
  for (const dir of [-1, 1]) {
    const b = document.createElement("button");
    b.textContent = dir < 0 ? "−" : "+";
    b.id = `jog-${id}-${dir < 0 ? "minus" : "plus"}`;
    b.addEventListener("pointerdown", (ev) => { ev.preventDefault(); pressJog(b, { ...msg, direction: dir }); });
    b.addEventListener("pointerleave", releaseJog);
    row.appendChild(b);
  }
  return row;
}
for (let j = 1; j <= 6; j++) $("jog-joint").appendChild(jogRow(`J${j}`, { mode: "joint", axis: j }, `j${j}`));
for (const a of AXES) $("jog-cart").appendChild(jogRow(a, { mode: "cartesian", axis: a }, a));

// --- tool/frame selection, move to a location ----------------------------------------------

async function loadSelections() {
  const t = await api("GET", "/api/tools");
  const tools = t.entries.filter((e) => e.kind !== "frame").map((e) => e.name);
  const frames = t.entries.filter((e) => e.kind === "frame").map((e) => e.name);
  $("sel-tool").innerHTML = tools.map((n) => `<option>${n}</option>`).join("");
  $("sel-frame").innerHTML = frames.map((n) => `<option>${n}</option>`).join("");
  $("sel-tool").value = selection.tool;
  $("sel-frame").value = selection.frame;
}
function selectionChanged() {
  selection = { tool: $("sel-tool").value, frame: $("sel-frame").value };
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: "select", ...selection }));
}
$("sel-tool").onchange = selectionChanged;
$("sel-frame").onchange = selectionChanged;

// Refilling a list keeps the operator's choice: a reply that arrives after the operator picked
// a location must not turn "move to spot" into a move to the list's first entry.
function fillKeepingChoice(select, names) {
  const chosen = select.value;
  select.innerHTML = names.map((n) => `<option>${n}</option>`).join("");
  if (names.includes(chosen)) select.value = chosen;
}
async function loadMoveJobs() {
  const { jobs } = await api("GET", "/api/jobs");
  fillKeepingChoice($("move-job"), jobs);
  await loadMoveNames();
}
async function loadMoveNames() {
  const name = $("move-job").value;
  if (!name) return;
  const j = await api("GET", `/api/jobs/${encodeURIComponent(name)}`);
  if ($("move-job").value !== name) return; // another job was chosen meanwhile: its load fills
  const items = j.job ? j.job.items.filter((i) => i.kind !== "pause") : [];
  fillKeepingChoice($("move-name"), items.map((i) => i.name));
  updateControls();
}
$("move-job").onchange = loadMoveNames;
$("move-name").onchange = updateControls;
$("move-go").onclick = async () => {
  const name = $("move-name").value;
  if (!name || !(await confirmAction(`Move the arm to ${name}?`))) return;
  await api("POST", "/api/move", { job: $("move-job").value, name, linear: $("move-linear").checked });
  say(`moving to ${name}`, "info", (s) => s.moving);
};

// --- sensor --------------------------------------------------------------------------------

let frames = [];
async function sensorLoop() {
  for (;;) {
    const t0 = performance.now();
    if (location.hash === "#sensor" && !document.hidden) {
      try { await showFrame(); } catch (e) { /* shown in the message line */ }
    }
    // about 5 frames per second, never more than one request in flight
    await new Promise((r) => setTimeout(r, Math.max(50, 200 - (performance.now() - t0))));
  }
}

async function showFrame() {
  const r = await request("GET", "/api/sensor/frame");
  const f = await r.json();
  if (!r.ok) { $("sensor-index").textContent = f.error; return; }
  $("sensor-index").textContent = f.index >= 0 ? `#${f.index}` : f.message || "";
  const now = performance.now();
  frames.push(now);
  while (frames.length && frames[0] < now - 2000) frames.shift();
  $("sensor-rate").textContent = `${(frames.length / 2).toFixed(1)} frames/s`;
  if (f.image) {
    const img = new Image();
    img.onload = () => {
      const c = $("sensor-image");
      c.width = f.width; c.height = f.height;
      c.getContext("2d").drawImage(img, 0, 0);
    };
    img.src = `data:image/png;base64,${f.image}`;
  }
  drawProfile(f.profile || [], f.seam);
  $("sensor-seam").textContent = f.seam
    ? `seam (S frame): x ${f.seam[0].toFixed(3)}, y ${f.seam[1].toFixed(3)}, z ${f.seam[2].toFixed(3)} mm, quality ${f.quality.toFixed(2)}`
    : `no seam (${f.status || "no data"})`;
}

// --- charts (Chart.js, vendored in vendor/ with its licence) ---------------------------------

const COLORS = { blue: "#1565c0", red: "#d50000", green: "#2e7d32", black: "#222", grey: "#888" };
const xy = (pts) => pts.map(([x, y]) => ({ x, y }));

// The y range to show: at least ``minSpan`` around the data, so a flat profile or a straight
// seam is drawn flat, not its micrometre noise blown up to the full height.
function yRange(datasets, minSpan) {
  const ys = datasets.flatMap((d) => d.data.map((p) => p.y));
  if (!minSpan || !ys.length) return { min: undefined, max: undefined };
  const lo = Math.min(...ys), hi = Math.max(...ys);
  if (hi - lo >= minSpan) return { min: undefined, max: undefined };
  const q = minSpan / 4; // ends on round numbers: ticks at -2, -1, 0, 1, 2, not -1.999
  const mid = (lo + hi) / 2;
  return { min: Math.floor((mid - minSpan / 2) / q) * q, max: Math.ceil((mid + minSpan / 2) / q) * q };
}

// One chart per canvas, made on first use and then given new data: ``series`` are
// { label, pts: [[x, y]...], color, line (default true), points (radius), dash, width },
// the later drawn over the earlier, the legend in the same order (line or dot, dash shown).
function plot(canvasId, series, xTitle, yTitle, { yMinSpan = 0 } = {}) {
  const datasets = series.map((d, i) => ({
    label: d.label,
    data: xy(d.pts),
    borderColor: d.color,
    backgroundColor: d.color,
    showLine: d.line !== false,
    pointRadius: d.points || 0,
    borderWidth: d.width || 1.5,
    borderDash: d.dash || [],
    order: series.length - i,
  }));
  const range = yRange(datasets, yMinSpan);
  const existing = Chart.getChart(canvasId);
  if (existing) {
    existing.data.datasets = datasets;
    Object.assign(existing.options.scales.y, range);
    existing.update("none");
    return existing;
  }
  const axis = (text) => ({ type: "linear", title: { display: true, text }, grid: { color: "#e3e3e3" }, ticks: { maxTicksLimit: 9 } });
  const labels = (chart) => Chart.defaults.plugins.legend.labels.generateLabels(chart).map((item) => {
    const d = chart.data.datasets[item.datasetIndex];
    return { ...item, pointStyle: d.showLine ? "line" : "circle", lineWidth: d.showLine ? Math.min(d.borderWidth, 4) : 1 };
  });
  return new Chart($(canvasId), {
    type: "scatter",
    data: { datasets },
    options: {
      animation: false,
      responsive: true,
      maintainAspectRatio: false,
      parsing: false,
      normalized: true,
      scales: { x: axis(xTitle), y: { ...axis(yTitle), ...range } },
      plugins: {
        legend: {
          position: "top",
          labels: { usePointStyle: true, generateLabels: labels, sort: (a, b) => a.datasetIndex - b.datasetIndex, font: { size: 13 }, padding: 14 },
        },
        tooltip: { enabled: true },
      },
    },
  });
}

function drawProfile(profile, seam) {
  plot("sensor-profile", [
    { label: "stripe profile", pts: profile, color: COLORS.blue, line: false, points: 1.5 },
    { label: "seam point (GetData)", pts: seam ? [[seam[1], seam[2]]] : [], color: COLORS.red, line: false, points: 6 },
  ], "y (mm, sensor frame)", "z (mm, sensor frame)", { yMinSpan: 4 });
}

async function loadSettings() {
  try {
    const s = await api("GET", "/api/sensor/settings");
    $("set-exposure").value = s.exposure_ms.toFixed(3);
    $("set-first").value = s.first_column;
    $("set-columns").value = s.columns;
    $("set-info").textContent = `acquisition ${s.acquisition_ms.toFixed(3)} ms, ${s.width}×${s.height} px`;
  } catch (e) { /* no sensor */ }
}
$("set-apply").onclick = async () => {
  await api("POST", "/api/sensor/settings", {
    exposure_ms: Number($("set-exposure").value),
    first_column: Number($("set-first").value),
    columns: Number($("set-columns").value),
  });
  say("sensor settings applied");
  loadSettings();
};

// --- tools and frames ----------------------------------------------------------------------

// A location's six numbers as the page shows them: 1 µm and 0.001° (the database keeps its
// full precision: an unedited field is saved as it was read, not rounded).
const UNITS = ["mm", "mm", "mm", "°", "°", "°"];
function fmtCoord(v, i) {
  return `${(Object.is(v, -0) ? 0 : v).toFixed(3)}${i < 3 ? " mm" : "°"}`;
}
async function loadTools() {
  const t = await api("GET", "/api/tools");
  $("new-kind").innerHTML = t.kinds.map((k) => `<option>${k}</option>`).join("");
  const rows = t.entries.map((e) => {
    if (e.builtin) {
      return `<tr><td>${e.name}</td><td>${e.kind}</td>${e.location.map((v) => `<td class="num">${v.toFixed(3)}</td>`).join("")}<td>${esc(e.note)}</td><td></td></tr>`;
    }
    const coords = e.location.map((v, i) => `<td><input class="coord" type="number" step="any" data-c="${i}" data-raw="${v}" value="${v.toFixed(3)}" title="${v}"></td>`).join("");
    return `<tr data-name="${e.name}"><td>${e.name}</td><td>${e.kind}</td>${coords}
      <td><input class="note" value="${esc(e.note)}"></td>
      <td><button class="save">Save</button> <button class="remove">Remove</button></td></tr>`;
  });
  const heads = AXES.map((a, i) => `<th class="num">${a} (${UNITS[i]})</th>`).join("");
  $("tools-table").innerHTML = `<tr><th>name</th><th>kind</th>${heads}<th>note</th><th></th></tr>${rows.join("")}`;
  $("tools-table").querySelectorAll("tr[data-name]").forEach((tr) => {
    const name = tr.dataset.name;
    tr.querySelector(".save").onclick = async () => {
      const location = [...tr.querySelectorAll("input.coord")].map((inp) => {
        const raw = Number(inp.dataset.raw);
        return inp.value === raw.toFixed(3) ? raw : inp.value.trim() === "" ? "" : Number(inp.value);
      });
      await api("PUT", `/api/tools/${encodeURIComponent(name)}`, { location, note: tr.querySelector(".note").value });
      say(`${name} saved`);
      loadTools();
    };
    tr.querySelector(".remove").onclick = async () => {
      if (!(await confirmAction(`Remove ${name}?`))) return;
      await api("DELETE", `/api/tools/${encodeURIComponent(name)}`);
      say(`${name} removed`);
      loadTools();
    };
  });
  loadSelections();
  updateControls();
}
function parseLoc(text) {
  return text.split(",").map((v) => (v.trim() === "" ? NaN : Number(v))).map((v) => (Number.isFinite(v) ? v : String(v)));
}
$("new-add").onclick = async () => {
  await api("POST", "/api/tools", {
    name: $("new-name").value, kind: $("new-kind").value, location: parseLoc($("new-loc").value), note: $("new-note").value,
  });
  say(`${$("new-name").value} added`);
  loadTools();
};

// --- jobs ----------------------------------------------------------------------------------

async function loadJobs() {
  const { jobs } = await api("GET", "/api/jobs");
  $("job-list").innerHTML = jobs.map((n) => `<li data-file="${n}" class="${n === jobFile ? "open" : ""}">${n}</li>`).join("");
  $("job-list").querySelectorAll("li").forEach((li) => { li.onclick = () => openJob(li.dataset.file); });
  if (!jobFile && jobs.length) openJob(jobs[0]);
}

async function openJob(file) {
  const j = await api("GET", `/api/jobs/${encodeURIComponent(file)}`);
  jobFile = file;
  $("job-file").textContent = file;
  $("job-list").querySelectorAll("li").forEach((li) => li.classList.toggle("open", li.dataset.file === file));
  showProblems(j);
  if (j.job) { job = j.job; renderJob(); }
  updateControls();
}

const PARAMS = {
  path: [["velocity", "mm/s"], ["power", "W"], ["laser", ""], ["gas", ""], ["crossjet", ""], ["preflow", "s"], ["postflow", "s"]],
  stitch: [["duration", "s"], ["power", "W"], ["gas", ""], ["crossjet", ""], ["preflow", "s"], ["postflow", "s"], ["speed", "%"]],
  via: [["speed", "%"]],
  pause: [["duration", "s"]],
};

// Where an item goes, read-only (locations come from teaching and the tool tables): the
// target point in its frame, or a path's start, end and segments.
function fmtLoc(l) {
  const [x, y, z] = l.values;
  return `(${[x, y, z].map((v) => v.toFixed(1)).join(", ")}) mm, ${l.tool} in ${l.frame}`;
}
function where(it) {
  if (it.kind === "via" || it.kind === "stitch") return fmtLoc(it.at);
  if (it.kind !== "path") return "";
  const end = it.segments.length ? it.segments[it.segments.length - 1].to : it.start;
  const arcs = it.segments.filter((s) => s.kind === "arc").length;
  const segs = `${it.segments.length} segment${it.segments.length === 1 ? "" : "s"}${arcs ? `, ${arcs} arc${arcs === 1 ? "" : "s"}` : ""}`;
  return `${fmtLoc(it.start)} → ${fmtLoc(end).split(" mm")[0]} mm; ${segs}`;
}

function renderJob() {
  $("job-name").value = job.name;
  $("job-desc").value = job.description;
  const rows = job.items.map((it, i) => {
    const params = PARAMS[it.kind].map(([k, unit]) => {
      const v = it[k];
      const input = typeof v === "boolean"
        ? `<input type="checkbox" data-i="${i}" data-k="${k}" ${v ? "checked" : ""}>`
        : `<input type="number" step="any" data-i="${i}" data-k="${k}" value="${v}">`;
      return `<label>${k}${unit ? ` (${unit})` : ""} ${input}</label>`;
    }).join(" ");
    return `<tr data-item="${esc(it.name)}"><td>${i + 1}</td><td><input data-i="${i}" data-k="name" value="${esc(it.name)}"></td><td>${it.kind}</td>
      <td class="where">${esc(where(it))}</td><td>${params}</td><td><button data-up="${i}">↑</button><button data-down="${i}">↓</button></td></tr>`;
  });
  $("job-items").innerHTML = `<tr><th>#</th><th>item</th><th>kind</th><th>where</th><th>parameters</th><th>order</th></tr>${rows.join("")}`;
  $("job-items").querySelectorAll("input").forEach((inp) => {
    inp.onchange = () => {
      const it = job.items[Number(inp.dataset.i)];
      const k = inp.dataset.k;
      if (inp.type === "checkbox") it[k] = inp.checked;
      else if (k === "name") renameItem(it, inp.value);
      else it[k] = inp.value === "" ? null : Number(inp.value);
    };
  });
  $("job-items").querySelectorAll("button").forEach((b) => {
    b.onclick = () => {
      const i = Number(b.dataset.up ?? b.dataset.down);
      const k = b.dataset.up !== undefined ? i - 1 : i + 1;
      if (k < 0 || k >= job.items.length) return;
      [job.items[i], job.items[k]] = [job.items[k], job.items[i]];
      job.order = null; // document order is the processing order once reordered here
      renderJob();
    };
  });
}
function renameItem(it, name) {
  if (job.order) job.order = job.order.map((n) => (n === it.name ? name : n));
  it.name = name;
}
$("job-name").onchange = () => { job.name = $("job-name").value; };
$("job-desc").onchange = () => { job.description = $("job-desc").value; };

function showProblems(r) {
  const p = $("job-problems");
  if (r.ok) p.innerHTML = `<span class="good">${esc(r.summary)}</span>`;
  else p.innerHTML = r.problems.map((q) => `<div class="problem">${q.line ? `${q.line}:${q.column}: ` : ""}${esc(q.message)}</div>`).join("");
}

$("job-check").onclick = async () => {
  if (!job) return;
  showProblems(await api("POST", `/api/jobs/${encodeURIComponent(jobFile)}/check`, { job }));
};
async function saveJob(file) {
  const r = await api("PUT", `/api/jobs/${encodeURIComponent(file)}`, { job });
  showProblems(r);
  if (r.saved) { say(`${file} saved`); jobFile = file; loadJobs(); }
  else say(`${file} not saved: it has problems`, "error");
}
$("job-save").onclick = () => job && saveJob(jobFile);
$("job-saveas").onclick = () => job && $("job-new-name").value && saveJob($("job-new-name").value);
async function runJob(dry) {
  const what = dry ? "Dry run (motion only, every output off)" : "WELD (laser, gas and crossjet on)";
  if (!(await confirmAction(`${what}: ${jobFile}?`))) return;
  await api("POST", `/api/jobs/${encodeURIComponent(jobFile)}/run`, { dry_run: dry });
  say(`${dry ? "dry run" : "weld"} ${jobFile} started`, "info", runs("job"));
}
$("job-dry").onclick = () => runJob(true);
$("job-weld").onclick = () => runJob(false);
$("job-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };
$("teach-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };

// One line per activity, the same words on every page: what, its state, then only what the
// state does not say already ("dry run demo.xml: done", "weld demo.xml: aborted, cancelled by
// the operator"); a refusal's hint on a line of its own.
function activityName(a) {
  return {
    job: () => `${a.dry_run ? "dry run" : "weld"} ${a.file}`,
    teach: () => "teaching",
    delta_t: () => "ΔT measurement",
    calibration: () => `${a.which.replace("-", " ")} calibration`,
    track: () => `tracked weld (${a.seam}, ${a.speed} mm/s)`,
    ilc: () => `ILC (${a.seam})`,
  }[a.kind]();
}
function activityLine(a) {
  if (a.state === "running") {
    const progress = {
      job: () => `item ${Math.min(a.index + 1, a.total)}/${a.total} ${a.item} (${a.phase})`,
      teach: () => `${a.count} points`,
      delta_t: () => `${Math.round(100 * a.fraction)} %`,
      calibration: () => `${a.measurements} measurements`,
      track: () => "",
      ilc: () => {
        const last = a.trials[a.trials.length - 1];
        return `trial ${a.trials.length}/${a.total}` + (last ? `, the last ${(last.error_max_mm * 1e3).toFixed(1)} µm` : "");
      },
    }[a.kind]();
    return `${activityName(a)}: running${progress ? ", " + progress : ""}`;
  }
  return `${activityName(a)}: ${a.state}${a.message ? ", " + a.message : ""}`;
}
function showLine(el, a) {
  el.textContent = activityLine(a);
  if (a.hint && a.state !== "running") {
    const hint = document.createElement("div");
    hint.className = "todo";
    hint.textContent = `→ ${a.hint}`;
    el.appendChild(hint);
  }
  el.dataset.state = a.state;
}

let lastActivity = null; // the one the page saw last: its end is told once, in the banner
function showActivity(a) {
  if (!a) return;
  const seen = lastActivity;
  lastActivity = a;
  if (seen && seen.state === "running" && a.state !== "running" && seen.kind === a.kind) {
    say(activityLine(a) + (a.hint ? ` → ${a.hint}` : ""), a.state === "done" ? "info" : "error");
  }
  if (a.kind === "job") {
    showLine($("job-progress"), a);
    if (a.file === jobFile) {
      const current = a.state === "running" ? a.order[a.index] : null;
      $("job-items").querySelectorAll("tr[data-item]").forEach((tr) => tr.classList.toggle("current", tr.dataset.item === current));
    }
  } else if (a.kind === "calibration") {
    showLine($("cal-info"), a);
    const shown = `${a.which} ${a.message}`;
    if (a.state === "done" && $("cal-info").dataset.shown !== shown) {
      $("cal-info").dataset.shown = shown;
      loadCalibration();
    }
  } else if (a.kind === "track") {
    showLine($("tr-info"), a);
    if (a.state === "done" && $("tr-info").dataset.shown !== a.message) {
      $("tr-info").dataset.shown = a.message;
      loadTrack();
    }
  } else if (a.kind === "ilc") {
    showLine($("ilc-info"), a);
    if (a.trials.length) plotIlcConvergence(a.trials);
    if (a.state === "done" && $("ilc-info").dataset.shown !== a.message) {
      $("ilc-info").dataset.shown = a.message;
      loadIlc();
    }
  } else if (a.kind === "delta_t") {
    showLine($("dt-info"), a);
    if (a.state === "done" && $("dt-info").dataset.shown !== String(a.delta_t_ms)) {
      $("dt-info").dataset.shown = String(a.delta_t_ms);
      loadDeltaT();
    }
  } else if (a.kind === "teach") {
    showLine($("teach-info"), a);
    $("teach-info").dataset.count = a.count;
    if (location.hash === "#teach" || a.state !== "running") {
      plot("teach-plot", [{ label: "taught seam points", pts: a.points.map((q) => [q[0], q[1]]), color: COLORS.blue, points: 4 }],
        "x (mm, base frame)", "y (mm, base frame)", { yMinSpan: 4 });
    }
  }
}

// A start's banner holds until that activity runs and then ends (its end replaces it).
const runs = (kind) => (s) => Boolean(s.activity && s.activity.kind === kind && s.activity.state === "running");

$("teach-start").onclick = async () => {
  if (!(await confirmAction("Start teaching? The arm follows the seam under the sensor."))) return;
  await api("POST", "/api/teach", {
    step: Number($("teach-step").value), length: Number($("teach-length").value), speed: Number($("teach-speed").value),
  });
  say("teaching started", "info", runs("teach"));
};

// --- calibration ---------------------------------------------------------------------------

let calibrated = null;
async function loadCalibration() {
  const { result } = await api("GET", "/api/result/calibration");
  $("cal-result-card").hidden = !result;
  $("cal-none").hidden = Boolean(result);
  if (!result) return;
  calibrated = result;
  $("cal-which-shown").textContent = `${result.calibration.replace("-", " ")}, nominal ${result.nominal_tool}`;
  updateControls();
  // one unit per column (mm, degrees) in every row; residuals, far smaller, in µm
  const head = `<tr><th></th>${AXES.map((n, i) => `<th class="num">${n} (${UNITS[i]})</th>`).join("")}</tr>`;
  const row = (label, vals) => `<tr><th>${label}</th>${vals.map((v) => `<td class="num">${v === null ? "–" : v.toFixed(4)}</td>`).join("")}</tr>`;
  const um = (mm) => `${(mm * 1e3).toFixed(1)} µm`;
  $("cal-result").innerHTML = head + row(`nominal (${esc(result.nominal_tool)})`, result.nominal) +
    row("estimate", result.tool) + row("± 1σ", AXES.map((n) => result.uncertainty[n])) +
    (result.error_vs_true ? `<tr><th>error vs true tool</th><td colspan="6">${result.error_vs_true.position_mm.toFixed(4)} mm, ${result.error_vs_true.orientation_deg.toFixed(4)}°</td></tr>` : "") +
    `<tr><th>residual</th><td colspan="6">rms ${um(result.residual_rms_mm)}, max ${um(result.residual_max_mm)}, ${result.poses} poses, ${result.measurements} measurements</td></tr>`;
  plot("cal-plot", [{ label: "residual per pose", pts: result.residuals_mm.map((r, i) => [i + 1, r * 1e3]), color: COLORS.blue, line: false, points: 3 }],
    "pose (index)", "residual (µm)");
}
$("cal-start").onclick = async () => {
  const which = $("cal-which").value;
  const where = which === "laser-tool" ? "over the spot detector" : "around the seam";
  if (!(await confirmAction(`Calibrate the ${which.replace("-", " ")}? The arm moves to poses ${where}.`))) return;
  await api("POST", "/api/calibrate", {
    which, tool: $("cal-tool").value, poses: Number($("cal-poses").value), repeats: Number($("cal-repeats").value),
  });
  say("calibration started", "info", runs("calibration"));
};
$("cal-which").onchange = () => {
  const kind = $("cal-which").value === "laser-tool" ? "laser" : "sensor";
  $("cal-tool").value = kind;
  $("cal-poses").min = kind === "laser" ? 4 : 8;
  $("cal-save-name").value = `${kind}_cal`;
  updateControls();
};
$("cal-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };
$("cal-save").onclick = async () => {
  if (!calibrated) return;
  const name = $("cal-save-name").value;
  const note = `calibrated, ${calibrated.poses} poses, residual ${calibrated.residual_rms_mm.toFixed(4)} mm`;
  const tools = await api("GET", "/api/tools");
  if (tools.entries.some((e) => e.name === name)) {
    await api("PUT", `/api/tools/${encodeURIComponent(name)}`, { location: calibrated.tool, note });
  } else {
    await api("POST", "/api/tools", { name, kind: calibrated.kind, location: calibrated.tool, note });
  }
  say(`${name} saved in the tool database`);
};

// --- ΔT ------------------------------------------------------------------------------------

async function loadDeltaT() {
  const { result } = await api("GET", "/api/result/delta_t");
  if (!result) return;
  const rows = [
    ["ΔT", `${result.delta_t_ms.toFixed(3)} ms`],
    ["trusted", result.trusted ? "yes" : `NO: ${result.reasons.join("; ")}`],
    ["residual (synchronised)", `max ${result.residual_max_um.toFixed(1)} µm, rms ${result.residual_rms_um.toFixed(1)} µm`],
    ["residual (ΔT = 0)", `max ${result.unsynced_max_um.toFixed(1)} µm, rms ${result.unsynced_rms_um.toFixed(1)} µm`],
    ["readings", `${result.n_robot} joint samples, ${result.n_sensor} seam points`],
  ];
  $("dt-result").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${esc(v)}</td></tr>`).join("");
  plot("dt-fig6", [
    { label: "robot yᴿ (from the joint log)", pts: result.fig6.robot, color: COLORS.blue },
    { label: "sensor yˢ (seam points, at trigger time)", pts: result.fig6.sensor, color: COLORS.red, dash: [5, 3] },
  ], "t (s)", "lateral position y (mm)");
  const mse = result.fig7.map((p) => p[1]);
  plot("dt-fig7", [
    { label: "MSE(ΔT)", pts: result.fig7, color: COLORS.blue, points: 2 },
    { label: `minimum: ΔT = ${result.delta_t_ms.toFixed(3)} ms`, pts: [[result.delta_t_ms, Math.min(...mse)], [result.delta_t_ms, Math.max(...mse)]], color: COLORS.red, dash: [4, 4] },
  ], "ΔT (ms)", "MSE (µm²)");
}

$("dt-start").onclick = async () => {
  if (!(await confirmAction("Measure ΔT? The arm moves in a sine across the seam."))) return;
  await api("POST", "/api/delta-t", {
    frequency: Number($("dt-frequency").value), amplitude: Number($("dt-amplitude").value), duration: Number($("dt-duration").value),
  });
  say("ΔT measurement started", "info", runs("delta_t"));
};
$("dt-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };

// --- tracked weld --------------------------------------------------------------------------

async function loadTrack() {
  const { result } = await api("GET", "/api/result/track");
  if (!result) return;
  const um = (v) => `${(v * 1e3).toFixed(1)} µm`;
  const rows = [
    ["seam, speed", `${result.seam}, ${result.speed_mm_s} mm/s, ${result.tracked ? "tracked" : "untracked"}`],
    ["ΔT used", `${result.delta_t_ms.toFixed(3)} ms (true ${result.true_delta_t_ms.toFixed(3)} ms)`],
    ["tracking error", `max ${um(result.tracking_error_max_mm)}, rms ${um(result.tracking_error_rms_mm)}`],
    ["nominal path off the seam", `max ${um(result.nominal_error_max_mm)}`],
    ["welded", `${result.welded_mm} mm${result.stopped ? ", STOPPED: " + result.stopped : ""}`],
    // what a real cell would say: the tracker's own estimate, without the truth
    ["verdict (tracker's own)", (result.verdict && result.verdict.line) || "none"],
    ["clock", `${result.clock} (${result.cell})`],
  ];
  $("tr-result").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${esc(v)}</td></tr>`).join("");
  const t = result.top;
  // the four curves lie within micrometres of each other at this scale: told apart by width,
  // dash and marks (the error plot below shows the difference)
  // the measured points last: drawn under the lines they hid over the weld
  plot("tr-top", [
    { label: "true seam", pts: t.seam, color: COLORS.green, width: 6 },
    { label: "nominal path (untracked)", pts: t.nominal, color: COLORS.black, dash: [6, 4] },
    { label: "laser", pts: t.laser, color: COLORS.red, width: 1.5 },
    { label: "measured seam points", pts: t.measured, color: COLORS.blue, line: false, points: 1.5 },
  ], "x (mm, workpiece)", "y (mm, workpiece)");
  plot("tr-error", [{ label: "laser − seam, lateral", pts: result.error_um, color: COLORS.red }], "x (mm, workpiece)", "tracking error (µm)");
}
$("tr-start").onclick = async () => {
  await api("POST", "/api/track", {
    seam: $("tr-seam").value, speed: Number($("tr-speed").value), tracked: $("tr-tracked").checked,
  });
  say("tracked weld started", "info", runs("track"));
};

$("tr-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };

// --- ILC -----------------------------------------------------------------------------------

function plotIlcConvergence(trials) {
  plot("ilc-conv", [
    { label: "max error", pts: trials.map((t) => [t.trial, t.error_max_mm * 1e3]), color: COLORS.red, points: 4 },
    { label: "rms error", pts: trials.map((t) => [t.trial, t.error_rms_mm * 1e3]), color: COLORS.blue, points: 4 },
  ], "trial (n)", "error against the true seam (µm)");
}
async function loadIlc() {
  const { result } = await api("GET", "/api/result/ilc");
  if (!result) return;
  const t = result.trials;
  const um = (v) => `${(v * 1e3).toFixed(1)} µm`;
  const rows = [
    ["seam, speed", `${result.seam}, ${result.speed_mm_s} mm/s, ${result.dynamics} joints`],
    ["model payload", `${result.model_payload_kg} kg (the arm carries ${result.arm_payload_kg} kg)`],
    ["convergence", result.convergence.converges ? `|Q(1 − L·G)| = ${result.convergence.norm.toFixed(3)} < 1` : "diverges"],
    ...t.map((x) => [`trial ${x.trial}`, `max ${um(x.error_max_mm)}, rms ${um(x.error_rms_mm)}${x.stopped ? ", STOPPED: " + x.stopped : ""}`]),
  ];
  $("ilc-result").innerHTML = rows.map(([k, v]) => `<tr><th>${esc(k)}</th><td>${esc(v)}</td></tr>`).join("");
  plotIlcConvergence(t);
  const shades = [COLORS.red, COLORS.blue, COLORS.green, COLORS.black];
  plot("ilc-profiles", result.profiles.map((p, i) => ({
    label: `trial ${t[i].trial}`, pts: p.map((q) => [q[0], q[1] * 1e3]), color: shades[i % shades.length], dash: i >= shades.length ? [6, 4] : [],
  })), "arc length (mm)", "error (µm)");
}
$("ilc-start").onclick = async () => {
  await api("POST", "/api/ilc", {
    seam: $("ilc-seam").value, speed: Number($("ilc-speed").value), length: Number($("ilc-length").value),
    trials: Number($("ilc-trials").value), model_payload_kg: Number($("ilc-payload").value),
  });
  say("ILC started", "info", runs("ilc"));
};
$("ilc-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent", "info", (s) => Boolean(s.activity && s.activity.state === "running")); };

// --- audit log (operators) -----------------------------------------------------------------

async function loadAudit() {
  const { entries, file } = await api("GET", "/api/audit");
  $("audit-file").textContent = file;
  const cols = ["time", "user", "address", "action", "outcome"];
  const rows = entries.reverse().map((e) => {
    const rest = Object.fromEntries(Object.entries(e).filter(([k]) => !cols.includes(k)));
    const cell = (c) => (c === "time" ? String(e.time).replace("T", " ").replace(/\+00:00$/, " UTC") : e[c] ?? "");
    return `<tr>${cols.map((c) => `<td>${esc(cell(c))}</td>`).join("")}<td class="detail">${esc(JSON.stringify(rest))}</td></tr>`;
  });
  $("audit-table").innerHTML = `<tr>${[...cols, "detail"].map((c) => `<th>${c}</th>`).join("")}</tr>${rows.join("")}`;
}
$("audit-reload").onclick = () => loadAudit();
$("signout").onclick = () => signOut();

// --- start ---------------------------------------------------------------------------------

loadSession().catch(() => {});
showPage();
connect();
loadSelections().catch(() => {});
loadMoveJobs().catch(() => {});
sensorLoop();
