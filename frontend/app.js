// RBA Studio page: start a session, watch its clip, answer "more / less <attribute>" or "this is it".
// Plain ES module, no build step. Talks only to the REST API the scripted users use too.

import { $, api, el, pretty, toast } from "./common.js";

const els = {
  domain: $("domain"), method: $("method"), setup: $("setup"), start: $("start"),
  video: $("video"), overlay: $("overlay"), overlayText: $("overlay-text"),
  welcome: $("welcome"), welcomeStart: $("welcome-start"), welcomeNote: $("welcome-note"),
  stepBadge: $("step-badge"), replayBanner: $("replay-banner"), replayText: $("replay-text"), replayBack: $("replay-back"),
  measured: $("measured"), attributes: $("attributes"), satisfied: $("satisfied"),
  controlsTitle: $("controls-title"), controlsHint: $("controls-hint"), sessionMeta: $("session-meta"),
  done: $("done"), doneTitle: $("done-title"), doneText: $("done-text"), again: $("again"),
  history: $("history"), historyEmpty: $("history-empty"), historyCount: $("history-count"), keyList: $("key-list"),
};

const state = {
  domains: [],
  session: null,
  busy: false,
  viewing: null, // a history entry being re-watched, or null for the current clip
  shownUrl: null,
};

// ---------------------------------------------------------------- small helpers
const fmt = (v) => {
  if (v === undefined || v === null || Number.isNaN(v)) return "–";
  const a = Math.abs(v);
  return a >= 100 ? v.toFixed(0) : a >= 10 ? v.toFixed(1) : v.toFixed(2);
};

function overlay(text, kind = "loading") {
  if (!text) { els.overlay.classList.add("hidden"); return; }
  els.overlayText.textContent = text;
  els.overlay.classList.toggle("error", kind === "error");
  els.overlay.classList.remove("hidden");
}

function setBusy(busy) {
  state.busy = busy;
  document.body.dataset.state = busy ? "busy" : (state.session ? "ready" : "idle");
  const active = state.session && state.session.status === "active";
  for (const b of els.attributes.querySelectorAll("button")) b.disabled = busy || !active;
  els.satisfied.disabled = busy || !active;
  els.start.disabled = busy;
}

// ---------------------------------------------------------------- domains and the setup form
function selectedDomain() { return state.domains.find((d) => d.name === els.domain.value); }

function fillMethods() {
  const d = selectedDomain();
  els.method.replaceChildren();
  for (const m of d ? d.available : []) {
    const label = `${m.method.charAt(0).toUpperCase()}${m.method.slice(1)} · ${m.rep === "onehot" ? "one-hot" : m.rep}`;
    els.method.append(el("option", { value: `${m.method}/${m.rep}` }, label));
  }
  if (d && !d.available.length) els.method.append(el("option", { value: "", disabled: true }, "not trained yet"));
  const ok = Boolean(d && d.available.length);
  els.start.disabled = !ok;
  els.welcomeStart.disabled = !ok;
  els.welcomeNote.textContent = ok ? `${pretty(d.name)}: ${d.attributes.map((a) => pretty(a.name)).join(", ")}`
    : (d && d.missing) || "";
}

async function loadDomains() {
  const body = await api("/api/domains");
  state.domains = body.domains;
  els.domain.replaceChildren(...state.domains.map((d) => el("option", { value: d.name },
    pretty(d.name) + (d.available.length ? "" : " (not built)"))));
  const first = state.domains.find((d) => d.available.length) || state.domains[0];
  if (first) els.domain.value = first.name;
  fillMethods();
}
els.domain.addEventListener("change", fillMethods);

