// Lupin HMI: wires the panels to the daemon's WebSocket.
//
// Everything shown comes from the daemon: the joints and their windows, the
// presets, the pad layout and the mux sources arrive in the "hello" frame
// (the same body as GET /api/robot), the live values in "state" frames. The
// page duplicates no robot number, so a profile change needs no edit here.

import { ArmPanel } from "./arm.js";
import { api, Link, setToken } from "./conn.js";
import { DrivePad } from "./drive.js";
import { Trace } from "./plot.js";
import { $, confirmTap, errorText, fmt, setAttr, setDisabled, setText, signed, toast } from "./ui.js";

const POSES_REFRESH_MS = 3000;

const app = {
  info: null,
  state: null,
  connected: false,
  armed: false,
};

const link = new Link({
  onHello: (info) => hello(info),
  onState: (state) => update(state),
  onStatus: (status, detail) => connection(status, detail),
  onError: (error) => toast(errorText(error)),
});
const drive = new DrivePad(link);
const arm = new ArmPanel(link);
const trace = new Trace();

// -- connection -----------------------------------------------------------------------

function connection(status, detail) {
  app.connected = status === "connected";
  document.body.classList.toggle("disconnected", !app.connected);
  const pill = $("conn-pill");
  const text = {
    connected: "connected",
    connecting: "connecting…",
    retrying: "offline",
    unauthorized: "token needed",
  }[status];
  setText($("conn-text"), text);
  setAttr(pill, "data-tone", app.connected ? "good" : status === "connecting" ? "warn" : "bad");
  banner(status, detail);
  if (!app.connected) {
    app.state = null;
    render(); // every control off, torque back to unknown
  }
}

let countdown = null;

function banner(status, detail) {
  const box = $("banner");
  clearInterval(countdown);
  if (status === "connected" || status === "connecting") {
    box.hidden = status === "connected";
    if (status === "connecting") box.textContent = "Connecting to the daemon…";
    return;
  }
  box.hidden = false;
  box.replaceChildren();
  if (status === "unauthorized") {
    const form = document.createElement("form");
    form.className = "token-form";
    form.innerHTML =
      '<span>This daemon needs its API token.</span>' +
      '<input type="password" autocomplete="current-password" aria-label="API token" placeholder="token">' +
      '<button class="btn" type="submit">Connect</button>';
    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      setToken(form.querySelector("input").value.trim());
      link.retryNow();
    });
    box.append(form);
    return;
  }
  const msg = document.createElement("span");
  const retry = document.createElement("button");
  retry.className = "btn";
  retry.type = "button";
  retry.textContent = "Retry now";
  retry.addEventListener("click", () => link.retryNow());
  box.append(msg, retry);
  const tick = () => {
    const left = Math.max(0, (link.retryAt - performance.now()) / 1000);
    msg.textContent = `Disconnected (${detail.why}). All controls are off. Retrying in ${Math.ceil(left)} s`;
  };
  tick();
  countdown = setInterval(tick, 250);
}

// -- robot description: built once per hello ---------------------------------------------

function hello(info) {
  app.info = info;
  setText($("profile"), info.profile);
  $("profile").title = info.description;
  document.title = `Lupin · ${info.profile}`;
  arm.build(info);
  trace.build(info);
  buildPresets(info);
  buildSources(info);
  buildPadMap(info);
  refreshPoses();
}

function buildPresets(info) {
  const box = $("presets");
  box.replaceChildren();
  for (const [name, pose] of Object.entries(info.presets)) {
    const b = document.createElement("button");
    b.type = "button";
    b.className = "btn preset";
    b.textContent = name;
    b.dataset.testid = `preset-${name}`;
    b.title = Object.entries(pose)
      .map(([j, v]) => `${j} ${v.toFixed(1)}°`)
      .join("\n");
    b.addEventListener("click", () => run({ type: "preset", name }, `preset ${name}`));
    box.append(b);
  }
}

function buildSources(info) {
  const body = $("sources").tBodies[0];
  body.replaceChildren();
  const sources = Object.entries(info.mux_sources).sort((a, b) => b[1].priority - a[1].priority);
  for (const [name, s] of sources) {
    const tr = document.createElement("tr");
    tr.dataset.source = name;
    tr.innerHTML =
      `<td class="src"><span class="dot"></span><span></span></td><td class="num"></td>` +
      `<td class="num"></td><td class="num age"></td><td class="st"></td>`;
    tr.children[0].lastElementChild.textContent = name;
    tr.children[1].textContent = String(s.priority);
    tr.children[2].textContent = s.timeout > 0 ? `${s.timeout} s` : "never";
    body.append(tr);
  }
}

