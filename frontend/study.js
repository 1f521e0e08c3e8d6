// A study's participant page (/study/<token>): consent, then per trial the target clip beside the agent's current
// clip and "more / less" per attribute, then the end questionnaire. Plain ES module, no build step. The token in
// the address is the participant's only credential: every call goes to /api/participate/<token>.
// An answer is only possible once the current clip has played to its end once; it carries the time from the clip's
// first frame to the answer (ms) and how often the participant played the clip again (replays).

import { $, api, el, hideToast, pretty, toast } from "./common.js";
import { ClipPlayer } from "./player.js";

const TOKEN = (() => {
  const last = location.pathname.split("/").filter(Boolean).pop() || "";
  try { return decodeURIComponent(last); } catch { return last; }
})();
const BASE = `/api/participate/${encodeURIComponent(TOKEN)}`;
const SECTIONS = ["loading", "consent", "trial", "questionnaire", "thanks", "gone"];

const state = {
  body: null, // the last GET /api/participate/<token> (or answer) response
  trialId: null,
  shown: null, // `${trial id}:${answers used}`: which clip of which trial the current player shows
  played: false, // the current clip has played to its end once
  started: null, // performance.now() when the current clip's first frame was on screen
  replays: 0,
  busy: false,
  rate: 1, // playback speed of both clips (automation plays them fast: window.rbaStudy.rate)
  players: null, // {target, current}: ClipPlayers
};

// ---------------------------------------------------------------- the clips
/** One ClipPlayer per clip, kept across trials. A clip plays once and stays on its last frame (no loop): playing it
 * again is the participant's choice, by this page's button or the player's own play button, and counted. */
function makePlayers() {
  const make = (id, label) => {
    // no description (it names the clip's measured values, which would give the target away) and no loop
    const player = new ClipPlayer($(id), { label, describe: false, loop: false });
    player.rate = state.rate;
    return player;
  };
  state.players = { target: make("target", "Target clip"), current: make("current", "The agent's current clip") };
  const current = state.players.current;
  current.addEventListener("playedonce", () => {
    if (state.played) return;
    state.played = true;
    refresh();
  });
  // the player's own play buttons start a finished clip again: capture runs before their handlers
  current.element.addEventListener("click", (e) => {
    if (current.playedOnce && current.paused && e.target.closest(".cp-play, .cp-big")) state.replays += 1;
  }, true);
}

function restart(player) {
  player.seek(0);
  player.play();
}

async function showClip(which, clip) {
  const stage = $(which).closest(".clip");
  stage.classList.add("waiting");
  stage.dataset.rolloutId = clip.rollout_id;
  try {
    await state.players[which].show(clip);
  } catch (err) {
    toast(`${err.message} Reload the page to try again.`);
    return false;
  } finally {
    stage.classList.remove("waiting");
  }
  return true;
}

// ---------------------------------------------------------------- sections
function section(name) {
  for (const s of SECTIONS) $(s).hidden = s !== name;
  document.body.dataset.state = name;
  $("withdraw").hidden = ["loading", "gone"].includes(name);
  if (name !== "trial") $("progress").textContent = "";
}

function focusHeading(id) {
  $(id).focus({ preventScroll: false });
}

function showGone(status) {
  section("gone");
  const withdrawn = status === 410;
  $("h-gone").textContent = withdrawn ? "You have withdrawn from this study" : "This study link is not known";
  $("gone-text").textContent = withdrawn
    ? "Everything you answered has been deleted, and this link no longer works. Thank you for your time."
    : "The link may be incomplete: check that you opened the whole link you were sent. If it still does not work, "
      + "ask the person who invited you for a new one.";
  focusHeading("h-gone");
}

function render(body) {
  const before = document.body.dataset.state;
  state.body = body;
  $("study-name").textContent = body.study.name || "RBA Studio study";
  document.title = `${body.study.name || "Study"} · RBA Studio`;
  if (!body.consented) {
    section("consent");
    $("consent-text").replaceChildren(...String(body.study.consent_text || "").split(/\n{2,}/)
      .map((p) => el("p", {}, p)));
    if (before !== "consent") focusHeading("h-consent");
  } else if (body.trial) {
    showTrial(body);
  } else if (body.questionnaire) {
    showQuestionnaire(body.questionnaire);
    if (before !== "questionnaire") focusHeading("h-questionnaire");
  } else {
    section("thanks");
    if (before !== "thanks") focusHeading("h-thanks");
  }
}

