// rsal control: the control center page (thesis 3.4.2, 5.2.3). Polls /api/state every 0.5 s and
// renders scenarios, runs, agents, devices, the dispatcher's tasks, robots on the map and the Rerun view; the JSON API is
// described in docs/control.md.
"use strict";

const $ = (sel) => document.querySelector(sel);
let scenarios = [];
let state = null;
let mapInfo = null; // {device, width, height, resolution, origin, png}
let mapImage = null;
let drag = null; // {x, y, px, py, ex, ey} while the mouse is pressed on the map

function el(tag, attrs = {}, text = "") {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

async function api(method, path, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  const r = await fetch(path, opts);
  const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
  if (!r.ok) throw new Error(data.error || `HTTP ${r.status}`);
  return data;
}

// ------------------------------------------------------------------ scenarios
async function loadScenarios() {
  scenarios = await api("GET", "/api/scenarios");
  const sel = $("#scenario");
  sel.replaceChildren();
  for (const s of scenarios) {
    const o = el("option", { value: s.name }, s.error ? `${s.name} (invalid)` : s.name);
    sel.append(o);
  }
  showApps();
}

function currentScenario() {
  return scenarios.find((s) => s.name === $("#scenario").value);
}

function showApps() {
  const s = currentScenario();
  const sel = $("#app");
  sel.replaceChildren();
  const tbody = $("#arguments tbody");
  tbody.replaceChildren();
  $("#start-error").textContent = s && s.error ? s.error : "";
  if (!s || s.error) return;
  for (const a of s.applications) sel.append(el("option", { value: a.name }, a.name));
  for (const [k, v] of Object.entries(s.arguments_yaml || {})) addArgRow(k, v, v);
  showAppDescription();
}

// One row of the arguments table; a value that differs from ``initial`` is sent as --set K=V
// (a row added by hand has no initial value: always sent).
function addArgRow(name, value, initial) {
  const tr = el("tr");
  tr.append(el("td", {}, name));
  const td = el("td");
  const input = el("input", { "data-arg": name, value });
  if (initial !== null) input.dataset.initial = initial;
  td.append(input);
  tr.append(td);
  $("#arguments tbody").append(tr);
}

function addArgument() {
  const name = $("#new-arg-name").value.trim();
  const value = $("#new-arg-value").value;
  if (!/^[A-Za-z_][A-Za-z0-9_]*$/.test(name)) {
    $("#start-error").textContent = `argument name '${name}' must be a name (letters, digits, '_')`;
    return;
  }
  $("#start-error").textContent = "";
  const have = document.querySelector(`#arguments input[data-arg="${name}"]`);
  if (have) have.value = value;
  else addArgRow(name, value, null);
  $("#new-arg-name").value = "";
  $("#new-arg-value").value = "";
}

function showAppDescription() {
  const s = currentScenario();
  const a = s && !s.error ? s.applications.find((x) => x.name === $("#app").value) : null;
  $("#app-description").textContent = a
    ? `${a.description} — agents: ${a.agents.join(", ")}${a.simulator ? "; world " + a.simulator : ""}`
    : "";
}

async function startRun() {
  $("#start-error").textContent = "";
  const set = {};
  for (const input of document.querySelectorAll("#arguments input")) {
    if (input.value !== input.dataset.initial) set[input.dataset.arg] = input.value;
  }
  try {
    await api("POST", "/api/runs", { scenario: $("#scenario").value, app: $("#app").value, set });
    poll();
  } catch (e) {
    $("#start-error").textContent = e.message;
  }
}

// ------------------------------------------------------------------ runs, agents, devices
function renderRuns(runs) {
  const box = $("#runs");
  if (!runs.length) return;
  const empty = box.querySelector("p.muted");
  if (empty) empty.remove();
  for (const r of runs) {
    let div = box.querySelector(`.run[data-run="${r.id}"]`);
    if (!div) {
      div = el("div", { class: "run", "data-run": String(r.id) });
      div.append(el("span", { class: "title" }, `#${r.id} ${r.scenario} / ${r.app} `));
      div.append(el("span", { class: "state" }));
      div.append(el("span", { class: "info muted" }));
      const b = el("button", { class: "stop", "data-run": String(r.id) }, "Stop");
      b.addEventListener("click", () => stopRun(r.id, b));
      div.append(" ", b);
      div.append(el("pre"));
      box.prepend(div);
    }
    const st = div.querySelector(".state");
    st.textContent = r.state;
    st.className = `state ${r.state}`;
    const code = r.exit_code === null ? "" : `, exit code ${r.exit_code}`;
    div.querySelector(".info").textContent = ` pid ${r.pid}${code}${r.result ? " — " + r.result : ""}`;
    div.querySelector("button.stop").disabled = r.state !== "running";
    const pre = div.querySelector("pre");
    const text = r.lines.slice(-12).join("\n");
    if (pre.textContent !== text) {
      pre.textContent = text;
      pre.scrollTop = pre.scrollHeight;
    }
  }
}

async function stopRun(id, button) {
  button.disabled = true;
  try {
    await api("POST", `/api/runs/${id}/stop`, {});
  } catch (e) {
    $("#status").textContent = e.message;
  }
}

function renderList(ul, items, attr) {
  const want = new Set(items);
  for (const li of [...ul.children]) if (!want.has(li.dataset[attr])) li.remove();
  const have = new Set([...ul.children].map((li) => li.dataset[attr]));
  for (const it of items) {
    if (have.has(it)) continue;
    const li = el("li", {}, it);
    li.dataset[attr] = it;
    // keep the list sorted
    const next = [...ul.children].find((x) => x.dataset[attr] > it);
    ul.insertBefore(li, next || null);
  }
}

// ------------------------------------------------------------------ tasks
function showTaskForm() {
  const kind = $("#task-kind").value;
  for (const k of ["go_to", "charge", "patrol"]) $(`.kind-${k}`).hidden = k !== kind;
}

async function submitTask() {
  const kind = $("#task-kind").value;
  const body = { kind };
  if (kind === "go_to") {
    body.x = Number($("#task-x").value);
    body.y = Number($("#task-y").value);
  } else if (kind === "charge") {
    if ($("#task-charger").value) body.charger = $("#task-charger").value;
  } else {
    body.route = $("#task-route").value;
    body.laps = Number($("#task-laps").value) || 1;
  }
  if ($("#task-robot").value) body.robot = $("#task-robot").value.trim();
  $("#task-error").textContent = "";
  try {
    await api("POST", "/api/tasks", body);
    pollTasks();
  } catch (e) {
    $("#task-error").textContent = e.message;
  }
}

async function cancelTask(id, button) {
  button.disabled = true;
  try {
    await api("POST", `/api/tasks/${encodeURIComponent(id)}/cancel`, {});
  } catch (e) {
    $("#task-error").textContent = e.message;
  }
}

function renderTasks(tasks) {
  const body = $("#tasks tbody");
  const want = new Set(tasks.map((t) => t.id));
  for (const tr of [...body.children]) if (!want.has(tr.dataset.task)) tr.remove();
  for (const t of tasks) {
    let tr = [...body.children].find((x) => x.dataset.task === t.id);
    if (!tr) {
      tr = el("tr");
      tr.dataset.task = t.id;
      for (let i = 0; i < 5; i++) tr.append(el("td"));
      const b = el("button", { class: "cancel" }, "Cancel");
      b.addEventListener("click", () => cancelTask(t.id, b));
      const td = el("td");
      td.append(b);
      tr.append(td);
      body.append(tr);
    }
    const cells = tr.children;
    cells[0].textContent = t.id;
    cells[1].textContent = t.kind;
    cells[2].textContent = t.state;
    cells[2].className = `taskstate ${t.state}`;
    cells[2].title = [t.states.join(" → "), t.text].filter(Boolean).join("\n");
    cells[3].textContent = t.robot || "–";
    cells[4].textContent = `${Math.round(t.age)} s`;
    tr.querySelector("button.cancel").disabled = t.final;
  }
  $("#task-count").textContent = `(${tasks.filter((t) => !t.final).length} live)`;
  $("#tasks-empty").hidden = tasks.length > 0;
}

async function pollTasks() {
  try {
    renderTasks((await api("GET", "/api/tasks")).tasks);
  } catch (e) {
    $("#task-error").textContent = `tasks: ${e.message}`;
  }
}

// ------------------------------------------------------------------ robots and map
function selectedRobot() {
  return $("#robot").value;
}

function renderRobots(robots) {
  const sel = $("#robot");
  const names = robots.map((r) => r.name);
  const have = [...sel.options].map((o) => o.value);
  if (names.join(",") !== have.join(",")) {
    const keep = sel.value;
    sel.replaceChildren(...names.map((n) => el("option", { value: n }, n)));
    if (names.includes(keep)) sel.value = keep;
  }
  const r = robots.find((x) => x.name === selectedRobot());
  const wf = r && r.wallfollow && (r.wallfollow.state === "running" || r.wallfollow.state === "stopping");
  $("#robot-wallfollow").textContent = wf ? "Stop wall-following" : "Wall-follow";
  $("#robot-wallfollow").dataset.on = wf ? "1" : "";
  $("#mode-pose").disabled = !(r && r.localize);
  $("#mode-goal").disabled = !(r && r.planner);
  let note = r ? r.note || "" : "";
  if (r && r.goal) note += `${note ? "; " : ""}goal (${r.goal.x.toFixed(2)}, ${r.goal.y.toFixed(2)}): ${r.goal.status}`;
  if (!drag) $("#robot-note").textContent = note;
}

async function robotAction(action, body) {
  const r = selectedRobot();
  if (!r) {
    $("#robot-note").textContent = "no robot is alive";
    return;
  }
  try {
    const res = await api("POST", `/api/robots/${encodeURIComponent(r)}/${action}`, body);
    $("#robot-note").textContent = res.note || (res.goal ? `goal sent (${res.waypoints} waypoints)` : "ok");
  } catch (e) {
    $("#robot-note").textContent = e.message;
  }
}

async function estopAll(release) {
  try {
    const res = await api("POST", "/api/estop", { release });
    $("#estop-note").textContent = res.note;
  } catch (e) {
    $("#estop-note").textContent = e.message;
  }
}

async function refreshMap(maps) {
  const want = maps.includes("sim:map:0") ? "sim:map:0" : maps[0];
  if (!want) {
    mapInfo = null;
    mapImage = null;
    $("#map-info").textContent = "no map device alive yet";
    return;
  }
  if (mapInfo && mapInfo.device === want) return;
  mapInfo = { device: want, loading: true };
  try {
    const m = await api("GET", `/api/map?device=${encodeURIComponent(want)}`);
    const img = new Image();
    img.onload = () => {
      mapInfo = m;
      mapImage = img;
      const canvas = $("#map");
      const scale = Math.min(640 / m.width, 480 / m.height);
      canvas.width = Math.round(m.width * scale);
      canvas.height = Math.round(m.height * scale);
      $("#map-info").textContent =
        `${m.device}: ${m.width}x${m.height} cells of ${m.resolution} m, origin (${m.origin[0]}, ${m.origin[1]})`;
      draw();
    };
    img.src = m.png + `&t=${Date.now()}`;
  } catch (e) {
    mapInfo = null;
    $("#map-info").textContent = e.message;
  }
}

function toPixel(x, y) {
  const c = $("#map");
  const sx = c.width / mapInfo.width;
  const sy = c.height / mapInfo.height;
  return [((x - mapInfo.origin[0]) / mapInfo.resolution) * sx, c.height - ((y - mapInfo.origin[1]) / mapInfo.resolution) * sy];
}

function toWorld(px, py) {
  const c = $("#map");
  const sx = c.width / mapInfo.width;
  const sy = c.height / mapInfo.height;
  return [mapInfo.origin[0] + (px / sx) * mapInfo.resolution, mapInfo.origin[1] + ((c.height - py) / sy) * mapInfo.resolution];
}

function arrow(ctx, x0, y0, x1, y1, color) {
  ctx.strokeStyle = color;
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x0, y0);
  ctx.lineTo(x1, y1);
  ctx.stroke();
}

