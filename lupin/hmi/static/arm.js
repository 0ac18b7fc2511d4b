// Per-joint arm sliders, the rate slider and the gripper: ARMED, NOT LIVE.
//
// The runbook's slider rules, each one here for a reason:
// * A slider is disabled until the socket is up, the E-stop is clear and the
//   daemon says torque is "on". Torque reads "unknown" after every reload until
//   a state frame says otherwise, and unknown blocks, so a reload can never
//   re-arm a slider on its own.
// * Before first touch the thumb tracks the MEASURED position, so it never
//   starts from a phantom 0 and a release without a drag moves nothing.
// * Nothing is sent while dragging; the release (change event) sends one joint
//   command with the rate slider's speed. The daemon owns the motion.
// * The badge is the daemon's closed-loop status (measured convergence), never
//   the reply's ack: a reply comes back the instant the target is accepted.

import { $, errorText, fmt, setAttr, setDisabled, setText, toast } from "./ui.js";

function place(mark, window, value) {
  if (value === null || value === undefined) {
    mark.hidden = true;
    return;
  }
  const [lo, hi] = window;
  const f = Math.min(1, Math.max(0, (value - lo) / (hi - lo)));
  mark.hidden = false;
  mark.style.left = `${(f * 100).toFixed(2)}%`;
}

class Slider {
  // One range input whose thumb tracks a value until the operator grabs it.
  constructor(input, onRelease) {
    this.input = input;
    this.touched = false; // grabbed since last armed: stop tracking measurement
    this.dragging = false;
    input.addEventListener("pointerdown", () => {
      this.touched = true;
      this.dragging = true;
    });
    input.addEventListener("input", () => {
      this.touched = true;
      this.dragging = true;
    });
    input.addEventListener("change", () => {
      this.dragging = false;
      onRelease(Number(input.value));
    });
    // A tap on the thumb that changes nothing fires no change event: end the drag anyway.
    for (const type of ["pointerup", "pointercancel", "blur"]) {
      input.addEventListener(type, () => {
        this.dragging = false;
      });
    }
  }

  show(value) {
    if (this.dragging || value === null || value === undefined) return;
    const text = String(Math.round(value));
    if (this.input.value !== text) this.input.value = text;
  }

  reseed() {
    this.touched = false;
    this.dragging = false;
  }
}

// A stale reading shown only once it persists: one missed bus read is not news.
const STALE_SHOW_MS = 500;
class Persistent {
  constructor() {
    this.since = null;
  }

  seen(flag, now) {
    if (!flag) this.since = null;
    else if (this.since === null) this.since = now;
    return flag && now - this.since >= STALE_SHOW_MS;
  }
}

class JointRow {
  constructor(info, parent, template, onMove) {
    this.info = info;
    const node = template.content.firstElementChild.cloneNode(true);
    node.dataset.joint = info.name;
    this.node = node;
    this.badge = node.querySelector(".badge");
    this.readout = node.querySelector(".readout");
    this.diag = node.querySelector(".diag");
    this.meas = node.querySelector(".m-meas");
    this.tgt = node.querySelector(".m-tgt");
    const input = node.querySelector("input");
    const [lo, hi] = info.window_deg;
    input.min = String(lo);
    input.max = String(hi);
    input.dataset.testid = `slider-${info.name}`;
    input.setAttribute("aria-label", `${info.name} target, degrees`);
    this.badge.dataset.testid = `badge-${info.name}`;
    node.querySelector(".jname").textContent = info.name;
    node.querySelector(".lo").textContent = `${lo}°`;
    node.querySelector(".hi").textContent = `${hi}°`;
    this.slider = new Slider(input, (value) => onMove(this, value));
    this.stale = new Persistent();
    parent.append(node);
  }

  update(js, armed, stall, now) {
    const status = js.excluded ? "excluded" : js.status;
    setText(this.badge, status);
    setAttr(this.badge, "data-status", status);
    this.node.classList.toggle("stale", this.stale.seen(js.stale, now));
    const tgt = js.target_deg ?? js.commanded_deg;
    setText(this.readout, `${fmt(js.position_deg)}° → ${fmt(tgt)}°`);
    place(this.meas, this.info.window_deg, js.position_deg);
    place(this.tgt, this.info.window_deg, tgt);
    const why = js.excluded || (js.status === "stalled" && stall ? stall.diagnosis : "");
    this.diag.hidden = !why;
    setText(this.diag, why || "");
    const usable = armed && !js.excluded;
    if (!usable) this.slider.reseed();
    setDisabled(this.slider.input, !usable);
    // Untouched: the thumb is the measured angle. Touched: the daemon's target,
    // so a preset or the pad moving this joint is still shown truthfully.
    this.slider.show(this.slider.touched ? tgt ?? js.position_deg : js.position_deg);
  }
}

export class ArmPanel {
  constructor(link) {
    this.link = link;
    this.rows = new Map();
    this.rate = $("rate");
    this.rateOut = $("rate-out");
    this.gripperInfo = null;
    this.gripperStale = new Persistent();
    this.rateSeeded = false;
    this.rate.addEventListener("input", () => setText(this.rateOut, this.rate.value));
    setText(this.rateOut, this.rate.value);
    const grip = $("gripper-slider");
    this.grip = new Slider(grip, (value) => this.moveGripper(value));
    $("gripper-open").addEventListener("click", () => this.moveGripper(this.gripperInfo.hmi_open_deg));
    $("gripper-close").addEventListener("click", () =>
      this.moveGripper(this.gripperInfo.hmi_closed_deg),
    );
  }

  speed() {
    return Number(this.rate.value);
  }