function buildPadMap(info) {
  const box = $("pad-map");
  box.replaceChildren();
  const layout = info.pad_layout;
  $("pad-map-box").hidden = !layout;
  const mapping = (layout && layout.mapping) || {};
  setText($("pad-desc"), mapping.description || "");
  setText(
    $("pad-deadman-button"),
    mapping.require_enable_button === false
      ? "none (this layout has no dead-man)"
      : mapping.enable_button !== undefined
        ? `button ${mapping.enable_button}`
        : "—",
  );
  if (!layout) return;
  // The whole mapping, flattened: the daemon's file is the reference, shown as is.
  const rows = [];
  const walk = (prefix, value) => {
    if (value === null || value === undefined) return;
    if (typeof value === "object" && !Array.isArray(value)) {
      for (const [k, v] of Object.entries(value)) walk(prefix ? `${prefix}.${k}` : k, v);
    } else if (prefix !== "mapping.description") {
      rows.push([prefix.replace(/^mapping\./, ""), Array.isArray(value) ? value.join(", ") : String(value)]);
    }
  };
  walk("", layout);
  for (const [key, value] of rows) {
    const dt = document.createElement("dt");
    const dd = document.createElement("dd");
    dt.textContent = key;
    dd.textContent = value;
    box.append(dt, dd);
  }
}

// -- live state ------------------------------------------------------------------------

function update(state) {
  app.state = state;
  trace.push(state);
  render();
}

// Render everything from (info, state, connected). With no state every control is off.
function render() {
  const s = app.state;
  const on = app.connected && s !== null;
  const estop = on && s.estop;
  document.body.classList.toggle("estop-on", estop);
  setText($("estop-label"), estop ? "E-STOP ENGAGED" : "E-STOP");
  setAttr($("estop"), "aria-pressed", String(estop));
  setDisabled($("estop-release"), !estop);

  const torque = on ? s.torque : "unknown";
  setText($("torque-text"), torque);
  setAttr($("torque-pill"), "data-tone", { on: "good", enabling: "warn", off: "off" }[torque] || "unknown");

  drive.setEnabled(on && !s.estop);
  app.armed = arm.update(on ? s : emptyState(), on);
  for (const b of $("presets").children) setDisabled(b, !app.armed);
  for (const b of document.querySelectorAll(".pose-go")) setDisabled(b, !app.armed);
  for (const b of document.querySelectorAll(".pose-del")) setDisabled(b, !on);
  setDisabled($("pose-name"), !on);
  setDisabled($("pose-save"), !(on && s.seeded));
  setDisabled($("heal"), !on);
  renderMux(on ? s.mux : null);
  renderPad(on ? s.pad : null);
  renderBase(on ? s.base : null);
  renderEvents(on ? s.events : null);
}

function emptyState() {
  return { joints: [], torque: "unknown", estop: false, seeded: false, events: [] };
}

function renderMux(mux) {
  setText($("mux-active"), mux ? mux.active || "none" : "—");
  setAttr($("mux-active"), "data-source", mux && mux.active ? mux.active : "");
  setText($("mux-lock"), mux ? mux.locked_by || "none" : "—");
  setAttr($("mux-lock"), "data-locked", String(Boolean(mux && mux.locked_by)));
  setText($("mux-mode"), mux ? `${mux.mode} mode` : "");
  for (const tr of $("sources").tBodies[0].rows) {
    const src = mux && mux.sources[tr.dataset.source];
    const active = Boolean(mux && mux.active === tr.dataset.source);
    tr.classList.toggle("active", active);
    let st = "—";
    if (src) st = active ? "active" : src.masked ? "masked" : src.fresh ? "fresh" : "silent";
    setAttr(tr, "data-state", st);
    setText(tr.querySelector(".age"), src && src.age_s !== null ? `${fmt(src.age_s)} s` : "—");
    setText(tr.querySelector(".st"), st);
  }
}

function renderPad(pad) {
  setText($("pad-connected"), pad ? (pad.connected ? "yes" : "no") : "—");
  setAttr($("pad-connected"), "data-tone", pad && pad.connected ? "good" : "off");
  setText($("pad-layout"), pad && pad.layout ? pad.layout : "—");
  setText($("pad-deadman"), pad ? (pad.deadman ? "held" : "released") : "—");
  setAttr($("pad-deadman"), "data-tone", pad && pad.deadman ? "warn" : "off");
}

function renderBase(base) {
  const tw = base && base.twist;
  setText($("base-twist"), tw ? `${signed(tw.linear_x)} m/s  ${signed(tw.angular_z)} rad/s` : "stopped");
  // Goal speeds in counts/s, one fixed-width slot per wheel (two or four: the profile says).
  const box = $("wheels");
  const wheels = base ? base.wheels : [];
  if (box.children.length !== wheels.length || !wheels.length) {
    box.replaceChildren();
    for (const w of wheels) {
      const slot = document.createElement("span");
      slot.className = "wheel";
      slot.title = `${w.name} (id ${w.id}): goal speed, counts/s`;
      box.append(slot);
    }
    if (!wheels.length) box.textContent = "—";
  }
  wheels.forEach((w, i) => {
    setText(box.children[i], `${w.name} ${w.excluded ? "excluded" : signed(w.goal_counts_s, 0)}`);
  });
}

let lastEvents = null;

