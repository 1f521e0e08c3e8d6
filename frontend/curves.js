// Training curves on the admin page: per model, the loss and the held-out measures against the step as inline SVG
// (labelled axes, a title and a description), a one-line text summary, and every value in a table.

import { el } from "./common.js";

const SVG = "http://www.w3.org/2000/svg";
const WIDTH = 340;
const HEIGHT = 190;
const PAD = { left: 56, right: 12, top: 10, bottom: 38 };
const COLORS = ["#4f46e5", "#0f766e", "#b45309", "#be185d", "#1d4ed8", "#15803d"];  // each ≥ 4.5:1 on white
let shown = "";  // the curves drawn now (JSON): a poll that brings nothing new redraws nothing

const svg = (tag, attrs = {}, ...children) => {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  for (const c of children) node.append(c);
  return node;
};

const fmt = (v) => (v == null ? "–" : Math.abs(v) >= 100 || v === 0 ? String(Math.round(v)) : v.toPrecision(3));
const label = (tag) => tag.replace(/^held_out\//, "").replaceAll("_", " ");

/** [lo, hi] of every finite value of ``series`` (a flat range is widened so it has a height). */
function range(series) {
  const values = series.flatMap((s) => s.values.filter((v) => v != null && Number.isFinite(v)));
  let lo = Math.min(...values), hi = Math.max(...values);
  if (!values.length) [lo, hi] = [0, 1];
  if (hi - lo < 1e-9) [lo, hi] = [lo - 0.5, hi + 0.5];
  return [lo, hi];
}

/** One chart: ``series`` against the step, its axes labelled ("step", ``yTitle``), described for screen readers. */
function chart(id, title, yTitle, series, lastStep) {
  const [lo, hi] = range(series);
  const w = WIDTH - PAD.left - PAD.right, h = HEIGHT - PAD.top - PAD.bottom;
  const x = (step) => PAD.left + (w * step) / Math.max(lastStep, 1);
  const y = (v) => PAD.top + h - (h * (v - lo)) / (hi - lo);
  const desc = series.map((s) => `${label(s.tag)}: ${s.steps.length} points, ${fmt(s.values[0])} at step `
    + `${s.steps[0]} to ${fmt(s.values.at(-1))} at step ${s.steps.at(-1)}`).join("; ");
  const ticks = [lo, (lo + hi) / 2, hi].map((v) => svg("g", {},
    svg("line", { x1: PAD.left - 4, x2: PAD.left, y1: y(v), y2: y(v), class: "axis" }),
    svg("text", { x: PAD.left - 7, y: y(v) + 4, "text-anchor": "end" }, fmt(v))));
  const steps = [0, Math.round(lastStep / 2), lastStep].map((s) => svg("text", {
    x: x(s), y: PAD.top + h + 15, "text-anchor": "middle" }, String(s)));
  const lines = series.map((s, i) => {
    const pts = s.steps.map((st, j) => [st, s.values[j]]).filter(([, v]) => v != null && Number.isFinite(v));
    const g = svg("g", { class: "series", "data-tag": s.tag },
      svg("polyline", { points: pts.map(([st, v]) => `${x(st).toFixed(1)},${y(v).toFixed(1)}`).join(" "),
                        fill: "none", stroke: COLORS[i % COLORS.length], "stroke-width": 2 }));
    if (pts.length <= 20) {
      for (const [st, v] of pts) g.append(svg("circle", { cx: x(st), cy: y(v), r: 3, fill: COLORS[i % COLORS.length] }));
    }
    return g;
  });
  return svg("svg", { viewBox: `0 0 ${WIDTH} ${HEIGHT}`, role: "img", "aria-labelledby": `${id}-t ${id}-d`,
                      class: "curve", "data-chart": yTitle },
    svg("title", { id: `${id}-t` }, title), svg("desc", { id: `${id}-d` }, desc),
    svg("line", { x1: PAD.left, x2: PAD.left, y1: PAD.top, y2: PAD.top + h, class: "axis" }),
    svg("line", { x1: PAD.left, x2: PAD.left + w, y1: PAD.top + h, y2: PAD.top + h, class: "axis" }),
    ...ticks, ...steps, ...lines,
    svg("text", { x: PAD.left + w / 2, y: HEIGHT - 4, "text-anchor": "middle", class: "axis-title" }, "step"),
    svg("text", { x: 12, y: PAD.top + h / 2, "text-anchor": "middle", class: "axis-title",
                  transform: `rotate(-90 12 ${PAD.top + h / 2})` }, yTitle));
}

const legend = (series) => el("ul", { class: "legend small" }, series.map((s, i) =>
  el("li", {}, el("span", { class: "swatch", style: `background:${COLORS[i % COLORS.length]}`, "aria-hidden": "true" }),
    label(s.tag))));

/** Every value of the model's series, one row per step any of them has. */
function table(model) {
  const steps = [...new Set(model.series.flatMap((s) => s.steps))].sort((a, b) => a - b);
  const at = model.series.map((s) => new Map(s.steps.map((st, j) => [st, s.values[j]])));
  return el("table", { class: "small" }, el("caption", {}, `${model.model}: every value`),
    el("thead", {}, el("tr", {}, el("th", { scope: "col" }, "step"),
      model.series.map((s) => el("th", { scope: "col" }, label(s.tag))))),
    el("tbody", {}, steps.map((st) => el("tr", {}, el("th", { scope: "row" }, String(st)),
      at.map((m) => el("td", {}, m.has(st) ? fmt(m.get(st)) : ""))))));
}

function summary(model) {
  const parts = model.series.map((s) => `${label(s.tag)} ${fmt(s.values[0])} at step ${s.steps[0]} → `
    + `${fmt(s.values.at(-1))} at step ${s.steps.at(-1)}`);
  return el("p", { class: "small curve-summary" }, `${model.model}: ${parts.join("; ")}.`);
}

function figure(model, index, open) {
  const loss = model.series.filter((s) => s.tag === "loss");
  const held = model.series.filter((s) => s.tag !== "loss");
  const last = Math.max(...model.series.map((s) => s.steps.at(-1) || 0));
  const charts = [];
  if (loss.length) charts.push(el("div", {}, chart(`curve-${index}-loss`, `${model.model}: training loss`, "loss", loss, last)));
  if (held.length) {
    charts.push(el("div", {}, chart(`curve-${index}-held`, `${model.model}: held-out measures on val`, "held out",
                                    held, last), legend(held)));
  }
  const details = el("details", { "data-model": model.model }, el("summary", {}, "Show the values"), table(model));
  details.open = open.has(model.model);
  return el("figure", { class: "curves-model", "data-model": model.model },
    el("figcaption", {}, model.model), el("div", { class: "row charts" }, ...charts), summary(model), details);
}

/** Draw ``curves`` (GET /api/admin/jobs/{id}/curves, or null: none) into ``box``, keeping open tables open. */
export function showCurves(box, curves) {
  const models = curves?.models.filter((m) => m.series.some((s) => s.steps.length)) || [];
  const key = JSON.stringify(models);
  if (key === shown) return;
  shown = key;
  const open = new Set([...box.querySelectorAll("details[open]")].map((d) => d.dataset.model));
  box.hidden = !models.length;
  box.querySelector(".curves-list").replaceChildren(...models.map((m, i) => figure(m, i, open)));
}
