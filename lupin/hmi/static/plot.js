// A live trace of one joint: commanded vs measured (and the target) over the last 10 s.
//
// Plain canvas, no library. The y axis is the joint's window from /api/robot,
// so the scale never jumps as the arm moves; x is the daemon's own clock.

import { $ } from "./ui.js";

const SPAN_S = 10;
const COLORS = { grid: "#263040", label: "#8b96a8", cmd: "#4da3ff", meas: "#3ddc84", tgt: "#f5a524" };

export class Trace {
  constructor() {
    this.canvas = $("plot");
    this.select = $("plot-joint");
    this.samples = []; // {t, joints: {name: [measured, commanded, target]}}
    this.windows = new Map();
    this.pending = false;
    this.select.addEventListener("change", () => this.request());
    new ResizeObserver(() => this.resize()).observe(this.canvas);
  }

  build(info) {
    const previous = this.select.value;
    this.select.replaceChildren();
    for (const j of info.joints) {
      this.windows.set(j.name, j.window_deg);
      const opt = document.createElement("option");
      opt.value = j.name;
      opt.textContent = j.name;
      this.select.append(opt);
    }
    if (previous && this.windows.has(previous)) this.select.value = previous;
    this.samples = [];
    this.request();
  }

  push(state) {
    const joints = {};
    for (const js of state.joints) joints[js.name] = [js.position_deg, js.commanded_deg, js.target_deg];
    this.samples.push({ t: state.t, joints });
    const cutoff = state.t - SPAN_S - 1;
    let drop = 0;
    while (drop < this.samples.length && this.samples[drop].t < cutoff) drop += 1;
    if (drop) this.samples.splice(0, drop);
    this.request();
  }

  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(this.canvas.clientWidth * dpr);
    const h = Math.round(this.canvas.clientHeight * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    this.request();
  }

  request() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.draw();
    });
  }

  draw() {
    const ctx = this.canvas.getContext("2d");
    const dpr = window.devicePixelRatio || 1;
    const W = this.canvas.width;
    const H = this.canvas.height;
    ctx.clearRect(0, 0, W, H);
    const name = this.select.value;
    const window_ = this.windows.get(name);
    if (!window_ || !W || !H) return;
    const [lo, hi] = window_;
    const padL = 40 * dpr;
    const padR = 16 * dpr;
    const padT = 8 * dpr;
    const padB = 18 * dpr;
    const now = this.samples.length ? this.samples[this.samples.length - 1].t : 0;
    const x = (t) => padL + ((t - (now - SPAN_S)) / SPAN_S) * (W - padL - padR);
    const y = (v) => padT + (1 - (v - lo) / (hi - lo)) * (H - padT - padB);

    ctx.font = `${11 * dpr}px system-ui, sans-serif`;
    ctx.lineWidth = 1 * dpr;
    ctx.strokeStyle = COLORS.grid;
    ctx.fillStyle = COLORS.label;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    const ticks = [lo, hi];
    if (lo < 0 && hi > 0) ticks.push(0);
    for (const v of ticks) {
      ctx.beginPath();
      ctx.moveTo(padL, y(v));
      ctx.lineTo(W - padR, y(v));
      ctx.stroke();
      ctx.fillText(`${v}°`, padL - 6 * dpr, y(v));
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "alphabetic";
    for (let s = 0; s <= SPAN_S; s += 2) {
      const px = x(now - SPAN_S + s);
      ctx.beginPath();
      ctx.moveTo(px, padT);
      ctx.lineTo(px, H - padB);
      ctx.stroke();
      ctx.textAlign = s === SPAN_S ? "right" : "center";
      ctx.fillText(s === SPAN_S ? "now" : `−${SPAN_S - s}s`, s === SPAN_S ? W - 2 * dpr : px, H - 4 * dpr);
    }

    ctx.save();
    ctx.beginPath();
    ctx.rect(padL, padT, W - padL - padR, H - padT - padB);
    ctx.clip();
    const line = (index, color, width, dash) => {
      ctx.strokeStyle = color;
      ctx.lineWidth = width * dpr;
      ctx.setLineDash(dash.map((d) => d * dpr));
      ctx.beginPath();
      let open = false;
      for (const s of this.samples) {
        const v = s.joints[name] ? s.joints[name][index] : null;
        if (v === null || v === undefined) {
          open = false; // a gap in the data is a gap in the line
          continue;
        }
        if (open) ctx.lineTo(x(s.t), y(v));
        else ctx.moveTo(x(s.t), y(v));
        open = true;
      }
      ctx.stroke();
    };
    line(2, COLORS.tgt, 1, [3, 3]);
    line(1, COLORS.cmd, 2, []);
    line(0, COLORS.meas, 2, []);
    ctx.restore();
    ctx.setLineDash([]);
  }
}
