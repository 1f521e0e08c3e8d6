// The admin page's Studies panel: set up a study with people, make one link per participant, watch the results
// come in (a table per condition with 95 % CIs, SR@k drawn per condition, the paired test, everyone's progress) and
// download the export. Everything comes from the token-checked /api/admin/studies routes.

import { $, el, pretty, toast } from "./common.js";

const SVG = "http://www.w3.org/2000/svg";
const REFRESH_MS = 3000;
const COLORS = ["#4f46e5", "#b45309", "#0f766e", "#be185d", "#1d4ed8", "#15803d"];  // each ≥ 4.5:1 on white
const RANDOM = { method: "random", rep: null, label: "Random (floor: ignores the answers)" };
const CONSENT = "You are invited to a study of how people tune a simulated agent's behaviour. In each trial you "
  + "watch short clips and press “more” or “less” until the agent does what is asked. It takes about 20 minutes. "
  + "We record your answers, the clips you saw and how long you took; nothing that identifies you.\n\n"
  + "Taking part is voluntary. You may withdraw at any time with the button at the top of the page, and "
  + "everything you answered is then deleted.";

const st = { adminApi: null, token: () => "", domains: [], studies: [], study: null, timer: null, shown: "" };

const svg = (tag, attrs = {}, ...children) => {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  for (const c of children) node.append(c);
  return node;
};

const num = (v, digits = 2) => (v == null || !Number.isFinite(v) ? "–" : v.toFixed(digits));
/** "0.83 [0.61, 0.94]" from an estimate with its 95 % interval ({value, low, high}; null parts as "–"). */
const withCi = (e, digits = 2) => (e == null || e.value == null ? "–"
  : `${num(e.value, digits)} [${num(e.low, digits)}, ${num(e.high, digits)}]`);

// ---------------------------------------------------------------- the form
function conditionChoices() {
  const d = st.domains.find((x) => x.name === $("study-domain").value);
  const pairs = [...(d ? d.available : []).map((m) => ({ method: m.method, rep: m.rep,
    label: `${m.label || m.method}${m.rep === "onehot" ? "" : ` · ${m.rep}`}` })), RANDOM];
  $("study-conditions").replaceChildren(el("legend", {}, "Conditions (two or more)"), ...pairs.map((c, i) => {
    const checked = c === RANDOM || i === 0;
    return el("label", { class: "check" }, el("input", { type: "checkbox", name: "condition", checked,
      value: JSON.stringify({ method: c.method, rep: c.rep }) }), c.label);
  }));
}

async function create(event) {
  event.preventDefault();
  const conditions = [...document.querySelectorAll('#study-conditions input[name="condition"]:checked')]
    .map((i) => JSON.parse(i.value));
  const body = {
    name: $("study-name").value.trim(), domain: $("study-domain").value, conditions, task: $("study-task").value,
    targets_per_condition: Number($("study-targets").value), answer_budget: Number($("study-budget").value),
    precision: $("study-precision").value, consent_text: $("study-consent").value.trim(),
    seed: $("study-seed").value === "" ? null : Number($("study-seed").value),
  };
  try {
    const study = await st.adminApi("/api/admin/studies", { method: "POST", body: JSON.stringify(body) });
    toast(`Study “${study.config.name}” created: make its participants' links below.`, "info");
    await loadStudies(study.id);
  } catch (e) {
    toast(e.message);
  }
}

// ---------------------------------------------------------------- the list and one study
async function loadStudies(pick) {
  st.studies = await st.adminApi("/api/admin/studies");
  const keep = pick || $("study-pick").value;
  $("study-pick").replaceChildren(...st.studies.map((s) => el("option", { value: s.id },
    `${s.config.name} · ${s.config.domain} · ${new Date(s.created).toLocaleString()}`)));
  $("study-none").hidden = st.studies.length > 0;
  $("study-pick-field").hidden = !st.studies.length;
  if (st.studies.some((s) => s.id === keep)) $("study-pick").value = keep;
  await showStudy();
}

/** "RBA-Global", "RBA-Local · language", "Random": the method's label as the catalog gives it. */
function conditionName(c) {
  if (c.method === RANDOM.method) return "Random";
  const m = st.domains.flatMap((d) => d.available).find((x) => x.method === c.method && x.rep === c.rep);
  return `${m ? m.label || c.method : c.method}${c.rep && c.rep !== "onehot" ? ` · ${c.rep}` : ""}`;
}

async function showStudy() {
  const s = st.studies.find((x) => x.id === $("study-pick").value) || null;
  st.study = s;
  st.shown = "";
  $("study-view").hidden = !s;
  $("study-links").replaceChildren();
  if (!s) return;
  const c = s.config;
  $("study-about").textContent = `${pretty(c.domain)}: ${c.conditions.map(conditionName).join(" vs ")}; task `
    + `${c.task === "target" ? "reach a shown target" : "free personalisation"}; ${c.targets_per_condition} trials `
    + `per condition, at most ${c.answer_budget} answers each; ${c.precision} precision; ${s.participants} links made.`;
  await refreshResults();
}

