// RBA Studio admin page: label clips (saved one by one), upload labelled clips, retrain in the background, switch
// the served model. Everything it shows comes from /api/admin routes, which need the admin token.

import { $, api, el, hideToast, pretty, toast } from "./common.js";
import { showCurves } from "./curves.js";
import { ClipPlayer } from "./player.js";
import { mountStudies } from "./studies.js";

const ANSWERS = ["left-more", "skip", "right-more"];
const TOKEN_KEY = "rba-admin-token";  // in this tab's session storage until "Lock" or the tab closes
const state = {
  token: sessionStorage.getItem(TOKEN_KEY) || "", clips: [], players: [], watched: new Set(), failed: false,
  busy: false, job: null, curvesJob: null, jobState: "", labels: 0, trainable: [], versions: [], presets: [],
};

/** The shared call with the admin token the /api/admin routes need. */
const adminApi = (path, options = {}) =>
  api(path, { ...options, headers: { Authorization: `Bearer ${state.token}`, ...options.headers } });

const domain = () => $("domain").value;
const attribute = () => $("attribute").value;
const local = () => $("mode").value === "local";
const query = (params) => new URLSearchParams(params).toString();

// ---------------------------------------------------------------- unlock
async function unlock(event) {
  event?.preventDefault();
  state.token = $("token").value || state.token;
  try {
    await adminApi("/api/admin/jobs");
  } catch (e) {
    toast(e.message);
    return;
  }
  sessionStorage.setItem(TOKEN_KEY, state.token);
  hideToast();  // a refused token's message is stale once the right one unlocks the page
  $("login").hidden = true;
  $("admin").hidden = false;
  $("lock").hidden = false;
  $("h-what").focus();  // the form that had focus is gone: keyboard users start at the first panel
  const { domains, trainable, reps } = await api("/api/domains");
  $("domain").replaceChildren(...domains.map((d) => el("option", { value: d.name }, d.name)));
  state.trainable = trainable;
  $("train-method").replaceChildren(...trainable.map((m) => el("option", { value: m.method }, m.label)));
  $("rep").replaceChildren(...reps.map((r) => el("option", { value: r }, r)));
  showPresets();
  await Promise.all([loadDomain(), mountStudies(adminApi, () => state.token, domains)]);
}

/** Forget the token (this tab's storage and memory), stop following the job and show the token form again: a
 * shared screen keeps no admin access. */
function lock() {
  sessionStorage.removeItem(TOKEN_KEY);
  state.token = "";
  state.job = null;  // the poll stops at its next turn
  state.clips = [];
  stopPlayers();
  $("pair").replaceChildren();
  $("admin").hidden = true;
  $("lock").hidden = true;
  $("login").hidden = false;
  $("token").value = "";
  $("token").focus();
  toast("Locked: this tab has forgotten the admin token.", "info");
}

// The presets the chosen method's trainer knows (the server's method registry says which), each described.
function showPresets() {
  const method = state.trainable.find((m) => m.method === $("train-method").value);
  const keep = $("preset").value;
  $("preset").replaceChildren(...(method ? method.presets : []).map((p) => el("option", { value: p }, p)));
  if (method?.presets.includes(keep)) $("preset").value = keep;
  aboutPreset();
}

function aboutPreset() {
  const p = state.presets.find((x) => x.method === $("train-method").value && x.preset === $("preset").value);
  $("preset-about").textContent = p
    ? `${p.preset}: ${p.description}. Typically about ${duration(p.typical_seconds)} on 2 CPU cores.` : "";
}

async function loadPresets() {
  state.presets = await adminApi(`/api/admin/presets?${query({ domain: domain() })}`);
  aboutPreset();
}

async function loadAttributes() {
  const { attributes } = await adminApi(`/api/admin/attributes?${query({ domain: domain() })}`);
  const keep = attribute();
  $("attribute").replaceChildren(...attributes.map((a) =>
    el("option", { value: a.name, title: a.description }, `${pretty(a.name)}${a.added ? " (added)" : ""}`)));
  if (attributes.some((a) => a.name === keep)) $("attribute").value = keep;
}