function draw() {
  const c = $("#map");
  const ctx = c.getContext("2d");
  ctx.clearRect(0, 0, c.width, c.height);
  if (!mapImage || !mapInfo || mapInfo.loading) return;
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(mapImage, 0, 0, c.width, c.height);
  const pxPerM = c.width / (mapInfo.width * mapInfo.resolution);
  for (const r of (state && state.robots) || []) {
    if (r.goal) {
      const [gx, gy] = toPixel(r.goal.x, r.goal.y);
      ctx.strokeStyle = "#2563eb";
      ctx.strokeRect(gx - 4, gy - 4, 8, 8);
    }
    if (!r.pose) continue;
    const [px, py] = toPixel(r.pose[0], r.pose[1]);
    const rad = Math.max(4, 0.25 * pxPerM);
    const chosen = r.name === selectedRobot();
    ctx.fillStyle = chosen ? "#dc2626" : "#059669";
    ctx.beginPath();
    ctx.arc(px, py, rad, 0, 2 * Math.PI);
    ctx.fill();
    arrow(ctx, px, py, px + 2 * rad * Math.cos(r.pose[2]), py - 2 * rad * Math.sin(r.pose[2]), "#111");
    ctx.fillStyle = "#111";
    ctx.fillText(r.name, px + rad + 2, py - rad);
  }
  if (drag) arrow(ctx, drag.px, drag.py, drag.ex, drag.ey, "#f59e0b");
}

