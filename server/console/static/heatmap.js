// The coverage heatmap of a floor (GET /v1/floors/{id}/maps/coverage): its grid's cells
// coloured by a chosen figure on fixed class edges (so that floors compare), a legend, and
// the figures of the cell under the pointer. Cells are drawn in floor metres inside the
// floor map's y-flipped group: one path per colour class.

import { get } from "./api.js";
import { fill, h, num, s } from "./dom.js";

// good to bad (ColorBrewer RdYlGn, reversed)
const PALETTE = ["#1a9850", "#66bd63", "#a6d96a", "#d9ef8b", "#fee08b", "#fdae61", "#f46d43", "#d73027"];
const NO_DATA = "#adb5bd";
const OPACITY = 0.6;

// per figure: class edges (a class holds edge[i] <= value < edge[i + 1]) and which end is
// good. Counts, variances and ages on fixed edges, so floors compare; the expected error on
// round steps over the floor's own range ("auto"), since the map's fix-error table sets its
// scale (a learned table may put a whole floor under 4 m, the default one over 5.7 m)
export const METRICS = {
  expected_error_m: { label: "Expected error", unit: "m", edges: "auto", good: "low", digits: 2 },
  readings: { label: "Readings", unit: "", edges: [1, 10, 50, 200, 1000], good: "high", digits: 0, below: "none" },
  var_db2: { label: "RSS variance", unit: "dB²", edges: [4, 9, 16, 25, 36], good: "low", digits: 1 },
  age_days: { label: "Age of the newest point", unit: "days", edges: [1, 7, 30, 90, 365], good: "low", digits: 1 },
};

const STEPS = [1, 2, 2.5, 5, 10];
const AUTO_CLASSES = 6;

/** Round class edges over the range of the values drawn: at most AUTO_CLASSES classes. */
function autoEdges(values) {
  const finite = values.filter((v) => v !== null && Number.isFinite(v));
  if (!finite.length) return [];
  const lo = Math.min(...finite);
  const hi = Math.max(...finite);
  if (hi - lo < 1e-6) return [];
  const raw = (hi - lo) / AUTO_CLASSES;
  const power = 10 ** Math.floor(Math.log10(raw));
  const step = power * STEPS.find((m) => m * power >= raw);
  const edges = [];
  for (let k = Math.floor(lo / step) + 1; k * step < hi; k += 1) edges.push(Number((k * step).toFixed(6)));
  return edges;
}

/** The colours of a figure's classes, first class first. */
function colours(metric) {
  const n = metric.edges.length + 1;
  const picked = Array.from({ length: n }, (_, i) => PALETTE[n > 1 ? Math.round((i * (PALETTE.length - 1)) / (n - 1)) : 0]);
  return metric.good === "low" ? picked : picked.reverse();
}

/** The class of a value: how many edges it reaches; -1 for no value. */
function classOf(metric, value) {
  if (value === null || value === undefined) return -1;
  let k = 0;
  while (k < metric.edges.length && value >= metric.edges[k]) k += 1;
  return k;
}

function classText(metric, k) {
  const { edges, unit, digits, below } = metric;
  const u = unit ? ` ${unit}` : "";
  if (!edges.length) return "all cells";
  if (k === 0) return below ?? `under ${num(edges[0], digits)}${u}`;
  if (k === edges.length) return `${num(edges[k - 1], digits)}${u} or more`;
  return `${num(edges[k - 1], digits)}–${num(edges[k], digits)}${u}`;
}

function swatch(colour) {
  return s("svg", { class: "swatch-box", width: 14, height: 14, viewBox: "0 0 14 14", "aria-hidden": "true" }, s("rect", { width: 14, height: 14, rx: 2, fill: colour, "fill-opacity": OPACITY + 0.2 }));
}