async function loadDomain() {
  $("upload-domain").textContent = domain();
  $("example-domain").textContent = domain();
  $("upload-result").replaceChildren();
  await loadAttributes();
  await Promise.all([nextClips(), loadDatasets(), loadVersions(), loadLatestJob(), loadPresets()]);
}

// ---------------------------------------------------------------- labelling
/** Answers (and ← → ↓) work only about clips both seen: each played through once. A clip that fails to load
 * can still be skipped. aria-disabled rather than disabled, so a focused button keeps the focus. */
function gate() {
  const seen = state.clips.length === 2 && state.watched.size === 2 && !state.busy;
  const canSkip = seen || (state.failed && !state.busy);
  for (const id of ANSWERS) $(id).setAttribute("aria-disabled", String(!(id === "skip" ? canSkip : seen)));
  const status = state.busy ? "Loading the next pair…"
    : state.failed ? "A clip could not be played: skip to the next pair (↓)."
      : seen ? "Both clips played: answer with the buttons or ← → ↓."
        : "Watch both clips: the answers unlock once each has played through.";
  if ($("watch-status").textContent !== status) $("watch-status").textContent = status;
}

const allowed = (id) => $(id).getAttribute("aria-disabled") !== "true";

/** Mark clip ``i`` seen once it has played through, in the set of its own pair only (a replaced player's late
 * event must not unlock the pair after it). */
function watch(player, i, caption) {
  const seen = state.watched;
  player.addEventListener("playedonce", () => {
    if (seen !== state.watched || seen.has(i)) return;
    seen.add(i);
    caption.append(el("span", { class: "seen" }, " · ✓ seen"));
    gate();
  });
}

function stopPlayers() {
  for (const p of state.players) p.destroy();
  state.players = [];
}

function showPair(clips) {
  stopPlayers();
  state.clips = clips;
  state.watched = new Set();
  state.failed = false;
  const names = local() ? ["Anchor", "Candidate"] : ["Left", "Right"];
  const seen = state.watched;
  $("pair").replaceChildren(...clips.map((c, i) => {
    const caption = el("figcaption", {}, `${names[i]} · ${c.rollout_id}`);
    const figure = el("figure", {}, caption);
    const player = new ClipPlayer(figure, { label: `${names[i]} clip (${c.rollout_id})` });
    state.players.push(player);
    watch(player, i, caption);
    player.show(c).then(() => {
      if (player.failed && seen === state.watched) { state.failed = true; gate(); }
    });
    return figure;
  }));
}

function showQuestion() {
  const a = pretty(attribute());
  $("question").textContent = local()
    ? `Is the candidate the anchor with a little more or a little less ${a}, and otherwise the same?`
    : `Which clip shows more ${a}?`;
  // Only the label span changes: the key hints beside it stay.
  $("left-more").querySelector(".label").textContent = local() ? `A little less ${a}` : "Left has more";
  $("right-more").querySelector(".label").textContent = local() ? `A little more ${a}` : "Right has more";
  $("skip").querySelector(".label").textContent = local() ? "Not the same behaviour / next" : "Can’t tell / next";
}

async function nextClips(skip = false) {
  state.busy = true;
  gate();
  const q = { domain: domain(), size: "2", anchor: String(local()) };
  if (skip === true) q.seed = String(Math.floor(Math.random() * 1e9));
  try {
    const { clips } = await adminApi(`/api/admin/pairs?${query(q)}`);
    showPair(clips);
    showQuestion();
  } catch (e) {
    toast(e.message);
  } finally {
    state.busy = false;
    gate();
  }
}

function labelBody(side) {
  const [a, b] = state.clips.map((c) => c.rollout_id);
  if (local()) {
    return { domain: domain(), local_change: { attribute: attribute(), anchor: a, changed: b,
      direction: side === "right" ? "more" : "less" } };
  }
  const [more, less] = side === "left" ? [a, b] : [b, a];
  return { domain: domain(), comparison: { attribute: attribute(), more, less } };
}