async function makeLinks(event) {
  event.preventDefault();
  if (!st.study) return;
  try {
    const r = await st.adminApi(`/api/admin/studies/${st.study.id}/participants`,
      { method: "POST", body: JSON.stringify({ count: Number($("study-count").value) }) });
    const links = r.participants.map((p) => new URL(p.link, location.origin).href);
    const area = el("textarea", { readonly: true, rows: Math.min(links.length, 8), class: "links",
      "aria-label": "The new participants' links, one a line" });
    area.value = links.join("\n");
    const copy = el("button", { type: "button", class: "btn btn-outline btn-small", onclick: async () => {
      try { await navigator.clipboard.writeText(area.value); toast("Links copied.", "info"); } catch {
        area.select(); toast("Select all and copy (Ctrl+C): the browser did not allow copying.", "info");
      }
    } }, "Copy the links");
    $("study-links").replaceChildren(el("p", { class: "small" }, `${links.length} new links: each is shown only `
      + "now (the server keeps only a hash), so copy them before leaving the page."), area, copy);
    st.study.participants += links.length;
    await refreshResults();
  } catch (e) {
    toast(e.message);
  }
}

async function download() {
  if (!st.study) return;
  try {
    const res = await fetch(`/api/admin/studies/${st.study.id}/export`,
      { headers: { Authorization: `Bearer ${st.token()}` } });
    if (!res.ok) throw new Error(`${res.status} ${res.statusText}`);
    const url = URL.createObjectURL(await res.blob());
    const a = el("a", { href: url, download: `study-${st.study.id}.zip` });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10_000);
  } catch (e) {
    toast(`The export failed: ${e.message}`);
  }
}

// ---------------------------------------------------------------- results
const ksOf = (r) => r.sr_at_k.map(String);

function resultsTable(r) {
  const ks = ksOf(r);
  const head = ["Condition", "Trials", "Successes", "SR", "AF (successes)", ...ks.map((k) => `SR@${k}`), "Answers",
    "Median time per answer"];
  return el("table", { class: "scores study-table" },
    el("caption", {}, `Per condition, finished trials, with 95 % intervals (${r.intervals})`),
    el("thead", {}, el("tr", {}, head.map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, r.conditions.map((c) => el("tr", { dataset: { condition: `${c.method}/${c.rep}` } },
      el("th", { scope: "row" }, conditionName(c)), el("td", {}, String(c.trials)), el("td", {}, String(c.successes)),
      el("td", {}, withCi(c.sr)), el("td", {}, withCi(c.af, 1)), ks.map((k) => el("td", {}, withCi(c.sr_at[k]))),
      el("td", {}, String(c.answers)),
      el("td", {}, c.median_ms_per_answer == null ? "–" : `${num(c.median_ms_per_answer / 1000, 1)} s`)))));
}

/** SR@k against k per condition: points with their CI bars, a line through each condition's points. */
function srPlot(r) {
  const W = 360, H = 200, P = { left: 48, right: 12, top: 10, bottom: 36 };
  const ks = ksOf(r);
  const w = W - P.left - P.right, h = H - P.top - P.bottom;
  const x = (i) => P.left + (w * (i + 0.5)) / ks.length;  // k as categories, each in the middle of its band
  const y = (v) => P.top + h - h * v;
  const desc = r.conditions.map((c) => `${conditionName(c)}: ${ks.map((k) => `SR@${k} ${num(c.sr_at[k]?.value)}`)
    .join(", ")}`).join("; ");
  const series = r.conditions.map((c, n) => {
    const color = COLORS[n % COLORS.length];
    const dx = (n - (r.conditions.length - 1) / 2) * 5;  // side by side, so CI bars do not hide each other
    const pts = ks.map((k, i) => [x(i) + dx, c.sr_at[k]]).filter(([, e]) => e && e.value != null);
    return svg("g", { class: "series", "data-condition": `${c.method}/${c.rep}` },
      svg("polyline", { points: pts.map(([px, e]) => `${px},${y(e.value)}`).join(" "), fill: "none", stroke: color,
        "stroke-width": 2 }),
      ...pts.flatMap(([px, e]) => [
        svg("line", { x1: px, x2: px, y1: y(e.high ?? e.value), y2: y(e.low ?? e.value), stroke: color }),
        svg("circle", { cx: px, cy: y(e.value), r: 3.5, fill: color })]));
  });
  const plot = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", class: "curve study-plot",
    "aria-labelledby": "sr-plot-t sr-plot-d" },
  svg("title", { id: "sr-plot-t" }, "Success rate within k answers (SR@k) per condition, with 95 % CIs"),
  svg("desc", { id: "sr-plot-d" }, desc),
  svg("line", { x1: P.left, x2: P.left, y1: P.top, y2: P.top + h, class: "axis" }),
  svg("line", { x1: P.left, x2: P.left + w, y1: P.top + h, y2: P.top + h, class: "axis" }),
  ...[0, 0.5, 1].map((v) => svg("text", { x: P.left - 6, y: y(v) + 4, "text-anchor": "end" }, String(v))),
  ...ks.map((k, i) => svg("text", { x: x(i), y: P.top + h + 15, "text-anchor": "middle" }, String(k))),
  svg("text", { x: P.left + w / 2, y: H - 4, "text-anchor": "middle", class: "axis-title" }, "k (answers)"),
  svg("text", { x: 12, y: P.top + h / 2, "text-anchor": "middle", class: "axis-title",
    transform: `rotate(-90 12 ${P.top + h / 2})` }, "SR@k"), ...series);
  const legend = el("ul", { class: "legend small" }, r.conditions.map((c, n) => el("li", {},
    el("span", { class: "swatch", style: `background:${COLORS[n % COLORS.length]}`, "aria-hidden": "true" }),
    conditionName(c))));
  return el("figure", { class: "study-figure" }, plot, legend);
}