function mode() {
  return document.querySelector('input[name="mode"]:checked').value;
}

function canvasPoint(ev) {
  const c = $("#map");
  const rect = c.getBoundingClientRect();
  return [((ev.clientX - rect.left) * c.width) / rect.width, ((ev.clientY - rect.top) * c.height) / rect.height];
}

function setupMap() {
  const c = $("#map");
  c.addEventListener("mousedown", (ev) => {
    if (!mapInfo || mapInfo.loading || mode() === "none") return;
    const [px, py] = canvasPoint(ev);
    drag = { px, py, ex: px, ey: py };
  });
  window.addEventListener("mousemove", (ev) => {
    if (!drag) return;
    [drag.ex, drag.ey] = canvasPoint(ev);
    const [x, y] = toWorld(drag.px, drag.py);
    $("#robot-note").textContent = `${mode() === "pose" ? "initial pose" : "goal"} at (${x.toFixed(2)}, ${y.toFixed(2)})`;
    draw();
  });
  window.addEventListener("mouseup", () => {
    if (!drag) return;
    const [x, y] = toWorld(drag.px, drag.py);
    const dx = drag.ex - drag.px;
    const dy = drag.py - drag.ey;
    const yaw = Math.hypot(dx, dy) > 3 ? (Math.atan2(dy, dx) * 180) / Math.PI : 0;
    const action = mode();
    drag = null;
    draw();
    robotAction(action, { x, y, yaw });
  });
}