async function answer(side) {
  if (!allowed(`${side}-more`)) return;
  state.busy = true;
  gate();
  try {
    await adminApi("/api/admin/labels", { method: "POST", body: JSON.stringify(labelBody(side)) });
    state.labels += 1;
    $("label-count").textContent = `· ${state.labels} saved this visit`;
  } catch (e) {
    toast(e.message);
    state.busy = false;
    gate();
    return;
  }
  await nextClips();
}

function skip() {
  if (allowed("skip")) nextClips(true);
}

async function addAttribute(event) {
  event.preventDefault();
  const name = $("attr-name").value.trim();
  try {
    await adminApi("/api/admin/attributes", { method: "POST", body: JSON.stringify({
      domain: domain(), name, description: $("attr-desc").value.trim() }) });
    $("attribute-form").reset();
    $("new-attribute").open = false;
    await loadAttributes();
    $("attribute").value = name;
    toast(`Added the attribute “${name}”: label it below.`, "info");  // replaces an earlier refusal's message
    $("attribute").focus();
    await nextClips();
  } catch (e) {
    toast(e.message);
  }
}

// ---------------------------------------------------------------- uploads
const NPZ_PROBLEM = /^trajector(y|ies)\b/;  // the server starts every problem of the .npz so

/** The server's problems, under the file each is about. */
function showProblems(body, status, labelsName, npzName) {
  const problems = Array.isArray(body?.problems) ? body.problems : null;
  if (!problems) {
    const detail = typeof body?.detail === "string" ? body.detail : `${status} (no details)`;
    $("upload-result").replaceChildren(el("p", { class: "refused" }, `Refused: ${detail}`));
    return;
  }
  const files = new Map([[labelsName, []], ...(npzName ? [[npzName, []]] : [])]);
  for (const p of problems) files.get(npzName && NPZ_PROBLEM.test(p) ? npzName : labelsName).push(p);
  $("upload-result").replaceChildren(
    el("p", { class: "refused" }, `Refused: nothing was stored. ${problems.length} problem${problems.length > 1 ? "s" : ""}`
      + " to fix, by file:"),
    ...[...files].map(([name, found]) => el("div", { class: "file-problems" },
      el("p", {}, el("strong", {}, name), found.length ? "" : " — no problems found"),
      found.length ? el("ul", {}, found.map((p) => el("li", {}, p))) : null)));
}

function showUploaded(d, duplicate) {
  const added = d.new_attributes.length ? `; new attributes: ${d.new_attributes.map(pretty).join(", ")}` : "";
  $("upload-result").replaceChildren(el("p", { class: "stored" }, duplicate
    ? `Already uploaded as dataset ${d.id}: nothing new stored.`
    : `Stored dataset ${d.id}: ${d.labels} labels, ${d.trajectories} trajectories${added}.`));
}

async function upload(event) {
  event.preventDefault();
  const labels = $("upload-labels").files[0];
  const npz = $("upload-npz").files[0];
  const form = new FormData();
  form.append("domain", domain());
  form.append("labels", labels);
  if (npz) form.append("trajectories", npz);
  $("upload-result").replaceChildren(el("p", {}, "Checking the files…"));
  let res;
  let body = null;
  try {  // not api(): the browser sets the multipart Content-Type (with its boundary) itself
    res = await fetch("/api/admin/datasets", { method: "POST", body: form,
                                               headers: { Authorization: `Bearer ${state.token}` } });
    body = await res.json();
  } catch {
    if (!res) { showProblems({ detail: "the server cannot be reached. Is `rba serve` running?" }, 0); return; }
  }
  if (!res.ok) { showProblems(body, res.status, labels.name, npz?.name); return; }
  showUploaded(body, res.status === 200);
  $("upload-form").reset();
  await Promise.all([loadAttributes(), loadDatasets()]);
}