// ---------------------------------------------------------------- a trial
const isTarget = () => state.body.study.task === "target";

function answerButton(a, dir) {
  const more = dir === "more";
  return el("button", { type: "button", class: `btn btn-${dir}`, dataset: { attr: a.name, dir },
    onclick: () => answer({ kind: "attribute", feedback: [{ attribute: a.name, direction: dir }] }) },
  el("span", { "aria-hidden": "true" }, more ? "▲" : "▼"), more ? "More" : "Less",
  el("span", { class: "visually-hidden" }, ` ${pretty(a.name)}`));
}

function buildControls(attributes) {
  $("attributes").replaceChildren(...attributes.map((a) => el("div", { class: "attr", dataset: { attr: a.name } },
    el("div", { class: "attr-head" }, el("span", { class: "attr-name" }, pretty(a.name))),
    a.description ? el("p", { class: "attr-desc" }, a.description) : null,
    el("div", { class: "attr-buttons" }, answerButton(a, "less"), answerButton(a, "more")))));
}

function showTrial(body) {
  const t = body.trial;
  const fresh = document.body.dataset.state !== "trial";
  section("trial");
  const left = t.answer_budget - t.answers_used;
  $("progress").textContent = `Trial ${t.index + 1} of ${t.of} · ${left} answer${left === 1 ? "" : "s"} left`;
  $("h-trial").textContent = `Trial ${t.index + 1} of ${t.of}: ${t.label}`;
  $("current-name").textContent = t.label;
  $("current-step").textContent = `clip ${t.answers_used + 1}`;
  $("task-text").textContent = isTarget()
    ? "Watch the target, then tell the agent how its clip should change until it matches the target."
    : "Tell the agent how its clip should change until it behaves the way you like.";
  $("satisfied-text").textContent = isTarget() ? "This matches the target" : "I’m satisfied";
  $("target-figure").hidden = !t.target;
  if (t.id !== state.trialId) {
    state.trialId = t.id;
    if (!$("attributes").children.length) buildControls(body.study.attributes);
    if (t.target) showClip("target", t.target);
    if (!fresh) focusHeading("h-trial");  // a new trial: screen readers hear which one
  }
  const key = `${t.id}:${t.answers_used}`;
  if (key !== state.shown) {
    state.shown = key;
    state.played = false;
    state.started = null;
    state.replays = 0;
    refresh();
    showClip("current", t.clip).then((ok) => { if (ok && state.shown === key) state.started = performance.now(); });
  }
  refresh();
}

function canAnswer() {
  return document.body.dataset.state === "trial" && state.played && !state.busy && state.started !== null;
}

function refresh() {
  const open = canAnswer();
  for (const b of [...$("attributes").querySelectorAll("button"), $("satisfied")]) {
    b.setAttribute("aria-disabled", String(!open));
    b.classList.toggle("locked", !open);
  }
  const hint = state.busy ? "Sending your answer…" : open ? "Press more or less, or say it matches."
    : "Watch the agent’s clip: the answers unlock once it has played to its end.";
  if ($("hint").textContent !== hint) $("hint").textContent = hint;
  $("current-figure").dataset.played = String(state.played);
  document.body.dataset.answerable = String(open);
}

async function answer(feedback) {
  if (!canAnswer()) return;
  const payload = { trial_id: state.trialId, feedback, ms: Math.max(0, Math.round(performance.now() - state.started)),
                    replays: state.replays };
  state.busy = true;
  refresh();
  try {
    render(await api(`${BASE}/answer`, { method: "POST", body: JSON.stringify(payload) }));
  } catch (err) {
    await failed(err);
  } finally {
    state.busy = false;
    refresh();
  }
}

/** A refused call: a withdrawn or unknown link explains itself; a stale answer (409) shows where things are now. */
async function failed(err) {
  if (err.status === 404 || err.status === 410) { showGone(err.status); return; }
  toast(err.message, err.status === 409 ? "info" : "error");
  if (err.status === 409) await load();
}

