// RBA Studio admin page: label clips (saved one by one), retrain in the background, switch the served model.
// Everything it shows comes from /api/admin routes, which need the admin token.

import { $, api, el, hideToast, pretty, toast } from "./common.js";

const state = { token: sessionStorage.getItem("rba-admin-token") || "", clips: [], job: null, labels: 0, trainable: [] };

/** The shared call with the admin token the /api/admin routes need. */
const adminApi = (path, options = {}) =>
  api(path, { ...options, headers: { Authorization: `Bearer ${state.token}`, ...options.headers } });

const domain = () => $("domain").value;
const attribute = () => $("attribute").value;
const local = () => $("mode").value === "local";

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
  sessionStorage.setItem("rba-admin-token", state.token);
  hideToast();  // a refused token's message is stale once the right one unlocks the page
  $("login").hidden = true;
  $("admin").hidden = false;
  const { domains, trainable, reps } = await api("/api/domains");
  $("domain").replaceChildren(...domains.map((d) => el("option", { value: d.name }, d.name)));
  state.trainable = trainable;
  $("train-method").replaceChildren(...trainable.map((m) => el("option", { value: m.method }, m.label)));
  $("rep").replaceChildren(...reps.map((r) => el("option", { value: r }, r)));
  showPresets();
  await loadDomain();
}

// The presets the chosen method's trainer knows (the server's method registry says which).
function showPresets() {
  const method = state.trainable.find((m) => m.method === $("train-method").value);
  $("preset").replaceChildren(...(method ? method.presets : []).map((p) => el("option", { value: p }, p)));
}

async function loadDomain() {
  const { attributes } = await adminApi(`/api/admin/attributes?domain=${encodeURIComponent(domain())}`);
  const keep = attribute();
  $("attribute").replaceChildren(...attributes.map((a) =>
    el("option", { value: a.name, title: a.description }, `${pretty(a.name)}${a.added ? " (added)" : ""}`)));
  if (attributes.some((a) => a.name === keep)) $("attribute").value = keep;
  await Promise.all([nextClips(), loadVersions(), loadLatestJob()]);
}

// ---------------------------------------------------------------- labelling
async function nextClips(skip = false) {
  const q = new URLSearchParams({ domain: domain(), size: "2", anchor: String(local()) });
  if (skip === true) q.set("seed", String(Math.floor(Math.random() * 1e9)));
  const { clips } = await adminApi(`/api/admin/pairs?${q}`);
  state.clips = clips;
  const names = local() ? ["Anchor", "Candidate"] : ["Left", "Right"];
  $("pair").replaceChildren(...clips.map((c, i) => el("figure", {},
    el("video", { src: c.url, muted: "", loop: "", autoplay: "", playsinline: "", "aria-label": `${names[i]} clip` }),
    el("figcaption", {}, `${names[i]} · ${c.rollout_id}`))));
  for (const v of $("pair").querySelectorAll("video")) { v.muted = true; v.play().catch(() => {}); }
  const a = pretty(attribute());
  $("question").textContent = local()
    ? `Is the candidate the anchor with a little more or a little less ${a}, and otherwise the same?`
    : `Which clip shows more ${a}?`;
  $("left-more").textContent = local() ? `A little less ${a}` : "◀ Left has more";
  $("right-more").textContent = local() ? `A little more ${a}` : "Right has more ▶";
  $("skip").textContent = local() ? "Not the same behaviour / next" : "Can’t tell / next";
}

async function answer(side) {
  if (state.clips.length < 2) return;
  const [a, b] = state.clips.map((c) => c.rollout_id);
  let body;
  if (local()) {
    body = { domain: domain(), local_change: { attribute: attribute(), anchor: a, changed: b,
      direction: side === "right" ? "more" : "less" } };
  } else {
    const [more, less] = side === "left" ? [a, b] : [b, a];
    body = { domain: domain(), comparison: { attribute: attribute(), more, less } };
  }
  try {
    await adminApi("/api/admin/labels", { method: "POST", body: JSON.stringify(body) });
    state.labels += 1;
    $("label-count").textContent = `· ${state.labels} saved this visit`;
  } catch (e) {
    toast(e.message);
    return;
  }
  await nextClips();
}