/** Save the server's example label file for this domain (the route needs the token, so no plain link). */
async function downloadExample() {
  try {
    const labels = await adminApi(`/api/admin/datasets/example?${query({ domain: domain() })}`);
    const url = URL.createObjectURL(new Blob([JSON.stringify(labels, null, 2)], { type: "application/json" }));
    const link = el("a", { href: url, download: `labels-example-${domain()}.json` });
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(url), 1000);
  } catch (e) {
    toast(e.message);
  }
}

async function loadDatasets() {
  const datasets = await adminApi(`/api/admin/datasets?${query({ domain: domain() })}`);
  $("datasets-none").hidden = datasets.length > 0;
  $("datasets").replaceChildren(...datasets.map((d) => el("li", {}, el("label", {},
    el("input", { type: "checkbox", value: d.id, checked: true }),
    ` ${d.filename} · ${d.labels} labels · ${d.trajectories} trajectories`,
    d.new_attributes.length ? ` · new: ${d.new_attributes.map(pretty).join(", ")}` : "",
    " · use in training ", el("code", {}, d.id.slice(0, 8))))));
}

// ---------------------------------------------------------------- training
const running = (job) => Boolean(job) && ["queued", "running"].includes(job.state);

function duration(seconds) {
  if (seconds < 90) return `${Math.max(1, Math.round(seconds))} s`;
  if (seconds < 5400) return `${Math.round(seconds / 60)} min`;
  return `${(seconds / 3600).toFixed(1)} h`;
}

/** One bar for the whole job (the server weighs its stages); announced only when the job's state changes. */
function showJob(job) {
  state.job = job;
  const pct = Math.round(100 * (job?.progress || 0));
  $("bar").style.width = `${pct}%`;
  $("progress").setAttribute("aria-valuenow", String(pct));
  const cancelFocused = document.activeElement === $("cancel");
  $("cancel").hidden = !running(job);
  $("train").setAttribute("aria-disabled", String(running(job)));
  if (cancelFocused && !running(job)) $("train").focus();  // a hidden button drops the focus to the body
  if (!job) { $("job-status").textContent = "No training job yet."; $("job-detail").textContent = ""; return; }
  const result = job.version ? ` → version ${job.version}` : job.error ? ` — ${job.error}` : "";
  const status = `Job ${job.id.slice(0, 8)} (${job.method}/${job.rep}, ${job.preset}): ${job.state}${result}`;
  if (state.jobState !== status) { $("job-status").textContent = status; state.jobState = status; }
  const eta = job.eta_seconds == null ? "" : ` · about ${duration(job.eta_seconds)} left`;
  const loss = job.loss == null ? "" : `, loss ${job.loss.toFixed(4)}`;
  const where = job.total && running(job) ? ` · ${job.stage} step ${job.step}/${job.total}${loss}` : "";
  $("job-detail").textContent = running(job) || job.state === "succeeded" ? `${pct} % done${eta}${where}` : "";
  const log = $("job-log");
  const following = log.hidden || log.scrollTop + log.clientHeight >= log.scrollHeight - 4;  // at its end
  log.hidden = !job.log_tail;
  log.textContent = job.log_tail;
  if (following) log.scrollTop = log.scrollHeight;  // the newest lines, unless the admin scrolled up to read
}

async function pollJob() {
  if (!running(state.job)) return;
  try {
    const job = await adminApi(`/api/admin/jobs/${state.job.id}`);
    if (!state.token) return;  // locked while asking
    showJob(job);
    if (!state.curvesJob || state.curvesJob === job.id) await loadCurves();
  } catch (e) {
    if (state.token) toast(e.message);
  }
  if (running(state.job)) setTimeout(pollJob, 1000);
  else await Promise.all([loadVersions(), listJobs(), loadCurves()]);
}

async function loadLatestJob() {
  const jobs = await listJobs();
  showJob(jobs[0] || null);
  await loadCurves();
  pollJob();
}