$("satisfied").addEventListener("click", () => answer({ kind: "satisfied" }));
$("current-again").addEventListener("click", () => {
  if (!state.body?.trial) return;
  state.replays += 1;
  restart(state.players.current);
});
$("target-again").addEventListener("click", () => {
  if (state.body?.trial?.target) restart(state.players.target);
});

// ---------------------------------------------------------------- questionnaire
/** One radio group per item, on the item's own scale (its ends named): a fieldset whose legend is the statement. */
function questions(box, items, prefix) {
  box.replaceChildren(...items.map((item, i) => {
    const name = `${prefix}-${i}`;
    const values = Array.from({ length: item.max - item.min + 1 }, (_, j) => item.min + j);
    const end = (v) => (v === item.min ? item.low : v === item.max ? item.high : null);
    return el("fieldset", { class: "likert", dataset: { item: item.id } },
      el("legend", {}, `${i + 1}. ${item.text}`),
      el("div", { class: "likert-options" }, values.map((v) => el("label", { class: "likert-option" },
        el("input", { type: "radio", name, value: String(v), required: true }),
        el("span", {}, String(v)), end(v) ? el("span", { class: "likert-end" }, end(v)) : null))));
  }));
}

function showQuestionnaire(q) {
  if (document.body.dataset.state === "questionnaire") return;
  section("questionnaire");
  questions($("satisfaction"), q.satisfaction, "satisfaction");
  questions($("usability"), q.usability, "usability");
  $("questions-error").hidden = true;
}

function chosen(prefix, n) {
  return Array.from({ length: n }, (_, i) => {
    const r = document.querySelector(`input[name="${prefix}-${i}"]:checked`);
    return r ? Number(r.value) : null;
  });
}

$("questions").addEventListener("submit", async (e) => {
  e.preventDefault();
  const q = state.body.questionnaire;
  const satisfaction = chosen("satisfaction", q.satisfaction.length);
  const usability = chosen("usability", q.usability.length);
  const missing = [...satisfaction.map((v, i) => (v === null ? `satisfaction ${i + 1}` : null)),
    ...usability.map((v, i) => (v === null ? `usability ${i + 1}` : null))].filter(Boolean);
  for (const f of document.querySelectorAll("fieldset.likert")) {
    f.classList.toggle("missing", !f.querySelector("input:checked"));
  }
  if (missing.length) {
    $("questions-error").textContent = `Please answer every statement; still open: ${missing.join(", ")}.`;
    $("questions-error").hidden = false;
    document.querySelector("fieldset.likert.missing input")?.focus();
    return;
  }
  $("questions-error").hidden = true;
  try {
    render(await api(`${BASE}/questionnaire`, { method: "POST", body: JSON.stringify({ satisfaction, usability }) }));
  } catch (err) {
    await failed(err);
  }
});

// ---------------------------------------------------------------- consent and withdrawal
$("agree").addEventListener("click", async () => {
  try {
    render(await api(`${BASE}/consent`, { method: "POST" }));
  } catch (err) {
    await failed(err);
  }
});

$("withdraw").addEventListener("click", () => $("confirm-withdraw").showModal());
$("confirm-withdraw").addEventListener("close", async () => {
  if ($("confirm-withdraw").returnValue !== "withdraw") return;
  try {
    await api(BASE, { method: "DELETE" });
    hideToast();
    showGone(410);
  } catch (err) {
    await failed(err);
  }
});

// ---------------------------------------------------------------- start
async function load() {
  try {
    render(await api(BASE));
  } catch (err) {
    if (err.status === 404 || err.status === 410) showGone(err.status);
    else {
      $("loading").textContent = err.message;
      toast(err.message);
    }
  }
}

/** For automation (the browser test plays clips fast): ``window.rbaStudy.rate = 16``. */
window.rbaStudy = {
  get rate() { return state.rate; },
  set rate(r) {
    state.rate = r;
    for (const p of Object.values(state.players || {})) p.rate = r;
  },
};

(async function main() {
  makePlayers();
  if (!TOKEN) { showGone(404); return; }
  await load();
})();