// ------------------------------------------------------------------ the Rerun view
// The viewer is loaded under the other name of the loopback host (localhost for a page opened as
// 127.0.0.1 and the other way round): a different site gets its own browser process, so that the
// viewer's rendering (slow without a GPU) does not hold up the controls.
function otherLoopbackName(url) {
  const u = new URL(url);
  if (u.hostname === "127.0.0.1" && location.hostname === "127.0.0.1") u.hostname = "localhost";
  else if (u.hostname === "localhost" && location.hostname === "localhost") u.hostname = "127.0.0.1";
  return u.toString();
}

function renderWatch(w) {
  $("#watch-state").textContent = w.state + (w.pid ? ` (pid ${w.pid})` : "");
  const frame = $("#viewer");
  const ph = $("#viewer-placeholder");
  if (w.url) {
    const url = otherLoopbackName(w.url);
    if (frame.getAttribute("src") !== url) frame.setAttribute("src", url);
    frame.hidden = false;
    ph.hidden = true;
  } else {
    frame.hidden = true;
    ph.hidden = false;
    const last = w.lines && w.lines.length ? ` — ${w.lines[w.lines.length - 1]}` : "";
    ph.textContent = w.hint
      ? `The Rerun web view appears here: ${w.hint}.`
      : `Starting 'rsal watch --serve' (${w.state})${last}`;
  }
}

// ------------------------------------------------------------------ polling
// One poll at a time: a browser opens at most six connections to a host, so polls that pile up
// behind a slow answer (a loaded machine) would queue a button's request behind them.
let polling = false;

async function poll() {
  if (polling) return;
  polling = true;
  try {
    await pollOnce();
  } finally {
    polling = false;
  }
}

async function pollOnce() {
  try {
    state = await api("GET", "/api/state");
    $("#status").textContent = "";
  } catch (e) {
    $("#status").textContent = `control unreachable: ${e.message}`;
    return;
  }
  $("#fabric").textContent = `fabric: ${state.fabric}`;
  renderRuns(state.runs);
  renderList($("#agents"), state.agents, "agent");
  renderList($("#devices"), state.devices, "device");
  $("#agent-count").textContent = `(${state.agents.length})`;
  $("#device-count").textContent = `(${state.devices.length})`;
  renderRobots(state.robots);
  renderWatch(state.watch);
  refreshMap(state.maps);
  draw();
  await pollTasks();
}

window.addEventListener("load", () => {
  $("#scenario").addEventListener("change", showApps);
  $("#app").addEventListener("change", showAppDescription);
  $("#start").addEventListener("click", startRun);
  $("#add-arg").addEventListener("click", addArgument);
  $("#robot").addEventListener("change", () => poll());
  $("#robot-stop").addEventListener("click", () => robotAction("stop", {}));
  $("#robot-estop").addEventListener("click", () => robotAction("estop", {}));
  $("#robot-estop-release").addEventListener("click", () => robotAction("estop", { release: true }));
  $("#estop-all").addEventListener("click", () => estopAll(false));
  $("#estop-release-all").addEventListener("click", () => estopAll(true));
  $("#robot-wallfollow").addEventListener("click", (ev) => robotAction("wallfollow", { on: !ev.target.dataset.on }));
  $("#task-kind").addEventListener("change", showTaskForm);
  $("#task-submit").addEventListener("click", submitTask);
  setupMap();
  loadScenarios().catch((e) => ($("#start-error").textContent = e.message));
  poll();
  setInterval(poll, 500);
});