/** The domain's jobs, newest first, in the curves' job picker (the one chosen stays chosen while it is listed). */
async function listJobs() {
  const jobs = await adminApi(`/api/admin/jobs?${query({ domain: domain() })}`);
  const pick = $("curves-job");
  pick.replaceChildren(...jobs.map((j) => el("option", { value: j.id },
    `${j.id.slice(0, 8)} · ${j.method}/${j.rep}, ${j.preset} · ${j.state}`)));
  if (!jobs.some((j) => j.id === state.curvesJob)) state.curvesJob = null;
  pick.value = state.curvesJob || jobs[0]?.id || "";
  $("curves-pick").hidden = !jobs.length;
  return jobs;
}

/** The chosen job's training curves (by default the latest job's, which the poll redraws while it runs). */
async function loadCurves() {
  const id = state.curvesJob || state.job?.id;
  const curves = id ? await adminApi(`/api/admin/jobs/${id}/curves`) : null;
  showCurves($("curves"), curves);
  const job = id === state.job?.id ? state.job : null;
  $("curves-none").textContent = running(job) ? "No curves yet: the first points come with the first steps."
    : "No curves for this job: a failed or cancelled job keeps none (nor does a version trained without them).";
  $("curves-none").hidden = !id || !$("curves").hidden;
}

async function chooseCurves() {
  const id = $("curves-job").value;
  state.curvesJob = id === state.job?.id ? null : id;  // the latest job's curves follow its poll
  await loadCurves();
}

async function train() {
  if (!allowed("train")) return;
  const datasets = [...$("datasets").querySelectorAll("input:checked")].map((c) => c.value);
  try {
    const body = { domain: domain(), preset: $("preset").value, rep: $("rep").value, method: $("train-method").value,
                   datasets };
    showJob(await adminApi("/api/admin/train", { method: "POST", body: JSON.stringify(body) }));
    state.curvesJob = null;
    await listJobs();
    pollJob();
  } catch (e) {
    toast(e.message);
  }
}

/** Stop the job once the admin confirms: minutes of training are lost on one click otherwise. */
async function cancel() {
  const job = state.job;
  if (!running(job)) return;
  $("confirm-cancel-text").textContent = `Job ${job.id.slice(0, 8)} (${job.method}/${job.rep}, ${job.preset}) is `
    + `${Math.round(100 * (job.progress || 0))} % done. Stopping it keeps nothing it made; the served models stay.`;
  if ((await ask($("confirm-cancel"))) !== "stop") { $("cancel").focus(); return; }
  try {
    showJob(await adminApi(`/api/admin/jobs/${job.id}/cancel`, { method: "POST" }));
    await Promise.all([listJobs(), loadCurves()]);  // the poll stops at a job that no longer runs
  } catch (e) {
    toast(e.message);
  }
}

// ---------------------------------------------------------------- versions
const number = (v) => (v == null ? "untested" : v.toFixed(3));

/** The version's held-out numbers beside those of what new sessions of its method/rep get now. */
function scoreTable(v) {
  const keys = [...new Set([...Object.keys(v.scores), ...Object.keys(v.baseline_scores)])];
  if (!keys.length) return el("p", { class: "small muted" }, "No held-out numbers in its model cards.");
  const worse = (k) => v.scores[k] === null || (v.scores[k] != null && v.baseline_scores[k] != null
    && v.scores[k] < v.baseline_scores[k]);
  return el("table", { class: "scores" },
    el("caption", { class: "sr-only" }, `Held-out numbers of ${v.version}${v.baseline ? ` and ${v.baseline}` : ""}`),
    el("thead", {}, el("tr", {}, el("th", { scope: "col" }, "held out (higher is better)"),
      el("th", { scope: "col" }, v.active ? "this version (serving)" : "this version"),
      v.baseline ? el("th", { scope: "col" }, `serving now: ${v.baseline}`) : null)),
    el("tbody", {}, keys.map((k) => el("tr", { class: worse(k) && v.baseline ? "worse" : "" },
      el("th", { scope: "row" }, pretty(k)),
      el("td", {}, k in v.scores ? number(v.scores[k]) : "—", worse(k) && v.baseline ? " ▼" : ""),
      v.baseline ? el("td", {}, k in v.baseline_scores ? number(v.baseline_scores[k]) : "—") : null))));
}

