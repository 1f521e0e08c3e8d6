// RBA Studio page: start a session, watch its clip, answer "more / less <attribute>" or "this is it".
// Plain ES module, no build step. Talks only to the REST API the scripted users use too.
// An answer is only possible about a clip that has played through once; it names that clip, so the server
// refuses (409) an answer about a clip the session no longer shows. An answer that makes the agent search for a
// new behaviour returns at once (202); the page then polls the search's progress with the buttons locked.

import { $, api, el, patientFetch, pretty, toast } from "./common.js";
import { describe, renderMeters, renderPath } from "./meters.js";
import { ClipPlayer } from "./player.js";

const els = {
  domain: $("domain"), method: $("method"), setup: $("setup"), start: $("start"),
  generate: $("generate"), generateField: $("generate-field"), advanced: $("advanced"), about: $("setup-about"),
  player: $("player"), overlay: $("overlay"), overlayText: $("overlay-text"),
  progress: $("progress"), progressFill: $("progress-fill"), progressText: $("progress-text"),
  welcome: $("welcome"), welcomeNote: $("welcome-note"),
  stepBadge: $("step-badge"), replayBanner: $("replay-banner"), replayText: $("replay-text"), replayBack: $("replay-back"),
  measured: $("measured"), path: $("path"), pathPlots: $("path-plots"), announce: $("announce"),
  attributes: $("attributes"), satisfied: $("satisfied"),
  controlsTitle: $("controls-title"), controlsHint: $("controls-hint"), sessionMeta: $("session-meta"),
  done: $("done"), doneTitle: $("done-title"), doneText: $("done-text"), again: $("again"), exportLink: $("export"),
  history: $("history"), historyEmpty: $("history-empty"), historyCount: $("history-count"), keyList: $("key-list"),
  words: $("words"), wordsText: $("words-text"), wordsGo: $("words-go"), wordsConfirm: $("words-confirm"),
  wordsUnderstood: $("words-understood"), wordsYes: $("words-yes"), wordsNo: $("words-no"), wordsError: $("words-error"),
  wordsExamples: $("words-examples"), wordsStatus: $("words-status"), wordsSure: $("words-sure"),
  wordsChoices: $("words-choices"),
};

const state = {
  domains: [],
  labels: {}, // method -> display name ("RBA-Global")
  generating: [], // methods whose sessions can make new behaviours
  generateDefault: false, // the server's: ticked for them unless the person unticks it
  searching: false, // the agent is making a new behaviour for the current clip's answer
  session: null,
  busy: false,
  waiting: false, // a new clip is being chosen or rendered: the previous one stays, dimmed
  viewing: null, // a history entry being re-watched, or null for the current clip
  shownUrl: null,
  played: new Set(), // rollout ids that have played through once
  announced: null,
  clipToken: 0,
  loading: null, // the rollout load() gave the video, until it can play: only its events take the overlay away
  understood: null, // the feedback the text box's sentence was understood as, awaiting confirmation
  reading: false, // the server is reading the text box's sentence: Interpret (and Enter) wait for it
};

const POLL_MS = 400;
const player = new ClipPlayer($("clip"), { label: "Current clip" });
const SESSION_ID = /^[0-9a-f]{32}$/;

// ---------------------------------------------------------------- small helpers
const plural = (n, word) => `${n} ${word}${n === 1 ? "" : "s"}`;
const rounds = (session) => session.history.filter((h) => !h.satisfied).length;
const choiceText = (f) => `${f.direction === "more" ? "▲ more" : "▼ less"} ${pretty(f.attribute)}`;

function overlay(text, kind = "loading") {
  els.progress.hidden = true;
  els.progressText.textContent = "";
  if (!text) { els.overlay.classList.add("hidden"); return; }
  if (els.overlayText.textContent !== text) els.overlayText.textContent = text;
  els.overlay.classList.toggle("error", kind === "error");
  els.overlay.classList.remove("hidden");
}