  build(info) {
    if (!this.rateSeeded) {
      // The daemon's default, once: after that the rate is the operator's choice.
      this.rate.value = String(Math.round(info.default_speed_deg_s));
      setText(this.rateOut, this.rate.value);
      this.rateSeeded = true;
    }
    const box = $("joints");
    box.replaceChildren();
    this.rows.clear();
    const template = $("joint-tpl");
    for (const j of info.joints) {
      if (j.is_gripper) continue;
      this.rows.set(j.name, new JointRow(j, box, template, (row, v) => this.moveJoint(row, v)));
    }
    this.buildGripper(info);
  }

  buildGripper(info) {
    const g = info.gripper;
    this.gripperInfo = g;
    $("gripper").hidden = !g;
    if (!g) return;
    const lo = Math.min(g.hmi_open_deg, g.hmi_closed_deg);
    const hi = Math.max(g.hmi_open_deg, g.hmi_closed_deg);
    const input = $("gripper-slider");
    input.min = String(lo);
    input.max = String(hi);
    // The open end is whatever the daemon says: on the runbook's jaw it is -30, the left end.
    const openLeft = g.hmi_open_deg === lo;
    setText($("gripper-left"), `${openLeft ? "open" : "closed"} ${lo}°`);
    setText($("gripper-right"), `${openLeft ? "closed" : "open"} ${hi}°`);
    setText($("gripper-name"), g.joint);
    $("gripper-badge").dataset.testid = `badge-${g.joint}`;
    // Seeding the thumb needs the joint angles of the open and closed ends.
    this.gripperMapped = Number.isFinite(g.open_rad) && Number.isFinite(g.closed_rad);
    const note = $("gripper-note");
    note.hidden = this.gripperMapped;
    // No phantom thumb: without the mapping the slider is not shown at all.
    $("gripper-scale").hidden = !this.gripperMapped;
    setText($("gripper-open"), `Open (${g.hmi_open_deg}°)`);
    setText($("gripper-close"), `Close (${g.hmi_closed_deg}°)`);
    note.textContent = this.gripperMapped
      ? ""
      : "The daemon does not publish the jaw's open/closed joint angles, so the slider " +
        "cannot be seeded from the measured jaw: use Open and Close.";
  }

  // Measured jaw angle (joint degrees) on the HMI's open..closed scale.
  gripperHmi(jointDeg) {
    const g = this.gripperInfo;
    if (!this.gripperMapped || jointDeg === null || jointDeg === undefined) return null;
    const rad = (jointDeg * Math.PI) / 180;
    const f = (rad - g.open_rad) / (g.closed_rad - g.open_rad);
    return g.hmi_open_deg + f * (g.hmi_closed_deg - g.hmi_open_deg);
  }

  // Everything locked and re-seeded: no connection, no state, or a state that lacks the joint.
  lock(row) {
    row.slider.reseed();
    setDisabled(row.slider.input, true);
  }

  update(state, connected) {
    const torque = connected ? state.torque : "unknown";
    const armed = connected && !state.estop && torque === "on" && state.seeded;
    const stalls = new Map();
    for (const ev of state.events || []) stalls.set(ev.joint, ev); // newest last
    const now = performance.now();
    const byName = new Map(state.joints.map((js) => [js.name, js]));
    for (const [name, row] of this.rows) {
      const js = byName.get(name);
      if (js) row.update(js, armed, stalls.get(name), now);
      else this.lock(row);
    }
    const grip = this.gripperInfo && byName.get(this.gripperInfo.joint);
    if (grip) this.updateGripper(grip, armed, now);
    else {
      this.lock({ slider: this.grip });
      for (const id of ["gripper-open", "gripper-close"]) setDisabled($(id), true);
    }
    setDisabled($("init"), !armed);
    setDisabled(this.rate, !connected);
    setDisabled(
      $("torque-on"),
      !connected || state.estop || !state.seeded || torque === "on" || torque === "enabling",
    );
    setDisabled($("torque-off"), !connected || torque === "off");
    let gate = "armed";
    if (!connected) gate = "locked: not connected";
    else if (state.estop) gate = "locked: E-stop engaged";
    else if (!state.seeded) gate = "locked: joints not seeded";
    else if (torque !== "on") gate = `locked: torque ${torque}`;
    setText($("arm-gate"), gate);
    setAttr($("arm-gate"), "data-armed", String(armed));
    return armed;
  }

  updateGripper(js, armed, now) {
    const badge = $("gripper-badge");
    const status = js.excluded ? "excluded" : js.status;
    $("gripper").classList.toggle("stale", this.gripperStale.seen(js.stale, now));
    setText(badge, status);
    setAttr(badge, "data-status", status);
    const hmi = this.gripperHmi(js.position_deg);
    setText(
      $("gripper-readout"),
      hmi === null ? `jaw ${fmt(js.position_deg)}°` : `${fmt(hmi)}° (jaw ${fmt(js.position_deg)}°)`,
    );
    const usable = armed && !js.excluded;
    for (const id of ["gripper-open", "gripper-close"]) setDisabled($(id), !usable);
    const slidable = usable && this.gripperMapped;
    if (!slidable) this.grip.reseed();
    setDisabled(this.grip.input, !slidable);
    if (!this.grip.touched) this.grip.show(hmi);
  }

  async moveJoint(row, angle) {
    try {
      await this.link.command({ type: "joint", joint: row.info.name, angle_deg: angle, speed_deg_s: this.speed() });
    } catch (err) {
      row.slider.reseed(); // nothing moved: show the truth again
      toast(`${row.info.name}: ${errorText(err)}`);
    }
  }

  async moveGripper(angle) {
    this.grip.touched = true;
    try {
      await this.link.command({ type: "gripper", angle_deg: angle, speed_deg_s: this.speed() });
      this.grip.show(angle);
    } catch (err) {
      this.grip.reseed();
      toast(`gripper: ${errorText(err)}`);
    }
  }
}
