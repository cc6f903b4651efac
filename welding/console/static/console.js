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

function say(text, kind = "info") {
  const m = $("message");
  m.textContent = m.title = text;
  m.className = kind;
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
  session = await r.json();
  $("user").textContent = `${session.user} (${session.role})`;
  document.body.dataset.role = session.role;
  $("nav-audit").hidden = session.role !== "operator";
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
  document.querySelectorAll(".page").forEach((p) => p.classList.toggle("active", p.id === `page-${page}`));
  document.querySelectorAll("nav a").forEach((a) => a.classList.toggle("active", a.dataset.page === page));
  if (page === "tools") loadTools();
  if (page === "jobs") loadJobs();
  if (page === "sensor") loadSettings();
  if (page === "deltat") loadDeltaT().catch(() => {});
  if (page === "calibration") loadCalibration().catch(() => {});
  if (page === "track") loadTrack().catch(() => {});
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
  $("st-error").textContent = $("st-error").title = s.last_error ? `${s.last_error}: ${s.last_message}` : "–";
  $("joints").innerHTML = s.joints.map((q, i) => `<tr><th>J${i + 1}</th><td>${q.toFixed(3)}</td></tr>`).join("");
  const pose = s.poses[`${selection.tool}@${selection.frame}`] || s.poses["flange@world"];
  if (pose) $("pose").innerHTML = pose.map((v, i) => `<tr><th>${AXES[i]}</th><td>${v.toFixed(3)}</td></tr>`).join("");
  showActivity(s.activity);
}

// --- control, power, E-stop ----------------------------------------------------------------