function progress(fraction, text) {
  els.progress.hidden = fraction === null;
  if (fraction !== null) {
    els.progressFill.style.width = `${Math.round(fraction * 100)}%`;
    els.progress.setAttribute("aria-valuenow", String(Math.round(fraction * 100)));
  }
  els.progressText.textContent = text;
}

function showWelcome(on) {
  els.welcome.hidden = !on;
  els.player.classList.toggle("welcoming", on);
  if (on) { overlay(null); document.body.dataset.state = "idle"; }
}

/** Answers are possible once the current clip has played through, the session is active and nothing is pending. */
function canAnswer() {
  const s = state.session;
  return Boolean(s && s.status === "active" && !state.busy && !state.waiting && state.played.has(s.clip.rollout_id));
}

function lock(button, locked) {
  button.setAttribute("aria-disabled", String(locked));
  button.classList.toggle("locked", locked);
}

/** Lock or unlock the answer controls (aria-disabled, so a focused button keeps its focus). */
function refreshControls() {
  const s = state.session;
  const open = canAnswer();
  for (const b of els.attributes.querySelectorAll("button")) lock(b, !open);
  lock(els.satisfied, !open);
  lock(els.wordsYes, !open);
  for (const b of els.wordsChoices.querySelectorAll("[data-reading]")) lock(b, !open);
  lock(els.start, state.busy);
  els.start.textContent = s ? "New session" : "Start tuning";
  document.body.classList.toggle("in-session", Boolean(s));
  document.body.dataset.state = state.searching ? "searching" : state.busy || state.waiting ? "busy" : (s ? "ready" : "idle");
  if (s && s.status === "active") {
    els.controlsHint.textContent = open ? "Press more or less — or “This is it”."
      : state.searching ? "No stored clip fits your answer, so the agent is making a new behaviour: the buttons "
        + "unlock once it has played."
      : state.busy || state.waiting ? "Wait for the new clip…" : "Watch the clip: the buttons unlock once it has played.";
  }
}

function setBusy(busy) {
  state.busy = busy;
  refreshControls();
}

// ---------------------------------------------------------------- domains and the setup form
function selectedDomain() { return state.domains.find((d) => d.name === els.domain.value); }

function methodLabel(m) {
  const name = m.label || state.labels[m.method] || `${m.method.charAt(0).toUpperCase()}${m.method.slice(1)}`;
  return m.rep === "onehot" ? name : `${name} · ${m.rep}`;
}

/** The domain picker: the domains people tune, and with "Advanced" the research views of their scenes too. */
function fillDomains() {
  const keep = els.domain.value;
  const shown = state.domains.filter((d) => els.advanced.checked || !d.advanced);
  const option = (d) => el("option", { value: d.name, title: d.description },
    pretty(d.name) + (d.available.length ? "" : " (not built)"));
  const views = shown.filter((d) => d.advanced);  // the same scenes, other states for the models
  els.domain.replaceChildren(...shown.filter((d) => !d.advanced).map(option),
    ...(views.length ? [el("optgroup", { label: "Research views: raw or image states" }, ...views.map(option))] : []));
  const first = shown.find((d) => d.name === keep) || shown.find((d) => d.available.length && !d.advanced)
    || shown.find((d) => d.available.length) || shown[0];
  if (first) els.domain.value = first.name;
  fillMethods();
}

/** The method picker: the selected domain's trained methods, research variants only with "Advanced". */
function fillMethods() {
  const d = selectedDomain();
  const keep = els.method.value;
  const offered = d ? d.available.filter((m) => els.advanced.checked || !m.advanced) : [];
  els.method.replaceChildren(...offered.map((m) => el("option", { value: `${m.method}/${m.rep}`, title: m.description },
    methodLabel(m))));
  if (d && !offered.length) {
    els.method.append(el("option", { value: "", disabled: true },
      d.available.length ? "research variants only: tick Advanced" : "not trained yet"));
  }
  if (offered.some((m) => `${m.method}/${m.rep}` === keep)) els.method.value = keep;
  const ok = offered.length > 0;
  fillGenerate();
  lock(els.start, !ok);
  els.welcomeNote.textContent = ok ? `${pretty(d.name)}: ${d.attributes.map((a) => pretty(a.name)).join(", ")}`
    : (d && d.missing) || "";
  describeChoice();
}