export class Heatmap {
  /** `layer`: the floor map's SVG group to draw in (floor metres). */
  constructor(layer) {
    this.layer = layer;
    this.grid = null;
    this.metric = "expected_error_m";
    this.select = h(
      "select",
      { name: "heatmap-metric", "aria-label": "figure the cells are coloured by", onchange: (e) => this.draw(e.target.value) },
      Object.entries(METRICS).map(([name, m]) => h("option", { value: name }, m.label)),
    );
    this.legend = h("ul", { class: "heat-legend" });
    this.summary = h("p", { class: "muted heat-summary" }, "loading…");
    this.readout = h("p", { class: "heat-readout muted" }, "Point at a cell for its figures.");
    this.element = h("div", { class: "heatmap" }, h("label", { class: "check" }, "Colour by ", this.select), this.legend, this.summary, this.readout);
    layer.addEventListener("pointermove", (event) => this.#point(event));
  }

  /** Fetch the floor's grid and draw it. */
  async load(floorId, { signal, cellM } = {}) {
    const grid = await get(`/v1/floors/${floorId}/maps/coverage`, cellM ? { cell_m: cellM } : {}, { signal });
    this.set(grid);
    return grid;
  }

  /** Draw a grid (a CoverageGridRead). */
  set(grid) {
    this.grid = grid;
    const { rows, cols, cells } = grid;
    let area = 0;
    let sampled = 0;
    for (let i = 0; i < rows; i += 1)
      for (let j = 0; j < cols; j += 1)
        if (cells.in_area[i][j]) {
          area += 1;
          if (cells.readings[i][j] > 0) sampled += 1;
        }
    const table = grid.fix_error === "learned" ? "the fix-error table learned with the map" : "the default fix-error table";
    this.summary.textContent = rows
      ? `${sampled} of ${area} cells of ${num(grid.cell_m)} m hold readings${grid.walkable_area_known ? "" : " (no plan: over the survey's extent)"}; errors from ${table}.`
      : "No plan and no survey on this floor: no cells.";
    this.draw(this.metric);
  }

  /** Colour the cells by a figure (a key of METRICS). */
  draw(name) {
    this.metric = name;
    this.select.value = name;
    const layer = this.layer;
    layer.replaceChildren();
    layer.dataset.metric = name;
    const grid = this.grid;
    if (!grid) return;
    const { rows, cols, cell_m: c, cells } = grid;
    const [x0, y0] = grid.origin_m;
    const values = cells[name];
    const shown = (i, j) => cells.in_area[i][j] || cells.readings[i][j] > 0 || cells.points[i][j] > 0;
    let metric = METRICS[name];
    if (metric.edges === "auto") {
      const drawnValues = values.flatMap((row, i) => row.filter((_, j) => shown(i, j)));
      metric = { ...metric, edges: autoEdges(drawnValues) };
    }
    const palette = colours(metric);
    const paths = new Map(); // class -> [path pieces]
    const counts = new Map();
    let drawn = 0;
    for (let i = 0; i < rows; i += 1) {
      for (let j = 0; j < cols; j += 1) {
        if (!shown(i, j)) continue; // the area's cells, and cells outside it that hold data
        const k = classOf(metric, values[i][j]);
        if (!paths.has(k)) paths.set(k, []);
        paths.get(k).push(`M${x0 + j * c} ${y0 + i * c}h${c}v${c}h${-c}Z`);
        counts.set(k, (counts.get(k) ?? 0) + 1);
        drawn += 1;
      }
    }
    layer.dataset.cells = String(drawn);
    for (const [k, pieces] of [...paths].sort((a, b) => a[0] - b[0])) {
      const text = k < 0 ? "no data" : classText(metric, k);
      layer.append(
        s(
          "path",
          { class: `heat heat-${k < 0 ? "none" : k}`, d: pieces.join(""), fill: k < 0 ? NO_DATA : palette[k], "fill-opacity": k < 0 ? 0.35 : OPACITY, "data-cells": pieces.length },
          s("title", { text: `${metric.label}: ${text} (${pieces.length} cells)` }),
        ),
      );
    }
    fill(
      this.legend,
      palette.map((colour, k) => h("li", { "data-class": k }, swatch(colour), ` ${classText(metric, k)}`, h("span", { class: "muted" }, ` · ${counts.get(k) ?? 0}`))),
      h("li", { "data-class": "none" }, swatch(NO_DATA), " no data", h("span", { class: "muted" }, ` · ${counts.get(-1) ?? 0}`)),
    );
  }

  #point(event) {
    const grid = this.grid;
    const ctm = this.layer.getScreenCTM();
    if (!grid || !ctm) return;
    const p = new DOMPoint(event.clientX, event.clientY).matrixTransform(ctm.inverse());
    const j = Math.floor((p.x - grid.origin_m[0]) / grid.cell_m);
    const i = Math.floor((p.y - grid.origin_m[1]) / grid.cell_m);
    if (i < 0 || j < 0 || i >= grid.rows || j >= grid.cols) return;
    const at = (name) => grid.cells[name][i][j];
    const x = grid.origin_m[0] + j * grid.cell_m;
    const y = grid.origin_m[1] + i * grid.cell_m;
    this.readout.textContent = [
      `Cell x ${num(x)}–${num(x + grid.cell_m)} m, y ${num(y)}–${num(y + grid.cell_m)} m:`,
      `expected error ${num(at("expected_error_m"))} m (nearest reference point ${num(at("nearest_rp_m"))} m away),`,
      `readings ${at("readings")} (${at("emitters")} emitters), survey points ${at("points")},`,
      `RSS variance ${num(at("var_db2"))} dB², newest point ${at("age_days") === null ? "—" : `${num(at("age_days"))} days old`}.`,
    ].join(" ");
  }
}
