// The drive pad: hold to drive, release to stop.
//
// While a pointer holds the pad it sends a manual twist at 10 Hz; on release it
// sends exactly one zero twist (so the stop is immediate) and then NOTHING. No
// zero stream: silence is what lets the mux time the source out and hand the
// base to a lower-priority source or to the base's own command timeout (the
// runbook's dead-man rule, the same one the pad teleop follows).

import { $, setText, signed } from "./ui.js";

const SEND_HZ = 10;
const DEADZONE = 0.06; // a tap in the middle must not creep

export class DrivePad {
  constructor(link) {
    this.link = link;
    this.pad = $("pad");
    this.knob = $("knob");
    this.maxLin = $("max-lin");
    this.maxAng = $("max-ang");
    this.sending = $("drive-sending");
    this.enabled = null; // neither: the first setEnabled() always paints
    this.pointer = null; // the id of the pointer that holds the pad
    this.vec = { x: 0, y: 0 };
    this.timer = null;

    for (const [input, out] of [[this.maxLin, "max-lin-out"], [this.maxAng, "max-ang-out"]]) {
      const show = () => setText($(out), Number(input.value).toFixed(2));
      input.addEventListener("input", show);
      show();
    }
    this.pad.addEventListener("pointerdown", (ev) => this.down(ev));
    this.pad.addEventListener("pointermove", (ev) => this.move(ev));
    for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) {
      this.pad.addEventListener(type, (ev) => {
        if (ev.pointerId === this.pointer) this.release();
      });
    }
    this.pad.addEventListener("contextmenu", (ev) => ev.preventDefault());
    // A hidden tab or a lost window cannot keep driving the robot.
    document.addEventListener("visibilitychange", () => document.hidden && this.release());
    window.addEventListener("blur", () => this.release());
    this.setEnabled(false);
  }

  setEnabled(enabled) {
    if (enabled === this.enabled) return;
    this.enabled = enabled;
    this.pad.classList.toggle("disabled", !enabled);
    this.pad.setAttribute("aria-disabled", String(!enabled));
    this.maxLin.disabled = !enabled;
    this.maxAng.disabled = !enabled;
    if (!enabled) this.release();
  }

  down(ev) {
    if (!this.enabled || this.pointer !== null || ev.button > 0) return;
    ev.preventDefault();
    this.pointer = ev.pointerId;
    this.pad.setPointerCapture(ev.pointerId);
    this.pad.classList.add("held");
    this.aim(ev);
    this.sendTwist();
    this.timer = setInterval(() => this.sendTwist(), 1000 / SEND_HZ);
  }

  move(ev) {
    if (ev.pointerId !== this.pointer) return;
    ev.preventDefault();
    this.aim(ev);
  }

  aim(ev) {
    const box = this.pad.getBoundingClientRect();
    const radius = box.width / 2;
    let x = (ev.clientX - (box.left + radius)) / radius;
    let y = (ev.clientY - (box.top + box.height / 2)) / radius;
    const length = Math.hypot(x, y);
    if (length > 1) {
      x /= length;
      y /= length;
    }
    this.vec = { x, y };
    this.knob.style.transform = `translate(${x * radius * 0.78}px, ${y * radius * 0.78}px)`;
  }

  twist() {
    const shape = (v) => (Math.abs(v) < DEADZONE ? 0 : (v - Math.sign(v) * DEADZONE) / (1 - DEADZONE));
    // Screen up is forward; screen left turns left (counter-clockwise, +angular_z).
    return {
      linear_x: -shape(this.vec.y) * Number(this.maxLin.value),
      linear_y: 0,
      angular_z: -shape(this.vec.x) * Number(this.maxAng.value),
    };
  }

  sendTwist() {
    const t = this.twist();
    this.link.send({ type: "twist", source: "manual", ...t });
    setText(this.sending, `${signed(t.linear_x)} m/s  ${signed(t.angular_z)} rad/s`);
  }

  release() {
    if (this.pointer === null) return;
    clearInterval(this.timer);
    this.timer = null;
    const held = this.pointer;
    this.pointer = null; // first: releasing the capture fires lostpointercapture
    if (this.pad.hasPointerCapture(held)) this.pad.releasePointerCapture(held);
    this.vec = { x: 0, y: 0 };
    this.pad.classList.remove("held");
    this.knob.style.transform = "";
    // One zero so the stop is immediate, then silence (the mux timeout does the rest).
    this.link.send({ type: "twist", source: "manual", linear_x: 0, linear_y: 0, angular_z: 0 });
    setText(this.sending, "—");
  }
}