async function addAttribute(event) {
  event.preventDefault();
  try {
    await adminApi("/api/admin/attributes", { method: "POST", body: JSON.stringify({
      domain: domain(), name: $("attr-name").value.trim(), description: $("attr-desc").value.trim() }) });
    const name = $("attr-name").value.trim();
    $("attribute-form").reset();
    $("new-attribute").open = false;
    await loadDomain();
    $("attribute").value = name;
    await nextClips();
  } catch (e) {
    toast(e.message);
  }
}

// ---------------------------------------------------------------- training and versions
function showJob(job) {
  state.job = job;
  $("bar").style.width = `${Math.round(100 * (job?.progress || 0))}%`;
  $("cancel").hidden = !job || !["queued", "running"].includes(job.state);
  $("train").disabled = !$("cancel").hidden;
  if (!job) { $("job-status").textContent = "No training job yet."; return; }
  const loss = job.loss == null ? "" : `, loss ${job.loss.toFixed(4)}`;
  const where = job.total ? ` ${job.stage} step ${job.step}/${job.total}${loss}` : "";
  const result = job.version ? ` → version ${job.version}` : job.error ? ` — ${job.error}` : "";
  $("job-status").textContent = `Job ${job.id.slice(0, 8)}: ${job.state}${where}${result}`;
  $("job-log").hidden = !job.log_tail;
  $("job-log").textContent = job.log_tail;
}

async function pollJob() {
  if (!state.job || !["queued", "running"].includes(state.job.state)) return;
  try {
    showJob(await adminApi(`/api/admin/jobs/${state.job.id}`));
  } catch (e) {
    toast(e.message);
  }
  if (["queued", "running"].includes(state.job.state)) setTimeout(pollJob, 1000);
  else await loadVersions();
}

async function loadLatestJob() {
  const jobs = await adminApi(`/api/admin/jobs?domain=${encodeURIComponent(domain())}`);
  showJob(jobs[0] || null);
  pollJob();
}

async function train() {
  try {
    const body = { domain: domain(), preset: $("preset").value, rep: $("rep").value, method: $("train-method").value };
    showJob(await adminApi("/api/admin/train", { method: "POST", body: JSON.stringify(body) }));
    pollJob();
  } catch (e) {
    toast(e.message);
  }
}

async function cancel() {
  try { showJob(await adminApi(`/api/admin/jobs/${state.job.id}/cancel`, { method: "POST" })); } catch (e) { toast(e.message); }
}

async function loadVersions() {
  const versions = await adminApi(`/api/admin/models?domain=${encodeURIComponent(domain())}`);
  $("versions").replaceChildren(...versions.map((v) => {
    const held = v.held_out?.argmax_within_epsilon?.normal;
    return el("li", {},
      el("code", {}, v.version), `${v.method}/${v.rep} · ${v.attributes.map(pretty).join(", ")}`,
      held === undefined ? "" : ` · argmax within ε ${held.toFixed(2)}`,
      v.active ? el("strong", {}, " ✓ serving new sessions")
        : el("button", { class: "btn btn-small btn-dark", type: "button", onclick: () => activate(v.version) }, "Activate"));
  }));
}

async function activate(version) {
  const q = version === "builtin" ? `?domain=${encodeURIComponent(domain())}` : "";
  try {
    await adminApi(`/api/admin/models/${encodeURIComponent(version)}/activate${q}`, { method: "POST" });
  } catch (e) {
    toast(e.message);
  }
  await loadVersions();
}

// ---------------------------------------------------------------- wiring
$("login").addEventListener("submit", unlock);
$("domain").addEventListener("change", loadDomain);
$("attribute").addEventListener("change", nextClips);
$("mode").addEventListener("change", nextClips);
$("train-method").addEventListener("change", showPresets);
$("attribute-form").addEventListener("submit", addAttribute);
$("left-more").addEventListener("click", () => answer("left"));
$("right-more").addEventListener("click", () => answer("right"));
$("skip").addEventListener("click", () => nextClips(true));
$("train").addEventListener("click", train);
$("cancel").addEventListener("click", cancel);
document.addEventListener("keydown", (e) => {
  if ($("admin").hidden || e.target.closest("input, select, textarea")) return;
  if (e.key === "ArrowLeft") answer("left");
  else if (e.key === "ArrowRight") answer("right");
  else if (e.key === "ArrowDown") nextClips(true);
});
if (state.token) unlock();