function versionItem(v) {
  return el("li", { class: v.active ? "version active" : "version" },
    el("div", { class: "version-head" },
      el("code", {}, v.version), ` ${v.method}/${v.rep} · ${v.attributes.map(pretty).join(", ")}`,
      v.active ? el("strong", { class: "serving", tabindex: "-1" }, " ✓ serving new sessions")
        : el("button", { class: "btn btn-small btn-dark", type: "button", "data-version": v.version,
                         "aria-label": `Activate ${v.version}`, onclick: () => activate(v) }, "Activate")),
    scoreTable(v),
    v.concerns.length ? el("p", { class: "concerns small" }, `⚠ ${v.concerns.map(pretty).join("; ")}`) : null);
}

async function loadVersions() {
  state.versions = await adminApi(`/api/admin/models?${query({ domain: domain() })}`);
  $("versions").replaceChildren(...state.versions.map(versionItem));
}

/** Open a confirming ``dialog`` with its safe choice (value "keep") focused; resolves to the value of the button
 * that closed it ("" for Escape). */
function ask(dialog) {
  dialog.returnValue = "";
  dialog.showModal();
  dialog.querySelector("[value=keep]").focus();  // the safe choice is the default
  return new Promise((resolve) => {
    dialog.addEventListener("close", () => resolve(dialog.returnValue), { once: true });
  });
}

/** Resolves true when the admin confirms activating ``v`` despite its concerns. */
async function confirmActivation(v) {
  $("confirm-title").textContent = `Activate ${v.version}? It may serve worse than ${v.baseline}`;
  $("confirm-concerns").replaceChildren(...v.concerns.map((c) => el("li", {}, pretty(c))));
  $("confirm-table").replaceChildren(scoreTable(v));
  return (await ask($("confirm"))) === "activate";
}

async function activate(v) {
  const opener = document.activeElement;
  if (v.concerns.length && !(await confirmActivation(v))) { opener?.focus(); return; }
  const q = v.version === "builtin" ? `?${query({ domain: domain() })}` : "";
  try {
    const done = await adminApi(`/api/admin/models/${encodeURIComponent(v.version)}/activate${q}`, { method: "POST" });
    toast(`New ${done.domain} sessions now get ${done.version}: ${done.attributes.map(pretty).join(", ")}.`, "info");
  } catch (e) {
    toast(e.message);
  }
  await loadVersions();
  ($("versions").querySelector(".serving") || $("h-versions")).focus();  // its button is gone: focus stays near
}

// ---------------------------------------------------------------- wiring
$("login").addEventListener("submit", unlock);
$("lock").addEventListener("click", lock);
$("domain").addEventListener("change", loadDomain);
$("attribute").addEventListener("change", nextClips);
$("mode").addEventListener("change", nextClips);
$("train-method").addEventListener("change", showPresets);
$("preset").addEventListener("change", aboutPreset);
$("example").addEventListener("click", downloadExample);
$("attribute-form").addEventListener("submit", addAttribute);
$("upload-form").addEventListener("submit", upload);
$("left-more").addEventListener("click", () => answer("left"));
$("right-more").addEventListener("click", () => answer("right"));
$("skip").addEventListener("click", skip);
$("train").addEventListener("click", train);
$("cancel").addEventListener("click", cancel);
$("curves-job").addEventListener("change", chooseCurves);
document.addEventListener("keydown", (e) => {
  // keys of their own: form fields, a video's controls (← → seek), the training log (↓ scrolls)
  if ($("admin").hidden || document.querySelector("dialog[open]") || e.target.closest("input, select, textarea, summary, video, pre, .clip-player")) return;
  const act = { ArrowLeft: () => answer("left"), ArrowRight: () => answer("right"), ArrowDown: skip }[e.key];
  if (!act) return;
  e.preventDefault();  // ↓ would scroll the page away from the clips
  act();
});
gate();
if (state.token) unlock();