// ---------------------------------------------------------------- sessions
async function startSession(event) {
  if (event) event.preventDefault();
  const d = selectedDomain();
  if (!d || !els.method.value) { toast(d && d.missing ? d.missing : "Pick a domain with trained models."); return; }
  const [method, rep] = els.method.value.split("/");
  setBusy(true);
  els.welcome.hidden = true;
  overlay("Starting a session…");
  try {
    const session = await api("/api/sessions", { method: "POST", body: JSON.stringify({ domain: d.name, method, rep }) });
    history.replaceState(null, "", `#session=${session.id}`);
    showSession(session, { fresh: true });
  } catch (err) {
    overlay(err.message, "error");
    toast(err.message);
    if (!state.session) els.welcome.hidden = false;
  } finally {
    setBusy(false);
  }
}
els.setup.addEventListener("submit", startSession);
els.welcomeStart.addEventListener("click", () => startSession());
els.again.addEventListener("click", () => startSession());

async function sendFeedback(payload, pressed) {
  const s = state.session;
  if (!s || state.busy || s.status !== "active") return;
  backToCurrent();
  setBusy(true);
  if (pressed) pressed.classList.add("pressed");
  overlay(payload.satisfied ? "Saving your choice…" : "Finding a behaviour that fits…");
  try {
    const next = await api(`/api/sessions/${s.id}/feedback`, { method: "POST", body: JSON.stringify({ step: s.step, ...payload }) });
    showSession(next);
  } catch (err) {
    if (err.status === 409) {
      toast(`${err.message}`, "info");
      await reloadSession();
    } else {
      toast(err.message);
      overlay(null);
    }
  } finally {
    if (pressed) pressed.classList.remove("pressed");
    setBusy(false);
  }
}

function feedback(attribute, direction, button) {
  return sendFeedback({ feedback: [{ attribute, direction }] }, button);
}

async function reloadSession() {
  if (!state.session) return;
  try { showSession(await api(`/api/sessions/${state.session.id}`)); } catch (err) { toast(err.message); }
}

async function resumeFromUrl() {
  const m = /session=([0-9a-f]{8,64})/.exec(location.hash);
  if (!m) return false;
  overlay("Resuming your session…");
  try {
    showSession(await api(`/api/sessions/${m[1]}`), { fresh: true });
    return true;
  } catch (err) {
    history.replaceState(null, "", location.pathname);
    toast(err.status === 404 ? "That session no longer exists; start a new one." : err.message);
    return false;
  }
}

// ---------------------------------------------------------------- rendering a session
function play(url, label) {
  if (state.shownUrl === url) { overlay(null); return; }
  state.shownUrl = url;
  overlay(label);
  els.video.dataset.ready = "false";
  els.video.src = url;
  els.video.load();
  const p = els.video.play();
  if (p && p.catch) p.catch(() => { /* autoplay blocked: the video still shows its first frame */ });
}

els.video.addEventListener("playing", () => { overlay(null); els.video.dataset.ready = "true"; });
els.video.addEventListener("canplay", () => { overlay(null); els.video.dataset.ready = "true"; });
els.video.addEventListener("error", () => {
  if (!state.shownUrl) return;
  overlay("The clip could not be loaded.", "error");
  toast("The clip could not be loaded; reload the page to try again.");
});

function showSession(session, { fresh = false } = {}) {
  const previous = state.session;
  state.session = session;
  els.welcome.hidden = true;
  if (fresh || !previous || previous.id !== session.id) {
    els.domain.value = session.domain;
    fillMethods();
    els.method.value = `${session.method}/${session.rep}`;
    buildControls(session);
  }
  els.video.dataset.rollout = session.clip.rollout_id;
  els.video.dataset.step = String(session.step);
  if (!state.viewing) {
    play(session.clip.url, session.clip.ready ? "Loading the clip…" : "Rendering the clip…");
  }
  renderStep(session);
  renderMeasured(session.clip, session.attributes);
  renderHistory(session);
  renderStatus(session);
  setBusy(state.busy);
}