/** One line each on the chosen domain and method, from their definitions (GET /api/domains). */
function describeChoice() {
  const d = selectedDomain();
  const m = d && d.available.find((a) => `${a.method}/${a.rep}` === els.method.value);
  const line = (name, text) => el("span", {}, el("b", {}, name), ` — ${text}`);
  els.about.replaceChildren(...(d ? [line(pretty(d.name), d.description)] : []),
    ...(m ? [" ", line(methodLabel(m), m.description)] : []));
}

/** The "make new behaviours" option: offered for the methods that can, the server's default ticked. */
function fillGenerate() {
  const able = state.generating.includes(els.method.value.split("/")[0]);
  if (!able) els.generate.checked = false;
  else if (els.generate.disabled) els.generate.checked = state.generateDefault;
  els.generate.disabled = !able;
  els.generateField.classList.toggle("off", !able);
  els.generateField.title = able ? "When no stored clip is close to what you ask for, the agent makes a new one "
    + "(takes longer)" : "Only RBA-Global can make new behaviours";
}
els.method.addEventListener("change", fillGenerate);
els.method.addEventListener("change", describeChoice);
els.advanced.addEventListener("change", fillDomains);

async function loadDomains() {
  const body = await api("/api/domains");
  state.domains = body.domains;
  state.generating = body.generating;
  state.generateDefault = body.generate;
  els.generate.checked = body.generate;
  state.labels = Object.fromEntries(body.trainable.map((t) => [t.method, t.label]));
  fillDomains();
}
els.domain.addEventListener("change", fillMethods);

// ---------------------------------------------------------------- sessions
async function startSession(event) {
  if (event) event.preventDefault();
  if (state.busy) return;
  const d = selectedDomain();
  if (!d || !els.method.value) { toast(d && d.missing ? d.missing : "Pick a domain with trained models."); return; }
  const [method, rep] = els.method.value.split("/");
  setBusy(true);
  showWelcome(false);
  overlay("Starting a session…");
  try {
    const generate = els.generate.disabled ? undefined : els.generate.checked;
    const session = await api("/api/sessions", { method: "POST",
      body: JSON.stringify({ domain: d.name, method, rep, generate }) });
    // after another session, a history entry of its own: Back returns to the one left (the hash names it)
    history[state.session ? "pushState" : "replaceState"](null, "", `#session=${session.id}`);
    showSession(session, { fresh: true });
    els.controlsTitle.focus();
  } catch (err) {
    overlay(err.message, "error");
    toast(err.message);
    if (!state.session) showWelcome(true);
  } finally {
    setBusy(false);
  }
}
els.setup.addEventListener("submit", startSession);
els.again.addEventListener("click", () => startSession());

async function sendFeedback(payload, pressed) {
  const s = state.session;
  if (!s || s.status !== "active" || state.busy) return false;
  if (!canAnswer()) {
    toast(state.waiting ? "The new clip is on its way: answer once it has played."
      : "Watch the clip first: answers unlock once it has played.", "info");
    return false;
  }
  backToCurrent();
  setBusy(true);
  state.waiting = true;
  els.player.classList.add("waiting");
  if (pressed) pressed.classList.add("pressed");
  overlay(payload.satisfied ? "Saving your choice…" : "Choosing a new behaviour that fits…");
  try {
    const body = { step: s.step, clip: s.clip.rollout_id, ...payload };
    const next = await api(`/api/sessions/${s.id}/feedback`, { method: "POST", body: JSON.stringify(body) });
    if (next.step === s.step && next.status === "active") return await waitForSearch(next);  // 202: searching
    showSession(next);
    return true;
  } catch (err) {
    stopWaiting();
    if (err.status === 409) {  // the session moved on elsewhere (another tab): show what it shows now
      toast("The session had moved on (another tab?); this is the clip it shows now.", "info");
      await reloadSession();
    } else {
      toast(err.message);
    }
    return false;
  } finally {
    if (pressed) pressed.classList.remove("pressed");
    setBusy(false);
  }
}

