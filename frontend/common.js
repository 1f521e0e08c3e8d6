// What the studio page (app.js) and the admin page (admin.js) both need: the REST call, the DOM builder, the toast.
// Plain ES module served from /static like the pages' own scripts; no build step.

export const $ = (id) => document.getElementById(id);

/** Attribute names as people read them: "step_size" -> "step size". */
export const pretty = (name) => name.replace(/_/g, " ");

const BUSY = new Set([429, 503]);
const PATIENCE = { tries: 4, longestWait: 15 }; // a longer Retry-After (e.g. wrong admin tokens) is shown at once

/** Seconds a busy answer (429 / 503) asks the client to wait, or null if it is not one worth waiting for. */
function busyWait(res) {
  const seconds = Number(res.headers.get("Retry-After"));
  return BUSY.has(res.status) && seconds > 0 && seconds <= PATIENCE.longestWait ? seconds : null;
}

/** fetch, waiting out a busy server: the server refuses heavy requests it has no room for before doing any of
 * their work (429 / 503 with Retry-After), so sending the same request again is safe. */
export async function patientFetch(path, options = {}) {
  for (let attempt = 1; ; attempt += 1) {
    const res = await fetch(path, options);
    const wait = busyWait(res);
    if (wait === null || attempt >= PATIENCE.tries) return res;
    toast(`The server is busy: trying again in ${wait} s…`, "info");
    await new Promise((resolve) => { setTimeout(resolve, wait * 1000); });
  }
}

/** JSON in and out; a failed call throws an Error whose message is the server's one-sentence `detail`. */
export async function api(path, options = {}) {
  let res;
  try {
    res = await patientFetch(path, { ...options, headers: { "Content-Type": "application/json", ...options.headers } });
  } catch {
    throw Object.assign(new Error("The server cannot be reached. Is `rba serve` running?"), { status: 0 });
  }
  let body = null;
  try { body = await res.json(); } catch { /* empty or not JSON */ }
  if (!res.ok) {
    const detail = body && typeof body.detail === "string" ? body.detail : `${res.status} ${res.statusText}`;
    throw Object.assign(new Error(detail), { status: res.status });
  }
  return body;
}

/** One element: `class`, `dataset`, `on<event>` handlers and attributes (null/undefined/false left out). */
export const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (v !== undefined && v !== null && v !== false) node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) node.append(c);
  return node;
};

let toastTimer = null;
/** Show `message` in the page's #toast; an "info" one is styled lighter and goes sooner than an error. */
export function toast(message, kind = "error") {
  $("toast-text").textContent = message;
  $("toast").className = `toast ${kind === "info" ? "info" : ""}`;
  $("toast").hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => { $("toast").hidden = true; }, kind === "info" ? 4000 : 9000);
}
/** Take the toast away (e.g. an error that the next step has made stale). */
export function hideToast() {
  clearTimeout(toastTimer);
  $("toast").hidden = true;
}
$("toast-close")?.addEventListener("click", hideToast);
