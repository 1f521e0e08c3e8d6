// The studio page's "where am I": each attribute on the library's scale (this clip, earlier clips, the agent's
// target interval) and, for two or three attributes, the path through attribute space as small SVG plots.
// Values are shown the way a person reads them: an attribute's `reading` (e.g. walker softness is minus a
// landing speed) flips the sign and names what is shown; `decimals` comes from the server.

import { el, pretty } from "./common.js";

const SVG = "http://www.w3.org/2000/svg";

/** The value as shown: sign applied, the attribute's decimals, its unit. */
export function formatValue(a, v) {
  if (v === undefined || v === null || Number.isNaN(v)) return "–";
  const shown = (a.reading ? a.reading.sign : 1) * v;
  const text = (Object.is(shown, -0) ? 0 : shown).toFixed(a.decimals ?? 2);
  return a.unit ? `${text} ${a.unit}` : text;
}

/** Where `v` sits on the library's range, 0 (least of the attribute) to 1 (most); null without a range. */
function position(a, v) {
  const span = (a.high ?? 0) - (a.low ?? 0);
  if (v === undefined || v === null || !(span > 0)) return null;
  return Math.max(0, Math.min(1, (v - a.low) / span));
}

const pct = (x) => `${(x * 100).toFixed(1)}%`;

/** One sentence for screen readers: the clip's values as shown. */
export function describe(attributes, clip) {
  return attributes.map((a) => `${a.reading ? a.reading.label : pretty(a.name)} ${formatValue(a, clip.measured[a.name])}`)
    .join(", ");
}

function targetOf(session, name) {
  return (session.target || []).find((t) => t.attribute === name) || null;
}

function scale(a, clip, session) {
  const bar = el("div", { class: "scale", "aria-hidden": "true" });
  const target = targetOf(session, a.name);
  if (target) {
    const lo = position(a, target.low), hi = position(a, target.high);
    if (lo !== null) bar.append(el("span", { class: "scale-band", style: `left:${pct(lo)};width:${pct(Math.max(hi - lo, 0.01))}` }));
  }
  for (const h of session.history) {
    const p = position(a, h.rollout_before.measured[a.name]);
    if (p !== null && h.rollout_before.rollout_id !== clip.rollout_id) {
      bar.append(el("span", { class: "scale-dot", style: `left:${pct(p)}` }));
    }
  }
  const p = position(a, clip.measured[a.name]);
  if (p !== null) bar.append(el("span", { class: "scale-mark", style: `left:${pct(p)}` }));
  return bar;
}

function meterLabel(a, clip, session) {
  const target = targetOf(session, a.name);
  const range = a.low === null || a.low === undefined ? ""
    : `, on a scale from ${formatValue(a, a.low)} to ${formatValue(a, a.high)}`;
  const aim = target ? `; the agent thinks your target is between ${formatValue(a, target.low)} and ${formatValue(a, target.high)}` : "";
  return `${pretty(a.name)}: ${formatValue(a, clip.measured[a.name])}${a.reading ? ` ${a.reading.label}` : ""}${range}${aim}`;
}

/** Rebuild the meters for `clip` (the current one or one being re-watched) of `session`. */
export function renderMeters(container, session, clip) {
  container.replaceChildren();
  for (const a of session.attributes) {
    const hasRange = a.low !== null && a.low !== undefined;
    container.append(el("div", { class: "meter", role: "img", "aria-label": meterLabel(a, clip, session) },
      el("div", { class: "meter-top" }, el("span", { class: "meter-name" }, pretty(a.name)),
        el("span", { class: "meter-value" }, formatValue(a, clip.measured[a.name]))),
      a.reading ? el("div", { class: "meter-sub" }, `${a.reading.label} · ${a.reading.note}`) : null,
      scale(a, clip, session),
      hasRange ? el("div", { class: "scale-ends", "aria-hidden": "true" },
        el("span", {}, formatValue(a, a.low)), el("span", { class: "scale-dir" }, `more ${pretty(a.name)} →`),
        el("span", {}, formatValue(a, a.high))) : null));
  }
}

const svg = (tag, attrs = {}, ...children) => {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, String(v));
  for (const c of children) if (c !== null && c !== undefined) node.append(c);
  return node;
};

const PAD = 14, SIDE = 100;
const xy = (px, py) => [PAD + px * (SIDE - PAD - 4), SIDE - PAD - py * (SIDE - PAD - 4)];

function pairPlot(ax, ay, session, clip) {
  const plot = svg("svg", { viewBox: `0 0 ${SIDE} ${SIDE}`, class: "path-plot", role: "img",
    "aria-label": `Path: ${pretty(ax.name)} across, ${pretty(ay.name)} up` });
  plot.append(svg("rect", { x: PAD, y: 4, width: SIDE - PAD - 4, height: SIDE - PAD - 4, class: "plot-frame" }));
  const tx = targetOf(session, ax.name), ty = targetOf(session, ay.name);
  if (tx && ty) {
    const [x0, y0] = xy(position(ax, tx.low), position(ay, ty.high));
    const [x1, y1] = xy(position(ax, tx.high), position(ay, ty.low));
    plot.append(svg("rect", { x: x0, y: y0, width: Math.max(x1 - x0, 1), height: Math.max(y1 - y0, 1), class: "plot-target" }));
  }
  const clips = [...session.history.map((h) => h.rollout_before), session.clip]
    .filter((c, i, all) => all.findIndex((d) => d.rollout_id === c.rollout_id) === i);
  const points = clips.map((c) => [c, position(ax, c.measured[ax.name]), position(ay, c.measured[ay.name])])
    .filter(([, px, py]) => px !== null && py !== null).map(([c, px, py]) => [c, ...xy(px, py)]);
  if (points.length > 1) plot.append(svg("polyline", { points: points.map(([, x, y]) => `${x},${y}`).join(" "), class: "plot-line" }));
  for (const [c, x, y] of points) {
    const current = c.rollout_id === clip.rollout_id;
    plot.append(svg("circle", { cx: x, cy: y, r: current ? 3.6 : 2.4, class: current ? "plot-now" : "plot-past" }));
  }
  plot.append(svg("text", { x: (PAD + SIDE) / 2, y: SIDE - 3, class: "plot-axis", "text-anchor": "middle" }, `${pretty(ax.name)} →`));
  plot.append(svg("text", { x: 0, y: 0, class: "plot-axis", "text-anchor": "middle",
    transform: `translate(8 ${(SIDE - PAD) / 2 + 2}) rotate(-90)` }, `${pretty(ay.name)} →`));
  return plot;
}

/** The path plots (one per pair of attributes) for two- or three-attribute domains; hidden otherwise. */
export function renderPath(figure, plots, session, clip) {
  const attrs = session.attributes.filter((a) => a.low !== null && a.low !== undefined);
  figure.hidden = attrs.length < 2 || attrs.length > 3;
  plots.replaceChildren();
  if (figure.hidden) return;
  for (let i = 0; i < attrs.length; i += 1) {
    for (let j = i + 1; j < attrs.length; j += 1) plots.append(pairPlot(attrs[i], attrs[j], session, clip));
  }
}