const pause = (ms) => new Promise((r) => { setTimeout(r, ms); });

function searchProgress(g) {
  overlay("Making a new behaviour for you…");
  els.progress.setAttribute("aria-label", "Search progress");
  // a time-bounded search ends by its clock or its generations, whichever comes first
  const byTime = g.seconds_at_most ? g.elapsed_seconds / g.seconds_at_most : 0;
  const fraction = Math.min(1, Math.max(g.generations ? g.generation / g.generations : 0, byTime));
  const bound = g.seconds_at_most ? ` of at most ${Number(g.seconds_at_most.toFixed(2))} s` : "";
  progress(fraction, `search generation ${g.generation} (up to ${g.generations}) · ${g.elapsed_seconds.toFixed(1)} s${bound}`);
}

/** No stored clip fits: poll the agent's search until the session moves on (true) or the search fails. */
async function waitForSearch(session) {
  state.searching = true;
  state.waiting = true;
  els.player.classList.add("waiting");
  refreshControls();
  els.announce.textContent = "No stored clip fits: the agent is making a new behaviour. This takes a while.";
  try {
    for (;;) {
      const g = await api(`/api/sessions/${session.id}/generation`);
      if (g.step !== session.step || g.state === "done") break;
      if (g.state === "failed") throw Object.assign(new Error(g.detail), { status: 409 });
      searchProgress(g);
      await pause(POLL_MS);
    }
  } catch (err) {
    state.searching = false;
    stopWaiting();
    toast(err.status === 404 ? "The search for a new behaviour was lost (the server restarted?); answer again."
      : err.message);
    await reloadSession();
    return false;
  }
  state.searching = false;
  showSession(await api(`/api/sessions/${session.id}`));
  return true;
}

function feedback(attribute, direction, button) {
  return sendFeedback({ feedback: [{ attribute, direction }] }, button);
}

async function reloadSession() {
  if (!state.session) return;
  try { showSession(await api(`/api/sessions/${state.session.id}`)); } catch (err) { toast(err.message); }
}

function hashSessionId() {
  const m = /^#session=(.*)$/.exec(location.hash);
  if (!m) return null;
  try { return decodeURIComponent(m[1]); } catch { return m[1]; }  // badly encoded: refused as any bad id is
}

function restoreHash() {
  history.replaceState(null, "", state.session ? `#session=${state.session.id}` : location.pathname);
}

/** Load the session the address names; a clear message (and the welcome or current session) if it cannot be. */
async function resumeFromUrl() {
  const id = hashSessionId();
  if (id === null || (state.session && state.session.id === id)) return Boolean(state.session);
  if (!SESSION_ID.test(id)) {
    toast(`“${id.slice(0, 40)}” in the address is not a session id (32 hex digits, as in the links this page `
      + "makes); start a new session.");
    restoreHash();
    return Boolean(state.session);
  }
  overlay("Resuming your session…");
  try {
    const session = await api(`/api/sessions/${id}`);
    showSession(session, { fresh: true });
    if (session.generation && session.generation.state === "searching") {
      setBusy(true);
      try { await waitForSearch(session); } finally { setBusy(false); }
    }
    return true;
  } catch (err) {
    toast(err.status === 404 ? `Session ${id} does not exist (any more); start a new one.` : err.message);
    restoreHash();
    if (state.session) overlay(null);
    return Boolean(state.session);
  }
}
window.addEventListener("hashchange", async () => {
  if (!(await resumeFromUrl()) && !state.session) showWelcome(true);
});

// ---------------------------------------------------------------- the clip: wait for its render, then play it
const statusUrl = (clip) => clip.url.replace(/\.mp4$/, "/status");