$("estop").addEventListener("click", async () => {
  releaseJog();
  await api("POST", "/api/estop");
  say("EMERGENCY STOP sent", "error");
});
$("estop-reset").onclick = async () => {
  if (await confirmAction("Reset the emergency stop?")) await api("POST", "/api/estop/reset");
};
$("take").onclick = async () => { await api("POST", "/api/control", { take: true }); say("control taken"); };
$("release").onclick = async () => { await api("POST", "/api/control", { take: false }); say("control released"); };
$("power-on").onclick = async () => {
  if (await confirmAction("Switch arm power ON?")) { await api("POST", "/api/power", { on: true }); say("power on"); }
};
$("power-off").onclick = async () => {
  if (await confirmAction("Switch arm power OFF?")) { await api("POST", "/api/power", { on: false }); say("power off"); }
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
  heldButton = button;
  button.classList.add("held");
  ws.send(JSON.stringify({ type: "jog", speed: Number($("jog-speed").value), ...selection, ...msg }));
  holdTimer = setInterval(() => ws.send(JSON.stringify({ type: "hold" })), 100);
}

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
}
$("move-job").onchange = loadMoveNames;
$("move-go").onclick = async () => {
  const name = $("move-name").value;
  if (!name || !(await confirmAction(`Move the arm to ${name}?`))) return;
  await api("POST", "/api/move", { job: $("move-job").value, name, linear: $("move-linear").checked });
  say(`moving to ${name}`);
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

function drawPlot(canvas, pts, marks, xlabel, ylabel) {
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height, m = 30;
  ctx.clearRect(0, 0, W, H);
  const all = pts.concat(marks);
  if (!all.length) return;
  let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
  for (const [x, y] of all) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
  const span = Math.max(x1 - x0, y1 - y0, 1) * 1.1;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  const s = Math.min(W, H) - 2 * m;
  const X = (x) => W / 2 + ((x - cx) / span) * s;
  const Y = (y) => H / 2 - ((y - cy) / span) * s;
  ctx.strokeStyle = "#999"; ctx.fillStyle = "#333"; ctx.font = "11px sans-serif";
  ctx.fillText(`${xlabel} ${x0.toFixed(1)}…${x1.toFixed(1)} mm`, 4, H - 4);
  ctx.fillText(`${ylabel} ${y0.toFixed(1)}…${y1.toFixed(1)} mm`, 4, 12);
  ctx.fillStyle = "#1565c0";
  for (const [x, y] of pts) ctx.fillRect(X(x) - 2.5, Y(y) - 2.5, 5, 5);
  ctx.strokeStyle = "#d50000"; ctx.lineWidth = 2;
  for (const [x, y] of marks) { ctx.beginPath(); ctx.arc(X(x), Y(y), 6, 0, 2 * Math.PI); ctx.stroke(); }
}

function drawProfile(profile, seam) {
  drawPlot($("sensor-profile"), profile, seam ? [[seam[1], seam[2]]] : [], "y", "z");
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

async function loadTools() {
  const t = await api("GET", "/api/tools");
  $("new-kind").innerHTML = t.kinds.map((k) => `<option>${k}</option>`).join("");
  const rows = t.entries.map((e) => {
    const loc = e.location.join(", ");
    if (e.builtin) return `<tr><td>${e.name}</td><td>${e.kind}</td><td>${loc}</td><td>${esc(e.note)}</td><td></td></tr>`;
    return `<tr data-name="${e.name}"><td>${e.name}</td><td>${e.kind}</td>
      <td><input class="wide loc" value="${loc}"></td><td><input class="note" value="${esc(e.note)}"></td>
      <td><button class="save">Save</button> <button class="remove">Remove</button></td></tr>`;
  });
  $("tools-table").innerHTML = `<tr><th>name</th><th>kind</th><th>location x, y, z, rx, ry, rz</th><th>note</th><th></th></tr>${rows.join("")}`;
  $("tools-table").querySelectorAll("tr[data-name]").forEach((tr) => {
    const name = tr.dataset.name;
    tr.querySelector(".save").onclick = async () => {
      await api("PUT", `/api/tools/${encodeURIComponent(name)}`, {
        location: parseLoc(tr.querySelector(".loc").value), note: tr.querySelector(".note").value,
      });
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
}

const PARAMS = {
  path: [["velocity", "mm/s"], ["power", "W"], ["laser", ""], ["gas", ""], ["crossjet", ""], ["preflow", "s"], ["postflow", "s"]],
  stitch: [["duration", "s"], ["power", "W"], ["gas", ""], ["crossjet", ""], ["preflow", "s"], ["postflow", "s"], ["speed", "%"]],
  via: [["speed", "%"]],
  pause: [["duration", "s"]],
};

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
    return `<tr data-item="${it.name}"><td>${i + 1}</td><td><input data-i="${i}" data-k="name" value="${it.name}"></td><td>${it.kind}</td>
      <td>${params}</td><td><button data-up="${i}">↑</button><button data-down="${i}">↓</button></td></tr>`;
  });
  $("job-items").innerHTML = `<tr><th>#</th><th>item</th><th>kind</th><th>parameters</th><th>order</th></tr>${rows.join("")}`;
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
  say(`${jobFile}: ${dry ? "dry run" : "weld"} started`);
}
$("job-dry").onclick = () => runJob(true);
$("job-weld").onclick = () => runJob(false);
$("job-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent"); };
$("teach-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent"); };