function buildControls(session) {
  els.attributes.replaceChildren();
  els.keyList.replaceChildren();
  session.attributes.forEach((a, i) => {
    const n = i + 1;
    const name = pretty(a.name);
    const less = el("button", { type: "button", class: "btn btn-less", "aria-label": `less ${name}`,
      title: `Less ${name} (Shift+${n})`, dataset: { attr: a.name, dir: "less" } },
    el("span", { "aria-hidden": "true" }, "▼"), "Less", n <= 9 ? el("kbd", {}, `⇧${n}`) : null);
    const more = el("button", { type: "button", class: "btn btn-more", "aria-label": `more ${name}`,
      title: `More ${name} (${n})`, dataset: { attr: a.name, dir: "more" } },
    el("span", { "aria-hidden": "true" }, "▲"), "More", n <= 9 ? el("kbd", {}, `${n}`) : null);
    less.addEventListener("click", () => feedback(a.name, "less", less));
    more.addEventListener("click", () => feedback(a.name, "more", more));
    els.attributes.append(el("div", { class: "attr", dataset: { attr: a.name } },
      el("div", { class: "attr-head" }, el("span", { class: "attr-name" }, name),
        el("span", { class: "attr-value", dataset: { valueOf: a.name } }, "")),
      el("p", { class: "attr-desc" }, a.description),
      el("div", { class: "attr-buttons" }, less, more)));
    if (n <= 9) {
      els.keyList.append(el("li", {}, el("kbd", {}, `${n}`), `more ${name}`, " · ", el("kbd", {}, `⇧${n}`), `less ${name}`));
    }
  });
  els.keyList.append(el("li", {}, el("kbd", {}, "Enter"), "this is it"),
    el("li", {}, el("kbd", {}, "Space"), "pause / play"),
    el("li", {}, el("kbd", {}, "Esc"), "back to the current clip"));
}

function renderStep(session) {
  els.stepBadge.hidden = false;
  const rounds = session.history.filter((h) => !h.satisfied).length;
  els.stepBadge.textContent = session.status === "satisfied" ? `✓ Chosen after ${rounds} round${rounds === 1 ? "" : "s"}`
    : `Clip ${session.step + 1} · ${session.clip.rollout_id}`;
}

function renderMeasured(clip, attributes) {
  els.measured.replaceChildren();
  for (const a of attributes) {
    const v = clip.measured[a.name];
    const span = (a.high ?? 0) - (a.low ?? 0);
    const pct = v === undefined || !(span > 0) ? 0 : Math.max(3, Math.min(100, ((v - a.low) / span) * 100));
    els.measured.append(el("div", { class: "meter", title: `${pretty(a.name)} measured on this clip` },
      el("div", { class: "meter-top" }, el("span", { class: "meter-name" }, pretty(a.name)),
        el("span", { class: "meter-value" }, `${fmt(v)} ${a.unit}`)),
      el("div", { class: "meter-bar" }, el("div", { class: "meter-fill", style: `width:${pct.toFixed(1)}%` }))));
    const label = els.attributes.querySelector(`[data-value-of="${a.name}"]`);
    if (label) label.textContent = `now ${fmt(v)} ${a.unit}`;
  }
}

function feedbackLabel(h) {
  if (h.satisfied) return [el("span", { class: "ok" }, "✓ this is it")];
  return h.feedback.map((f, i) => el("span", { class: f.direction },
    `${i ? ", " : ""}${f.direction === "more" ? "▲ more" : "▼ less"} ${pretty(f.attribute)}`));
}

function renderHistory(session) {
  els.history.replaceChildren();
  const items = session.history;
  els.historyEmpty.hidden = items.length > 0;
  els.historyCount.textContent = items.length ? `${items.length} answer${items.length === 1 ? "" : "s"}` : "";
  for (const h of items) {
    const isViewing = state.viewing && state.viewing.step === h.step;
    const thumb = el("video", { src: `${h.rollout_before.url}#t=1`, muted: true, playsinline: true, preload: "metadata",
      loop: true, "aria-hidden": "true" });
    thumb.muted = true;
    const card = el("button", { type: "button", class: `hist${isViewing ? " active" : ""}`,
      "aria-label": `Re-watch clip ${h.step + 1}`, dataset: { step: String(h.step) } },
    thumb, el("span", { class: "hist-body" }, el("span", { class: "hist-step" }, `Clip ${h.step + 1}`),
      el("span", { class: "hist-fb" }, feedbackLabel(h))));
    card.addEventListener("mouseenter", () => thumb.play().catch(() => {}));
    card.addEventListener("mouseleave", () => thumb.pause());
    card.addEventListener("click", () => rewatch(h));
    els.history.append(el("li", {}, card));
  }
  els.history.scrollLeft = els.history.scrollWidth;
}