function renderProgress(st) {
  els.progress.setAttribute("aria-label", "Rendering progress");
  if (st.state === "queued") { overlay("Waiting for a free renderer…"); return; }
  if (st.state !== "rendering") { overlay("Rendering the clip…"); return; }
  overlay("Rendering the clip…");
  const elapsed = st.elapsed_seconds ?? 0;
  if (st.typical_seconds) {
    const fraction = Math.min(0.95, elapsed / st.typical_seconds);
    const left = Math.max(1, Math.round(st.typical_seconds - elapsed));
    progress(fraction, `${Math.round(fraction * 100)} % · about ${plural(left, "second")} left`);
  } else {
    progress(null, `${elapsed.toFixed(0)} s so far`);
  }
}

/** Ask for the clip (HEAD: the server renders it, urgently) and show the render's status until it is stored. */
async function waitForRender(clip, token) {
  let rendered = false;
  const head = patientFetch(clip.url, { method: "HEAD" }).catch(() => null).finally(() => { rendered = true; });
  while (!rendered && token === state.clipToken) {
    try {
      const res = await fetch(statusUrl(clip));
      if (res.ok && !rendered && token === state.clipToken) renderProgress(await res.json());
    } catch { /* the HEAD request reports a dead server */ }
    await Promise.race([head, new Promise((r) => { setTimeout(r, POLL_MS); })]);
  }
}

/** Show ``clip`` (its data drawn, else its MP4) in the player; ``previous`` (or null) to compare it with. */
function load(clip, label, previous = null) {
  state.shownUrl = clip.url;
  state.loading = clip.rollout_id;
  overlay(label);
  player.show(clip).then(() => clipStarted(clip.rollout_id));
  player.compare(previous);
}

/** Show the session's current clip: the previous one stays, dimmed, with the render's progress until it is ready. */
async function showCurrentClip(clip) {
  const token = ++state.clipToken;
  if (state.shownUrl === clip.url) {  // already shown (another session's same first clip): played if it did
    if (player.element.dataset.played === clip.rollout_id) state.played.add(clip.rollout_id);
    stopWaiting();
    return;
  }
  if (!clip.ready && !clip.data_url) {  // drawn from data: no render to wait for
    state.waiting = true;
    els.player.classList.toggle("waiting", Boolean(state.shownUrl));
    refreshControls();
    await waitForRender(clip, token);
    if (token !== state.clipToken) return;
    if (state.viewing) { stopWaiting(); return; } // re-watching an old clip: the new one loads on "back to current"
  }
  load(clip, "Loading the clip…", previousClip());
}

/** The clip shown before the current one (to compare with), or null. */
function previousClip() {
  const h = state.session && state.session.history.at(-1);
  return h ? h.rollout_before : null;
}

function stopWaiting() {
  state.waiting = false;
  els.player.classList.remove("waiting");
  overlay(null);
  refreshControls();
}

function clipStarted(rolloutId) {
  if (state.loading !== rolloutId) return;  // only the clip being waited for ends the wait
  state.loading = null;
  const s = state.session;
  if (player.mode === "video" && player.failed) {
    stopWaiting();
    overlay("The clip could not be loaded.", "error");
    toast("The clip could not be loaded; reload the page to try again.");
    return;
  }
  if (state.viewing || !s || rolloutId !== s.clip.rollout_id) { overlay(null); return; }
  stopWaiting();
  if (state.announced !== s.clip.rollout_id) {
    state.announced = s.clip.rollout_id;
    els.announce.textContent = `Clip ${s.step + 1}: ${describe(s.attributes, s.clip)}`;
  }
}
player.addEventListener("playedonce", () => {
  const id = player.element.dataset.rolloutId;
  if (id && !state.played.has(id)) {
    state.played.add(id);
    refreshControls();
  }
});