function showActivity(a) {
  if (!a) return;
  if (a.kind === "job") {
    $("job-progress").innerHTML = `<b>${a.dry_run ? "dry run" : "weld"} ${a.file}</b>: ${a.state}` +
      (a.state === "running" ? `, item ${Math.min(a.index + 1, a.total)}/${a.total} ${a.item} (${a.phase})` : ` ${esc(a.message)}`);
    $("job-progress").dataset.state = a.state;
    if (a.file === jobFile) {
      const current = a.state === "running" ? a.order[a.index] : null;
      $("job-items").querySelectorAll("tr[data-item]").forEach((tr) => tr.classList.toggle("current", tr.dataset.item === current));
    }
  } else if (a.kind === "calibration") {
    $("cal-info").textContent = `${a.which}: ${a.measurements} measurements, ${a.state}${a.message ? ": " + a.message : ""}`;
    $("cal-info").dataset.state = a.state;
    const shown = `${a.which} ${a.message}`;
    if (a.state === "done" && $("cal-info").dataset.shown !== shown) {
      $("cal-info").dataset.shown = shown;
      loadCalibration();
    }
  } else if (a.kind === "track") {
    $("tr-info").textContent = `${a.seam} at ${a.speed} mm/s: ${a.state}${a.message ? ", " + a.message : ""}`;
    $("tr-info").dataset.state = a.state;
    if (a.state === "done" && $("tr-info").dataset.shown !== a.message) {
      $("tr-info").dataset.shown = a.message;
      loadTrack();
    }
  } else if (a.kind === "delta_t") {
    $("dt-info").textContent = a.state === "running"
      ? `running: ${Math.round(100 * a.fraction)} %`
      : `${a.state}${a.message ? ": " + a.message : ""}`;
    $("dt-info").dataset.state = a.state;
    if (a.state === "done" && $("dt-info").dataset.shown !== String(a.delta_t_ms)) {
      $("dt-info").dataset.shown = String(a.delta_t_ms);
      loadDeltaT();
    }
  } else if (a.kind === "teach") {
    $("teach-info").textContent = `${a.count} points, ${a.state}${a.message ? ": " + a.message : ""}`;
    $("teach-info").dataset.state = a.state;
    $("teach-info").dataset.count = a.count;
    drawPlot($("teach-plot"), a.points.map((p) => [p[0], p[1]]), [], "x", "y");
  }
}

$("teach-start").onclick = async () => {
  if (!(await confirmAction("Start teaching? The arm follows the seam under the sensor."))) return;
  await api("POST", "/api/teach", {
    step: Number($("teach-step").value), length: Number($("teach-length").value), speed: Number($("teach-speed").value),
  });
  say("teaching started");
};

// --- calibration ---------------------------------------------------------------------------

let calibrated = null;
async function loadCalibration() {
  const { result } = await api("GET", "/api/result/calibration");
  if (!result) return;
  calibrated = result;
  const names = ["x", "y", "z", "rx", "ry", "rz"];
  const head = `<tr><th></th>${names.map((n) => `<th>${n}</th>`).join("")}</tr>`;
  const row = (label, vals, digits) => `<tr><th>${label}</th>${vals.map((v) => `<td>${v === null ? "–" : v.toFixed(digits)}</td>`).join("")}</tr>`;
  $("cal-result").innerHTML = head + row(`nominal (${result.nominal_tool})`, result.nominal, 3) +
    row("estimate", result.tool, 4) + row("± 1σ", names.map((n) => result.uncertainty[n]), 4) +
    (result.error_vs_true ? `<tr><th>error vs true tool</th><td colspan="6">${result.error_vs_true.position_mm.toFixed(4)} mm, ${result.error_vs_true.orientation_deg.toFixed(4)}°</td></tr>` : "") +
    `<tr><th>residual</th><td colspan="6">rms ${(result.residual_rms_mm * 1e3).toFixed(1)} µm, max ${(result.residual_max_mm * 1e3).toFixed(1)} µm, ${result.poses} poses, ${result.measurements} measurements</td></tr>`;
  drawXY($("cal-plot"), [{ pts: result.residuals_mm.map((r, i) => [i, r]), color: "#1565c0" }], "measurement", "residual (mm)");
}
$("cal-start").onclick = async () => {
  const which = $("cal-which").value;
  const where = which === "laser-tool" ? "over the spot detector" : "around the seam";
  if (!(await confirmAction(`Calibrate the ${which.replace("-", " ")}? The arm moves to poses ${where}.`))) return;
  await api("POST", "/api/calibrate", {
    which, tool: $("cal-tool").value, poses: Number($("cal-poses").value), repeats: Number($("cal-repeats").value),
  });
  say("calibration started");
};
$("cal-which").onchange = () => {
  const kind = $("cal-which").value === "laser-tool" ? "laser" : "sensor";
  $("cal-tool").value = kind;
  $("cal-poses").min = kind === "laser" ? 4 : 8;
  $("cal-save-name").value = `${kind}_cal`;
};
$("cal-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent"); };
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

