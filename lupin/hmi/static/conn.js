// The one WebSocket to the daemon (state in, twists and commands out) and the HTTP helper.
//
// The daemon is the only source of truth: this module keeps no robot state of
// its own. It reconnects with capped exponential backoff, treats a socket that
// stops delivering state frames as dead (a half-open TCP link on Wi-Fi looks
// "open" for minutes), and matches command replies to their ids.

const PROTOCOL = "lupin.v1";
const BACKOFF_MIN_MS = 500;
const BACKOFF_MAX_MS = 8000;
const REPLY_TIMEOUT_MS = 15000;
const HELLO_TIMEOUT_MS = 6000; // the daemon greets at once (after auth, which it gives 5 s)
const TOKEN_KEY = "lupin.token";

// A token given as /#token=... is remembered for this browser and scrubbed from the address bar.
export function token() {
  const match = /(?:^#|&)token=([^&]+)/.exec(location.hash);
  if (match) {
    localStorage.setItem(TOKEN_KEY, decodeURIComponent(match[1]));
    history.replaceState(null, "", location.pathname + location.search);
  }
  return localStorage.getItem(TOKEN_KEY);
}

export function forgetToken() {
  localStorage.removeItem(TOKEN_KEY);
}

export function setToken(value) {
  if (value) localStorage.setItem(TOKEN_KEY, value);
  else forgetToken();
}

export class ApiError extends Error {
  constructor(status, body) {
    const err = body && body.error ? body.error : { code: `http_${status}`, message: `HTTP ${status}` };
    super(err.message);
    this.code = err.code;
    this.status = status;
  }
}

// fetch() with the bearer token on every request that changes something.
export async function api(method, path, body) {
  const headers = { Accept: "application/json" };
  const tok = token();
  if (tok && method !== "GET") headers.Authorization = `Bearer ${tok}`;
  const init = { method, headers, cache: "no-store" };
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const response = await fetch(path, init);
  let data = null;
  try {
    data = await response.json();
  } catch {
    data = null;
  }
  if (!response.ok) throw new ApiError(response.status, data);
  return data;
}

export class Link {
  constructor({ onHello, onState, onStatus, onError }) {
    this.onHello = onHello;
    this.onState = onState;
    this.onStatus = onStatus;
    this.onError = onError;
    this.ws = null;
    this.live = false; // hello received: the socket is usable
    this.nextId = 1;
    this.pending = new Map();
    this.attempt = 0;
    this.lastFrame = 0;
    this.staleMs = 2000;
    this.retryTimer = null;
    this.watchdog = setInterval(() => this.checkStale(), 500);
  }

  url() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    return `${scheme}://${location.host}/api/ws`;
  }

  connect() {
    clearTimeout(this.retryTimer);
    this.retryTimer = null;
    this.onStatus("connecting");
    let ws;
    try {
      ws = new WebSocket(this.url(), [PROTOCOL]);
    } catch (err) {
      this.scheduleRetry(String(err));
      return;
    }
    this.ws = ws;
    ws.addEventListener("open", () => {
      // An upgrade that never says hello is as dead as one that never opened.
      this.helloTimer = setTimeout(() => {
        if (ws === this.ws && !this.live) {
          this.closed(ws, { code: 4000 });
          ws.close();
        }
      }, HELLO_TIMEOUT_MS);
      const tok = token();
      // The daemon wants the token as the first frame; without one it answers ok anyway.
      if (tok) ws.send(JSON.stringify({ type: "auth", token: tok }));
    });
    ws.addEventListener("message", (ev) => this.receive(ev.data));
    ws.addEventListener("close", (ev) => this.closed(ws, ev));
    ws.addEventListener("error", () => {
      /* the close event follows and does the work */
    });
  }

  receive(text) {
    let frame;
    try {
      frame = JSON.parse(text);
    } catch {
      return;
    }
    this.lastFrame = performance.now();
    switch (frame.type) {
      case "hello":
        clearTimeout(this.helloTimer);
        this.live = true;
        this.attempt = 0;
        this.staleMs = Math.max(2000, (10 * 1000) / (frame.state_hz || 1));
        this.onHello(frame);
        this.onStatus("connected");
        break;
      case "state":
        if (this.live) this.onState(frame);
        break;
      case "reply":
        this.settle(frame);
        break;
      case "error":
        this.onError(frame.error);
        break;
      default:
        break;
    }
  }

  settle(frame) {
    const waiter = this.pending.get(frame.id);
    if (!waiter) return;
    this.pending.delete(frame.id);
    clearTimeout(waiter.timer);
    if (frame.ok) waiter.resolve(frame.result);
    else waiter.reject(frame.error || { message: "refused" });
  }

  closed(ws, ev) {
    if (ws !== this.ws) return;
    clearTimeout(this.helloTimer);
    this.ws = null;
    const wasLive = this.live;
    this.live = false;
    for (const waiter of this.pending.values()) {
      clearTimeout(waiter.timer);
      waiter.reject({ code: "disconnected", message: "connection lost before the reply" });
    }
    this.pending.clear();
    if (ev.code === 4401) {
      this.onStatus("unauthorized");
      return; // retrying with the same (missing or wrong) token cannot help
    }
    this.scheduleRetry(wasLive ? "connection lost" : "daemon unreachable");
  }

  scheduleRetry(why) {
    const base = Math.min(BACKOFF_MAX_MS, BACKOFF_MIN_MS * 2 ** this.attempt);
    const delay = base / 2 + Math.random() * (base / 2); // jitter: many tablets, one daemon
    this.attempt += 1;
    this.retryAt = performance.now() + delay;
    this.onStatus("retrying", { why, delay });
    this.retryTimer = setTimeout(() => this.connect(), delay);
  }

  // A socket that is open but silent is as good as closed: drop it and reconnect.
  checkStale() {
    if (this.live && performance.now() - this.lastFrame > this.staleMs && this.ws) {
      const ws = this.ws;
      this.closed(ws, { code: 4000 });
      ws.close();
    }
  }

  retryNow() {
    if (this.ws) return;
    this.attempt = 0;
    this.connect();
  }

  // Fire and forget (twists): true if it went out.
  send(frame) {
    if (!this.live || !this.ws || this.ws.readyState !== WebSocket.OPEN) return false;
    this.ws.send(JSON.stringify(frame));
    return true;
  }

  // A command with an id; resolves with the reply's result, rejects with its error.
  command(frame) {
    return new Promise((resolve, reject) => {
      const id = this.nextId++;
      if (!this.send({ ...frame, id })) {
        reject({ code: "disconnected", message: "not connected to the daemon" });
        return;
      }
      const timer = setTimeout(() => {
        this.pending.delete(id);
        reject({ code: "timeout", message: `no reply to ${frame.type} in ${REPLY_TIMEOUT_MS / 1000} s` });
      }, REPLY_TIMEOUT_MS);
      this.pending.set(id, { resolve, reject, timer });
    });
  }
}