/** One line per pair of conditions: the per-participant difference of SR@k and the test the server ran on it. */
function comparisons(r) {
  const c = r.comparison;
  const name = (i) => conditionName(r.conditions[i]);
  return el("ul", { class: "comparisons", id: "study-comparison" }, c.pairs.map((p) => {
    const pv = p.p_value == null ? "no p-value yet" : `p = ${p.p_value < 0.001 ? p.p_value.toExponential(1)
      : num(p.p_value, 3)}`;
    return el("li", { dataset: { a: String(p.a), b: String(p.b) } },
      `${c.measure} per participant, ${name(p.a)} minus ${name(p.b)} (n = ${p.n}, median difference `
      + `${num(p.median_difference)}): ${p.test}; ${pv}.`);
  }));
}

function questionnaires(r) {
  const q = r.questionnaires;
  return el("p", { class: "small", id: "study-questionnaires" }, `Questionnaires (n = ${q.n}): satisfaction `
    + `(${q.satisfaction.scale}) ${withCi(q.satisfaction, 1)}; usability (${q.usability.scale}) `
    + `${withCi(q.usability, 1)}.`);
}

function progressTable(r) {
  return el("table", { class: "scores study-progress-table" },
    el("caption", {}, `Participants' progress (${r.participants}; those who withdrew are left out)`),
    el("thead", {}, el("tr", {}, ["#", "Consented", "Trials done", "Finished"].map((h) => el("th", { scope: "col" }, h)))),
    el("tbody", {}, r.progress.map((p) => el("tr", { dataset: { participant: p.participant_id } },
      el("th", { scope: "row" }, String(p.number + 1)), el("td", {}, p.consented ? "yes" : "not yet"),
      el("td", {}, `${p.trials_done} of ${p.trials_total}`), el("td", {}, p.finished ? "yes" : "no")))));
}

function showResults(r) {
  const key = JSON.stringify(r);
  if (key === st.shown) return;
  st.shown = key;
  $("study-results").replaceChildren(resultsTable(r), srPlot(r), comparisons(r), questionnaires(r),
    progressTable(r));
  $("study-results").dataset.updated = String(Date.now());
}

async function refreshResults() {
  if (!st.study) return;
  try {
    showResults(await st.adminApi(`/api/admin/studies/${st.study.id}/results`));
  } catch (e) {
    $("study-results").replaceChildren(el("p", { class: "small" }, `Results unavailable: ${e.message}`));
  }
}

function poll() {
  clearTimeout(st.timer);
  st.timer = setTimeout(async () => {
    if (!$("admin").hidden && st.study) await refreshResults();
    if (!$("admin").hidden) poll();
  }, REFRESH_MS);
}

// ---------------------------------------------------------------- mount
/** Fill the Studies panel and follow the chosen study's results (admin.js calls it on unlock): ``adminApi`` is its
 * token-carrying call, ``token()`` the token itself (the export is a download, not JSON). */
export async function mountStudies(adminApi, token, domains) {
  st.adminApi = adminApi;
  st.token = token;
  st.domains = domains.filter((d) => d.available.length);
  if (!$("study-domain").options.length) {
    $("study-domain").replaceChildren(...st.domains.map((d) => el("option", { value: d.name }, pretty(d.name))));
    $("study-domain").addEventListener("change", conditionChoices);
    $("study-consent").value = CONSENT;
    $("study-form").addEventListener("submit", create);
    $("study-pick").addEventListener("change", showStudy);
    $("study-links-form").addEventListener("submit", makeLinks);
    $("study-export").addEventListener("click", download);
    conditionChoices();
  }
  try {
    await loadStudies();
  } catch (e) {
    $("study-none").textContent = `The studies cannot be listed: ${e.message}`;
    return;
  }
  poll();
}