function drawXY(canvas, series, xlabel, ylabel, vline) {
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height, m = 40;
  ctx.clearRect(0, 0, W, H);
  const all = series.flatMap((s) => s.pts);
  if (!all.length) return;
  let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
  for (const [x, y] of all) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) y1 = y0 + 1;
  const X = (x) => m + ((x - x0) / (x1 - x0)) * (W - 1.5 * m);
  const Y = (y) => H - m + ((y0 - y) / (y1 - y0)) * (H - 1.5 * m);
  ctx.strokeStyle = "#999"; ctx.lineWidth = 1;
  ctx.strokeRect(m, m / 2, W - 1.5 * m, H - 1.5 * m);
  ctx.fillStyle = "#333"; ctx.font = "11px sans-serif";
  ctx.fillText(`${xlabel}: ${x0.toPrecision(4)} … ${x1.toPrecision(4)}`, m, H - 8);
  ctx.fillText(`${ylabel}: ${y0.toPrecision(4)} … ${y1.toPrecision(4)}`, m, 12);
  for (const s of series) {
    ctx.strokeStyle = s.color; ctx.lineWidth = 1.2;
    ctx.beginPath();
    s.pts.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.stroke();
  }
  if (vline !== undefined) {
    ctx.strokeStyle = "#d50000"; ctx.beginPath(); ctx.moveTo(X(vline), m / 2); ctx.lineTo(X(vline), H - m); ctx.stroke();
  }
}

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
  drawXY($("dt-fig6"), [{ pts: result.fig6.robot, color: "#1565c0" }, { pts: result.fig6.sensor, color: "#d50000" }], "t (s)", "y (mm)");
  drawXY($("dt-fig7"), [{ pts: result.fig7, color: "#1565c0" }], "ΔT (ms)", "MSE (µm²)", result.delta_t_ms);
}

$("dt-start").onclick = async () => {
  if (!(await confirmAction("Measure ΔT? The arm moves in a sine across the seam."))) return;
  await api("POST", "/api/delta-t", {
    frequency: Number($("dt-frequency").value), amplitude: Number($("dt-amplitude").value), duration: Number($("dt-duration").value),
  });
  say("ΔT measurement started");
};
$("dt-abort").onclick = async () => { await api("POST", "/api/abort"); say("abort sent"); };

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
  ];
  $("tr-result").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${esc(v)}</td></tr>`).join("");
  const t = result.top;
  drawXY($("tr-top"), [
    { pts: t.seam, color: "#2e7d32" }, { pts: t.nominal, color: "#000" },
    { pts: t.laser, color: "#d50000" }, { pts: t.measured, color: "#1565c0" },
  ], "x (mm)", "y (mm)");
  drawXY($("tr-error"), [{ pts: result.error_um, color: "#d50000" }], "x (mm)", "error (µm)");
}
$("tr-start").onclick = async () => {
  await api("POST", "/api/track", {
    seam: $("tr-seam").value, speed: Number($("tr-speed").value), tracked: $("tr-tracked").checked,
  });
  say("tracked weld started");
};

// --- audit log (operators) -----------------------------------------------------------------

async function loadAudit() {
  const { entries, file } = await api("GET", "/api/audit");
  $("audit-file").textContent = file;
  const cols = ["time", "user", "address", "action", "outcome"];
  const rows = entries.reverse().map((e) => {
    const rest = Object.fromEntries(Object.entries(e).filter(([k]) => !cols.includes(k)));
    return `<tr>${cols.map((c) => `<td>${esc(e[c] ?? "")}</td>`).join("")}<td>${esc(JSON.stringify(rest))}</td></tr>`;
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