function renderStatus(session) {
  const active = session.status === "active";
  const answers = session.history.length;
  els.sessionMeta.replaceChildren(`${answers} answer${answers === 1 ? "" : "s"} so far · ${session.method}/${session.rep}`
    + " · model ", el("code", { title: "model version" }, session.model_version.slice(0, 12)));
  els.satisfied.hidden = !active;
  els.done.hidden = active;
  els.controlsTitle.textContent = active ? "How should it change?" : session.status === "satisfied" ? "Done" : "Session closed";
  els.controlsHint.textContent = active ? "Watch the clip, then press more or less — or “This is it”."
    : "This session takes no more feedback.";
  if (!active) {
    const rounds = session.history.filter((h) => !h.satisfied).length;
    els.doneTitle.textContent = session.status === "satisfied" ? "You found it" : "Session abandoned";
    els.doneText.textContent = session.status === "satisfied"
      ? `You settled on ${session.clip.rollout_id} after ${rounds} round${rounds === 1 ? "" : "s"} of feedback.`
      : "Start a new session to tune again.";
  }
}

function rewatch(h) {
  state.viewing = h;
  els.replayText.textContent = `Re-watching clip ${h.step + 1} — you said ${feedbackLabel(h).map((n) => n.textContent).join("")}`;
  els.replayBanner.hidden = false;
  play(h.rollout_before.url, "Loading the clip…");
  renderMeasured(h.rollout_before, state.session.attributes);
  renderHistory(state.session);
}

function backToCurrent() {
  if (!state.viewing || !state.session) return;
  state.viewing = null;
  els.replayBanner.hidden = true;
  play(state.session.clip.url, "Loading the clip…");
  renderMeasured(state.session.clip, state.session.attributes);
  renderHistory(state.session);
}
els.replayBack.addEventListener("click", backToCurrent);

// ---------------------------------------------------------------- keyboard
document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLSelectElement || e.target instanceof HTMLInputElement || e.metaKey || e.ctrlKey || e.altKey) return;
  const s = state.session;
  const digit = /^Digit([1-9])$/.exec(e.code);
  if (digit && s && s.status === "active") {
    const a = s.attributes[Number(digit[1]) - 1];
    if (!a) return;
    e.preventDefault();
    const dir = e.shiftKey ? "less" : "more";
    const btn = els.attributes.querySelector(`[data-attr="${a.name}"][data-dir="${dir}"]`);
    feedback(a.name, dir, btn);
  } else if (e.key === "Enter" && s && s.status === "active" && !(e.target instanceof HTMLButtonElement)) {
    e.preventDefault();
    sendFeedback({ satisfied: true }, els.satisfied);
  } else if (e.key === " " && !(e.target instanceof HTMLButtonElement)) {
    e.preventDefault();
    if (els.video.paused) els.video.play().catch(() => {}); else els.video.pause();
  } else if (e.key === "Escape") {
    backToCurrent();
  }
});
els.satisfied.addEventListener("click", () => sendFeedback({ satisfied: true }, els.satisfied));

// ---------------------------------------------------------------- start
(async function main() {
  setBusy(true);
  try {
    await loadDomains();
  } catch (err) {
    overlay(err.message, "error");
    toast(err.message);
    setBusy(false);
    return;
  }
  setBusy(false);
  const resumed = await resumeFromUrl();
  if (!resumed) {
    overlay(null);
    els.welcome.hidden = false;
    document.body.dataset.state = "idle";
  }
})();
