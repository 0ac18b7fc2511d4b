// Small DOM helpers shared by the panels: lookups, number formatting, toasts.

export const $ = (id) => document.getElementById(id);

export function fmt(value, digits = 1) {
  return value === null || value === undefined || Number.isNaN(value) ? "—" : value.toFixed(digits);
}

export function signed(value, digits = 2) {
  if (value === null || value === undefined) return "—";
  const s = value.toFixed(digits);
  return value >= 0 ? `+${s}` : s.replace("-", "−");
}

// Set text only when it changed: state frames arrive at 20 Hz and most fields are steady.
export function setText(node, text) {
  if (node.textContent !== text) node.textContent = text;
}

export function setAttr(node, name, value) {
  if (node.getAttribute(name) !== value) node.setAttribute(name, value);
}

export function setDisabled(node, disabled) {
  if (node.disabled !== disabled) node.disabled = disabled;
}

const TOAST_MS = 6000;

// A reply's error, a refused frame or a failed fetch: shown, never swallowed.
export function toast(message, tone = "bad") {
  const box = $("toasts");
  const item = document.createElement("div");
  item.className = "toast";
  item.dataset.tone = tone;
  item.setAttribute("role", tone === "bad" ? "alert" : "status");
  item.textContent = message;
  item.addEventListener("click", () => item.remove());
  box.append(item);
  while (box.children.length > 4) box.firstElementChild.remove();
  setTimeout(() => item.remove(), TOAST_MS);
}

export function errorText(error) {
  if (!error) return "unknown error";
  if (typeof error === "string") return error;
  if (error.message) return error.code ? `${error.message} (${error.code})` : error.message;
  return String(error);
}

// A button that needs a second tap within a few seconds: for Delete, never a blocking dialog.
export function confirmTap(button, label, action) {
  let armed = null;
  const original = button.textContent;
  button.addEventListener("click", () => {
    if (armed) {
      clearTimeout(armed);
      armed = null;
      button.textContent = original;
      button.classList.remove("confirming");
      action();
      return;
    }
    button.textContent = label;
    button.classList.add("confirming");
    armed = setTimeout(() => {
      armed = null;
      button.textContent = original;
      button.classList.remove("confirming");
    }, 3000);
  });
}