// ---------------------------------------------------------------- rendering a session
function showSession(session, { fresh = false } = {}) {
  const previous = state.session;
  state.session = session;
  showWelcome(false);
  if (fresh || !previous || previous.id !== session.id) {
    const d = state.domains.find((x) => x.name === session.domain);
    const pair = d && d.available.find((m) => m.method === session.method && m.rep === session.rep);
    if (d && (d.advanced || (pair && pair.advanced)) && !els.advanced.checked) {
      els.advanced.checked = true;  // a research session (an address, the API): the pickers show what it is
      fillDomains();
    }
    els.domain.value = session.domain;
    fillMethods();
    els.method.value = `${session.method}/${session.rep}`;
    fillGenerate();
    describeChoice();
    if (!els.generate.disabled) els.generate.checked = session.generate;  // the form says what this session does
    buildControls(session);
    state.played.clear(); // another session: its clip must be watched again, even one seen before
    state.viewing = null;
    els.replayBanner.hidden = true;
  }
  if (!state.viewing) showCurrentClip(session.clip);
  renderStep(session);
  renderClipView(state.viewing ? state.viewing.rollout_before : session.clip);
  renderHistory(session);
  renderStatus(session);
  refreshControls();
}

function answerButton(a, n, dir) {
  const name = pretty(a.name);
  const more = dir === "more";
  const key = more ? `${n}` : `⇧${n}`;
  const b = el("button", { type: "button", class: `btn btn-${dir}`,
    "aria-keyshortcuts": n <= 9 ? (more ? `${n}` : `Shift+${n}`) : null, dataset: { attr: a.name, dir } },
  el("span", { "aria-hidden": "true" }, more ? "▲" : "▼"), more ? "More" : "Less",
  el("span", { class: "visually-hidden" }, ` ${name}`), n <= 9 ? el("kbd", { "aria-hidden": "true" }, key) : null);
  b.addEventListener("click", (e) => {
    if (e.detail > 0) b.blur();  // a pointer's click: Enter then means "This is it", not this answer again
    feedback(a.name, dir, b);
  });
  return b;
}

function buildControls(session) {
  els.attributes.replaceChildren();
  els.keyList.replaceChildren();
  session.attributes.forEach((a, i) => {
    const n = i + 1;
    const name = pretty(a.name);
    els.attributes.append(el("div", { class: "attr", dataset: { attr: a.name } },
      el("div", { class: "attr-head" }, el("span", { class: "attr-name" }, name)),
      el("p", { class: "attr-desc" }, a.description),
      el("div", { class: "attr-buttons" }, answerButton(a, n, "less"), answerButton(a, n, "more"))));
    if (n <= 9) {
      els.keyList.append(el("li", {}, el("kbd", {}, `${n}`), `more ${name}`, " · ", el("kbd", {}, `⇧${n}`), `less ${name}`));
    }
  });
  els.keyList.append(el("li", {}, el("kbd", {}, "Enter"), "this is it"),
    el("li", {}, el("kbd", {}, "Space"), "pause / play"),
    el("li", {}, el("kbd", {}, "← →"), "one frame back / on (the player's own keys under it)"),
    el("li", {}, el("kbd", {}, "Esc"), "back to the current clip"));
  resetWords();
}

function renderStep(session) {
  els.stepBadge.hidden = false;
  els.stepBadge.textContent = (session.status === "satisfied" ? `✓ Chosen after ${plural(rounds(session), "round")}`
    : `Clip ${session.step + 1}`) + (session.clip.generated ? " · new behaviour" : "");
}

function renderClipView(clip) {
  renderMeters(els.measured, state.session, clip);
  renderPath(els.path, els.pathPlots, state.session, clip);
}

function feedbackLabel(h) {
  if (h.satisfied) return [el("span", { class: "ok" }, "✓ this is it")];
  return h.feedback.map((f, i) => el("span", { class: f.direction }, `${i ? ", " : ""}${choiceText(f)}`));
}