function renderEvents(events) {
  const key = events ? JSON.stringify(events) : "";
  if (key === lastEvents) return;
  lastEvents = key;
  const box = $("events");
  box.replaceChildren();
  if (!events || !events.length) {
    const li = document.createElement("li");
    li.className = "muted";
    li.textContent = events ? "no stalls" : "—";
    box.append(li);
    return;
  }
  for (const ev of events.slice(-5).reverse()) {
    const li = document.createElement("li");
    const head = document.createElement("b");
    head.textContent = `${ev.joint} stalled, ${fmt(ev.error_deg)}° off`;
    const body = document.createElement("span");
    body.textContent = ev.diagnosis;
    li.append(head, body);
    box.append(li);
  }
}

// -- commands ------------------------------------------------------------------------------

async function run(frame, what) {
  try {
    return await link.command(frame);
  } catch (err) {
    toast(`${what}: ${errorText(err)}`);
    return null;
  }
}

// The E-stop acts on press, not on release, and goes out on BOTH paths at once: the
// socket and plain HTTP, so a half-dead socket cannot swallow it. Engaging twice is
// harmless. Its look follows the daemon's state, never the press.
async function engage() {
  const paths = [api("POST", "/api/estop", { engaged: true })];
  if (link.live) paths.push(link.command({ type: "estop", engaged: true }));
  try {
    await Promise.any(paths);
  } catch (err) {
    toast(`E-stop NOT confirmed: ${errorText(err.errors ? err.errors[0] : err)}`);
  }
}
let pressedAt = -Infinity; // the click that follows a pointerdown is the same press
$("estop").addEventListener("pointerdown", (ev) => {
  ev.preventDefault();
  pressedAt = performance.now();
  engage();
});
$("estop").addEventListener("click", () => {
  if (performance.now() - pressedAt > 1500) engage(); // Enter or Space on the focused button
  pressedAt = -Infinity;
});
// Escape engages from anywhere on a keyboard (a laptop operator's reflex).
document.addEventListener("keydown", (ev) => {
  if (ev.key === "Escape" && !ev.repeat) engage();
});
$("estop-release").addEventListener("click", () => run({ type: "estop", engaged: false }, "release"));
$("torque-on").addEventListener("click", () => run({ type: "torque", enabled: true }, "torque on"));
$("torque-off").addEventListener("click", () => run({ type: "torque", enabled: false }, "torque off"));
$("init").addEventListener("click", () => run({ type: "init" }, "init"));
$("heal").addEventListener("click", async () => {
  setText($("heal-result"), "running…");
  const result = await run({ type: "heal" }, "heal");
  setText($("heal-result"), result ? `${result.result}${result.auto_home ? `, auto-home ${result.auto_home}` : ""}` : "");
});

// -- taught poses (HTTP: they live in a file, not in the state frame) -------------------

let posesTimer = null;

async function refreshPoses() {
  clearTimeout(posesTimer);
  try {
    const data = await api("GET", "/api/arm/poses");
    renderPoses(data.poses);
  } catch (err) {
    renderPoses(null, errorText(err));
  }
  posesTimer = setTimeout(() => app.connected && refreshPoses(), POSES_REFRESH_MS);
}

function renderPoses(poses, error) {
  const box = $("poses");
  const key = JSON.stringify(poses ? poses.map((p) => [p.name, fmt(p.distance_rad, 2)]) : error);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  box.replaceChildren();
  if (!poses || !poses.length) {
    const li = document.createElement("li");
    li.className = "muted";
    li.textContent = error ? `cannot list poses: ${error}` : "none taught yet";
    box.append(li);
    return;
  }
  for (const pose of poses) {
    const li = document.createElement("li");
    li.dataset.pose = pose.name;
    const name = document.createElement("span");
    name.className = "pname";
    name.textContent = pose.name;
    const dist = document.createElement("span");
    dist.className = "num muted";
    dist.title = "largest joint travel from here";
    dist.textContent = pose.distance_rad === null ? "" : `Δ ${fmt((pose.distance_rad * 180) / Math.PI)}°`;
    const go = document.createElement("button");
    go.type = "button";
    go.className = "btn pose-go";
    go.textContent = "Go";
    go.disabled = !app.armed;
    go.addEventListener("click", () => run({ type: "pose_go", name: pose.name }, `pose ${pose.name}`));
    const del = document.createElement("button");
    del.type = "button";
    del.className = "btn pose-del";
    del.textContent = "Delete";
    del.disabled = !app.connected;
    confirmTap(del, "Sure?", async () => {
      try {
        await api("DELETE", `/api/arm/poses/${encodeURIComponent(pose.name)}`);
      } catch (err) {
        toast(`delete ${pose.name}: ${errorText(err)}`);
      }
      refreshPoses();
    });
    li.append(name, dist, go, del);
    box.append(li);
  }
}

$("pose-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const input = $("pose-name");
  const name = input.value.trim();
  if (!input.checkValidity() || !name) {
    toast("pose names are 1-40 letters, digits, _ or -");
    return;
  }
  try {
    await api("PUT", `/api/arm/poses/${encodeURIComponent(name)}`, {});
    input.value = "";
    toast(`saved pose ${name}`, "good");
  } catch (err) {
    toast(`save ${name}: ${errorText(err)}`);
  }
  refreshPoses();
});

render();
link.connect();