function renderHistory(session) {
  els.history.replaceChildren();
  const items = session.history;
  els.historyEmpty.hidden = items.length > 0;
  const n = rounds(session);
  els.historyCount.textContent = items.length ? `${plural(n, "round")} of feedback${n < items.length ? " · chosen" : ""}` : "";
  for (const h of items) {
    const isViewing = state.viewing && state.viewing.step === h.step;
    const thumb = el("video", { src: `${h.rollout_before.url}#t=1`, muted: true, playsinline: true, preload: "metadata",
      loop: true, "aria-hidden": "true" });
    thumb.muted = true;
    const made = h.rollout_before.generated;
    const card = el("button", { type: "button", class: `hist${isViewing ? " active" : ""}`,
      "aria-label": `Re-watch clip ${h.step + 1}${made ? ", a new behaviour made for you" : ""}`,
      dataset: { step: String(h.step), generated: String(made) } },
    thumb, el("span", { class: "hist-body" }, el("span", { class: "hist-step" }, `Clip ${h.step + 1}`),
      made ? el("span", { class: "hist-new", title: "made for you: not from the stored clips" }, "new") : null,
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
  els.sessionMeta.replaceChildren(
    `Session ${session.id} · ${methodLabel(session)} (${session.method}/${session.rep}) · clip ${session.clip.rollout_id}`
    + ` · model `, el("code", {}, session.model_version), ` (${session.model_set})`);
  els.satisfied.hidden = !active;
  els.words.hidden = !active;
  if (active) showExamples(session.domain);
  els.attributes.hidden = !active;  // no dead buttons to tab through before the download
  els.done.hidden = active;
  els.exportLink.hidden = session.status !== "satisfied";
  els.exportLink.href = session.status === "satisfied" ? `/api/sessions/${encodeURIComponent(session.id)}/export` : "#";
  els.controlsTitle.textContent = active ? "How should it change?" : session.status === "satisfied" ? "Done" : "Session closed";
  if (!active) {
    els.controlsHint.textContent = "This session takes no more feedback.";
    els.doneTitle.textContent = session.status === "satisfied" ? "You found it" : "Session abandoned";
    els.doneText.textContent = session.status === "satisfied"
      ? `You chose clip ${session.step} after ${plural(rounds(session), "round")} of feedback.`
      : "Start a new session to tune again.";
  }
}

function rewatch(h) {
  state.viewing = h;
  els.replayText.textContent = `Re-watching clip ${h.step + 1} — you said ${feedbackLabel(h).map((n) => n.textContent).join("")}`;
  els.replayBanner.hidden = false;
  load(h.rollout_before, "Loading the clip…");
  renderClipView(h.rollout_before);
  renderHistory(state.session);
}

function backToCurrent() {
  if (!state.viewing || !state.session) return;
  state.viewing = null;
  els.replayBanner.hidden = true;
  load(state.session.clip, "Loading the clip…", previousClip());
  renderClipView(state.session.clip);
  renderHistory(state.session);
}
els.replayBack.addEventListener("click", backToCurrent);

// ---------------------------------------------------------------- feedback in your own words
function resetWords() {
  state.understood = null;
  els.wordsConfirm.hidden = true;
  els.wordsChoices.replaceChildren();
  els.wordsError.hidden = true;
}

/** The domain's example sentences (its anchors, from GET /api/domains): the placeholder, and buttons that read one. */
function showExamples(domain) {
  if (els.wordsExamples.dataset.domain === domain) return;
  const d = state.domains.find((x) => x.name === domain);
  const examples = (d && d.examples) || [];
  els.wordsExamples.dataset.domain = domain;
  els.wordsText.placeholder = examples.length ? `e.g. ${examples[0]}` : "";
  els.wordsExamples.replaceChildren("Try:", ...examples.map((text) => el("button", {
    type: "button", class: "words-example", onclick: () => { els.wordsText.value = text; els.words.requestSubmit(); },
  }, text)));
  els.wordsExamples.hidden = !examples.length;
}

/** While the server reads a sentence (the first after a restart can take seconds): say so, announced, and keep
 * Interpret and Enter from sending it again. */
function setReading(on) {
  state.reading = on;
  lock(els.wordsGo, on);
  els.words.setAttribute("aria-busy", String(on));
  els.wordsStatus.textContent = on ? "Reading…" : "";
}

/** What the sentence was read as: one reading to confirm, or (when the server is unsure) two to choose from. */
function offerReadings(r) {
  const choose = (r.alternatives || []).length > 1;  // (a server before the field: one reading)
  state.understood = r.feedback;
  const shown = (reading) => reading.map(choiceText).join(", ");
  els.wordsUnderstood.textContent = choose ? "Not sure what you meant. Which one?"
    : `${r.low_confidence ? "Not sure: " : ""}${shown(r.feedback)} — right?`;
  els.wordsSure.hidden = choose;
  els.wordsChoices.hidden = !choose;
  els.wordsChoices.replaceChildren(...(choose ? [
    ...r.alternatives.map((reading, i) => el("button", {
      type: "button", class: i ? "btn btn-light btn-outline" : "btn btn-primary", "data-reading": String(i),
      onclick: (e) => sendWords(reading, e.currentTarget),
    }, shown(reading))),
    el("button", { type: "button", class: "btn btn-light btn-outline", onclick: () => els.wordsNo.click() }, "Neither"),
  ] : []));
  els.wordsConfirm.hidden = false;
  refreshControls();  // the choices unlock with the other answers
  (choose ? els.wordsChoices.firstElementChild : els.wordsYes).focus();
}

async function sendWords(reading, button) {
  if (await sendFeedback({ feedback: reading }, button)) {
    els.wordsText.value = "";
    resetWords();
    els.wordsText.focus();
  }
}

els.words.addEventListener("submit", async (e) => {
  e.preventDefault();
  const s = state.session;
  const text = els.wordsText.value.trim();
  if (!s || !text || state.reading) return;
  resetWords();
  setReading(true);
  try {
    offerReadings(await api(`/api/domains/${encodeURIComponent(s.domain)}/interpret`,
      { method: "POST", body: JSON.stringify({ text }) }));
  } catch (err) {
    els.wordsError.textContent = err.status === 404 ? "This server cannot read sentences yet; use the buttons."
      : err.message;
    els.wordsError.hidden = false;
  } finally {
    setReading(false);
  }
});
els.wordsYes.addEventListener("click", () => { if (state.understood) sendWords(state.understood, els.wordsYes); });
els.wordsNo.addEventListener("click", () => { resetWords(); els.wordsText.focus(); });

// ---------------------------------------------------------------- keyboard
document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLSelectElement || e.target instanceof HTMLInputElement || e.metaKey || e.ctrlKey || e.altKey) return;
  if (e.defaultPrevented) return;  // the player's own keys (focus in it)
  const s = state.session;
  const digit = /^Digit([1-9])$/.exec(e.code);
  if (digit && s && s.status === "active") {
    const a = s.attributes[Number(digit[1]) - 1];
    if (!a) return;
    e.preventDefault();
    const dir = e.shiftKey ? "less" : "more";
    feedback(a.name, dir, els.attributes.querySelector(`[data-attr="${a.name}"][data-dir="${dir}"]`));
  } else if (e.key === "Enter" && s && s.status === "active" && !(e.target instanceof HTMLButtonElement)
    && !(e.target instanceof HTMLElement && e.target.closest("summary, a"))) {
    e.preventDefault();
    sendFeedback({ satisfied: true }, els.satisfied);
  } else if (e.key === " " && !(e.target instanceof HTMLButtonElement) && !(e.target instanceof HTMLElement && e.target.closest("summary"))) {
    e.preventDefault();
    player.toggle();
  } else if ((e.key === "ArrowLeft" || e.key === "ArrowRight") && !e.shiftKey) {
    e.preventDefault();
    player.step(e.key === "ArrowLeft" ? -1 : 1);
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
  if (!(await resumeFromUrl())) showWelcome(true);
})();
