// A floor drawn to scale in SVG: the plan (GeoJSON in metres of the floor frame, x east,
// y north; see server/positioning/plan/geojson_plan.py), the map-quality layers and the
// live positions. The drawing group flips y, so everything inside it is in floor metres.

import { h, num, s } from "./dom.js";

const WALKABLE = new Set(["walkable", "outline"]);
const BARRIERS = new Set(["wall", "unit", "obstacle"]);
// ways between floors, which routes take (server/positioning/plan/routing_graph.py)
const CONNECTORS = new Set(["stairs", "elevator", "escalator", "ramp"]);
const LAYERS = ["walkable", "heatmap", "zones", "walls", "doors", "beacons", "coverage", "magnetic", "emitters", "routes", "tracks", "live"];
const PICK_SLOP_PX = 5; // a click that moved the pointer more than this is a drag
const NICE_M = [0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];
// the fixes a session's track keeps: its history's (history.js) as well as its live ones
export const MAX_TRACK = 20000;

function rings(geometry) {
  if (!geometry) return [];
  if (geometry.type === "Polygon") return [geometry.coordinates];
  if (geometry.type === "MultiPolygon") return geometry.coordinates;
  return [];
}

function lines(geometry) {
  if (!geometry) return [];
  if (geometry.type === "LineString") return [geometry.coordinates];
  if (geometry.type === "MultiLineString") return geometry.coordinates;
  return [];
}

function points(geometry) {
  if (!geometry) return [];
  if (geometry.type === "Point") return [geometry.coordinates];
  if (geometry.type === "MultiPoint") return geometry.coordinates;
  return [];
}

const pathOf = (coords, close) =>
  coords.map(([x, y], i) => `${i ? "L" : "M"}${x} ${y}`).join("") + (close ? "Z" : "");

const polygonPath = (polygons) => polygons.map((p) => p.map((ring) => pathOf(ring, true)).join("")).join("");

function* coordinates(geometry) {
  for (const polygon of rings(geometry)) for (const ring of polygon) yield* ring;
  for (const line of lines(geometry)) yield* line;
  yield* points(geometry);
  for (const part of geometry?.geometries ?? []) yield* coordinates(part);
}

function label(properties) {
  const p = properties ?? {};
  return [p.kind ?? "no kind", p.name ?? p.id ?? "", p.use ?? ""].filter(Boolean).join(" · ");
}

export class FloorMap {
  constructor() {
    this.svg = s("svg", { id: "plan", class: "plan", role: "img", "aria-label": "floor plan" });
    this.world = s("g", { class: "world", transform: "scale(1 -1)" });
    this.layers = {};
    for (const name of LAYERS) {
      this.layers[name] = s("g", { class: `layer layer-${name}`, "data-layer": name });
      this.world.append(this.layers[name]);
    }
    this.svg.append(this.world);
    this.scaleBar = h("span", { class: "scale-bar" });
    this.scaleText = h("span", { class: "scale-text" });
    const tool = (text, title, action) => h("button", { type: "button", title, "aria-label": title, onclick: action }, text);
    this.element = h(
      "div",
      { class: "map" },
      this.svg,
      h(
        "div",
        { class: "map-tools" },
        tool("+", "zoom in", () => this.zoom(1 / 1.5)),
        tool("−", "zoom out", () => this.zoom(1.5)),
        tool("⤢", "fit the floor", () => this.fit()),
      ),
      h("div", { class: "scale" }, this.scaleBar, this.scaleText, h("span", { class: "axes" }, "x → east, y ↑ north")),
    );
    this.bounds = null; // [x0, y0, x1, y1] of what was drawn, metres
    this.view = null; // viewBox [x, y, width, height], SVG units (y flipped)
    this.sessions = new Map();
    this.hasPlan = false;
    this.picker = null; // what a click on the floor (not a drag) is for: see pick()
    this.#interact();
    new ResizeObserver(() => this.#scale()).observe(this.svg);
  }

  get dot() {
    if (!this.bounds) return 0.4;
    const [x0, y0, x1, y1] = this.bounds;
    return Math.max(0.25, Math.max(x1 - x0, y1 - y0) / 120);
  }

  #extend(xys) {
    for (const [x, y] of xys) {
      if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
      const b = (this.bounds ??= [x, y, x, y]);
      b[0] = Math.min(b[0], x);
      b[1] = Math.min(b[1], y);
      b[2] = Math.max(b[2], x);
      b[3] = Math.max(b[3], y);
    }
  }

  // a floor without a plan is framed by what its maps hold
  #fitIfPlanless(xys) {
    if (this.hasPlan) return;
    this.#extend(xys);
    this.fit();
  }

  /** Fit the view to what is drawn. */
  fit() {
    if (!this.bounds) return;
    const [x0, y0, x1, y1] = this.bounds;
    const pad = Math.max(1, 0.04 * Math.max(x1 - x0, y1 - y0));
    this.#setView([x0 - pad, -y1 - pad, x1 - x0 + 2 * pad, y1 - y0 + 2 * pad]);
  }

  #setView(view) {
    this.view = view;
    this.svg.setAttribute("viewBox", view.join(" "));
    this.#scale();
  }

  zoom(factor, around) {
    if (!this.view) return;
    const [x, y, w, h] = this.view;
    const [cx, cy] = around ?? [x + w / 2, y + h / 2];
    this.#setView([cx - (cx - x) * factor, cy - (cy - y) * factor, w * factor, h * factor]);
  }

  #interact() {
    const toSvg = (event) => {
      const ctm = this.svg.getScreenCTM();
      if (!ctm) return null;
      const p = new DOMPoint(event.clientX, event.clientY).matrixTransform(ctm.inverse());
      return [p.x, p.y];
    };
    this.svg.addEventListener(
      "wheel",
      (event) => {
        if (!this.view) return;
        event.preventDefault();
        this.zoom(event.deltaY > 0 ? 1.2 : 1 / 1.2, toSvg(event) ?? undefined);
      },
      { passive: false },
    );
    let drag = null;
    let moved = 0; // pixels the pointer went since it was pressed: a drag is no pick
    this.svg.addEventListener("pointerdown", (event) => {
      moved = 0;
      if (!this.view || event.button !== 0) return;
      drag = { x: event.clientX, y: event.clientY, view: [...this.view], scale: this.svg.getScreenCTM()?.a ?? 1 };
      this.svg.setPointerCapture(event.pointerId);
    });
    this.svg.addEventListener("pointermove", (event) => {
      if (!drag) return;
      moved = Math.max(moved, Math.hypot(event.clientX - drag.x, event.clientY - drag.y));
      const [x, y, w, hh] = drag.view;
      this.#setView([x - (event.clientX - drag.x) / drag.scale, y - (event.clientY - drag.y) / drag.scale, w, hh]);
    });
    const end = () => {
      drag = null;
    };
    this.svg.addEventListener("pointerup", end);
    this.svg.addEventListener("pointercancel", end);
    this.svg.addEventListener("click", (event) => {
      const ctm = this.world.getScreenCTM();
      if (!this.picker || moved > PICK_SLOP_PX || !ctm) return;
      const p = new DOMPoint(event.clientX, event.clientY).matrixTransform(ctm.inverse());
      this.picker([p.x, p.y]);
    });
  }

  /** While `picker` is set, a click on the floor (not a drag) calls it with the point in
   * floor metres, [x, y]; pick(null) ends that. */
  pick(picker) {
    this.picker = picker;
    this.svg.classList.toggle("picking", Boolean(picker));
  }

  #scale() {
    const pxPerM = this.svg.getScreenCTM()?.a;
    if (!this.view || !pxPerM) return;
    const metres = NICE_M.find((m) => m * pxPerM >= 60) ?? NICE_M.at(-1);
    this.scaleBar.style.width = `${Math.round(metres * pxPerM)}px`;
    this.scaleText.textContent = `${metres} m`;
  }

  /** Draw a plan (GeoJSON FeatureCollection); returns counts by what was drawn. */
  setPlan(plan) {
    const counts = { walkable: 0, walls: 0, doors: 0, beacons: 0, connectors: 0, other: 0 };
    for (const name of ["walkable", "walls", "doors", "beacons"]) this.layers[name].replaceChildren();
    const thin = [];
    const named = []; // [layer, x, y, name, above]: stairs, lifts and places, labelled once the scale is known
    for (const feature of plan?.features ?? []) {
      const kind = feature?.properties?.kind;
      const geometry = feature?.geometry;
      this.#extend(coordinates(geometry));
      const title = s("title", { text: label(feature?.properties) });
      const polygons = rings(geometry);
      const polylines = lines(geometry);
      if (WALKABLE.has(kind) && polygons.length) {
        this.layers.walkable.append(s("path", { class: "walkable", d: polygonPath(polygons) }, title));
        counts.walkable += 1;
      } else if (BARRIERS.has(kind) && polygons.length) {
        this.layers.walls.append(s("path", { class: "wall solid", d: polygonPath(polygons) }, title));
        counts.walls += 1;
      } else if (BARRIERS.has(kind) && polylines.length) {
        thin.push(...polylines);
        counts.walls += 1;
      } else if (CONNECTORS.has(kind) && polygons.length) {
        this.layers.doors.append(s("path", { class: `connector connector-${kind}`, d: polygonPath(polygons) }, title));
        const ring = polygons[0][0];
        const xs = ring.map(([x]) => x);
        const ys = ring.map(([, y]) => y);
        named.push([this.layers.doors, (Math.min(...xs) + Math.max(...xs)) / 2, Math.max(...ys), feature.properties?.name ?? kind, true]);
        counts.connectors += 1;
      } else if (kind === "door") {
        const d = polygons.length ? polygonPath(polygons) : polylines.map((l) => pathOf(l, false)).join("");
        this.layers.doors.append(s("path", { class: polygons.length ? "door door-area" : "door", d }, title));
        counts.doors += 1;
      } else if (points(geometry).length) {
        for (const [x, y] of points(geometry)) {
          this.layers.beacons.append(
            s("circle", { class: `beacon kind-${String(kind ?? "none").replace(/[^a-z0-9_-]/gi, "")}`, cx: x, cy: y, r: 1 }, s("title", { text: label(feature?.properties) })),
          );
          if (kind === "poi" && feature.properties?.name) named.push([this.layers.beacons, x, y, feature.properties.name, false]);
        }
        counts.beacons += 1;
      } else if (polygons.length || polylines.length) {
        // what the positioning ignores (no kind, or one it does not know): shown dashed
        const d = polygonPath(polygons) + polylines.map((l) => pathOf(l, false)).join("");
        this.layers.walls.append(s("path", { class: "other", d }, title));
        counts.other += 1;
      }
    }
    this.hasPlan = Boolean(this.bounds);
    if (this.hasPlan) {
      // the drawing takes the floor's shape (within the height the page allows)
      const [x0, y0, x1, y1] = this.bounds;
      this.svg.style.aspectRatio = `${Math.max(1, x1 - x0)} / ${Math.max(1, y1 - y0)}`;
    }
    if (thin.length) this.layers.walls.append(s("path", { class: "wall", d: thin.map((l) => pathOf(l, false)).join("") }));
    for (const beacon of this.layers.beacons.querySelectorAll("circle.beacon")) beacon.setAttribute("r", this.dot);
    for (const [layer, x, y, name, above] of named) {
      // upright in the y-flipped group: above a stair's or a lift's shape, beside a place
      const at = above ? { x, y: -y - 0.5 * this.dot, "text-anchor": "middle" } : { x: x + 1.5 * this.dot, y: -y, "dominant-baseline": "central" };
      layer.append(s("text", { class: "place-label", "font-size": 1.8 * this.dot, transform: "scale(1 -1)", ...at }, name));
    }
    this.fit();
    return counts;
  }

  /** The radio-map coverage: the planned reference points (GET .../maps/placement) as
   * grid cells, surveyed or still missing. */
  setCoverage(placement) {
    const layer = this.layers.coverage;
    layer.replaceChildren();
    const grid = placement?.properties?.grid_m ?? 1;
    const half = grid / 2;
    const cell = ([x, y]) => `M${x - half} ${y - half}h${grid}v${grid}h${-grid}Z`;
    const done = [];
    const missing = [];
    for (const feature of placement?.features ?? []) {
      const xy = feature.geometry?.coordinates;
      if (!xy) continue;
      (feature.properties?.surveyed ? done : missing).push(cell(xy));
    }
    this.#fitIfPlanless(placement?.features?.map((f) => f.geometry?.coordinates ?? []) ?? []);
    if (done.length) layer.append(s("path", { class: "coverage covered", d: done.join("") }, s("title", { text: `${done.length} planned points surveyed` })));
    if (missing.length) layer.append(s("path", { class: "coverage missing", d: missing.join("") }, s("title", { text: `${missing.length} planned points not surveyed yet` })));
    return { surveyed: done.length, missing: missing.length };
  }

  /** Located emitters (GET .../maps/quality: emitters.positions), with a 2σ ellipse. */
  setEmitters(positions) {
    const layer = this.layers.emitters;
    layer.replaceChildren();
    this.#fitIfPlanless((positions ?? []).map((e) => [e.x_m, e.y_m]));
    for (const e of positions ?? []) {
      const title = s("title", {
        text: `${e.kind} ${e.key}\nP0 ${num(e.p0_dbm)} dBm, exponent ${num(e.exponent, 2)}, ${e.n} readings, residual ${num(e.residual_rms_db)} dB`,
      });
      const g = s("g", { class: `emitter emitter-${e.kind}`, "data-key": e.key }, title);
      // a 2σ ellipse, left out when it would cover much of the floor (a poor fit)
      if (e.xy_std_m && 2 * Math.max(...e.xy_std_m) < 20 * this.dot)
        g.append(s("ellipse", { class: "spread", cx: e.x_m, cy: e.y_m, rx: 2 * e.xy_std_m[0], ry: 2 * e.xy_std_m[1] }));
      const half = 0.7 * this.dot;
      g.append(s("rect", { class: "mark", x: e.x_m - half, y: e.y_m - half, width: 2 * half, height: 2 * half }));
      layer.append(g);
    }
  }

  /** The extent of the floor's current magnetic grid. */
  setMagneticGrid(map) {
    const layer = this.layers.magnetic;
    layer.replaceChildren();
    if (!map) return;
    const width = map.n_cols * map.resolution_m;
    const height = map.n_rows * map.resolution_m;
    layer.append(
      s(
        "rect",
        { class: "magnetic-grid", x: map.origin_x_m, y: map.origin_y_m, width, height },
        s("title", { text: `magnetic map v${map.version}: ${map.known_cells} known cells of ${map.n_rows * map.n_cols} (${map.resolution_m} m)` }),
      ),
    );
  }

  show(layer, visible) {
    this.layers[layer]?.classList.toggle("hidden", !visible);
  }

  #session(id, colour) {
    let entry = this.sessions.get(id);
    if (!entry) {
      const accuracy = s("circle", { class: "accuracy", r: 0 });
      const dot = s("circle", { class: "fix-dot", r: this.dot });
      const heading = s("line", { class: "heading" });
      const group = s("g", { class: "session hidden", "data-session": id }, accuracy, heading, dot);
      const track = s("polyline", { class: "track", "data-session": id });
      for (const el of [accuracy, dot, heading, track]) el.setAttribute("stroke", colour);
      dot.setAttribute("fill", colour);
      accuracy.setAttribute("fill", colour);
      entry = { group, accuracy, dot, heading, track, fixes: [] };
      this.layers.live.append(group);
      this.layers.tracks.append(track);
      this.sessions.set(id, entry);
    }
    return entry;
  }

  /** Move a session's dot to `fix` (a FixOut), or hide it when `fix` is on another floor
   * (null); its accuracy circle is the 68 % radius, else the uncertainty. */
  place(id, colour, fix) {
    const entry = this.#session(id, colour);
    entry.group.classList.toggle("hidden", !fix);
    if (!fix) return;
    const r = fix.accuracy_68_m ?? fix.uncertainty_m ?? 0;
    for (const el of [entry.dot, entry.accuracy]) {
      el.setAttribute("cx", fix.x_m);
      el.setAttribute("cy", fix.y_m);
    }
    entry.dot.setAttribute("r", this.dot);
    entry.accuracy.setAttribute("r", Math.max(0, r));
    entry.group.dataset.t = fix.t;
    const heading = fix.heading_rad;
    entry.heading.classList.toggle("hidden", heading === null || heading === undefined);
    if (heading !== null && heading !== undefined) {
      // heading: clockwise from the floor frame's y axis
      const length = 3 * this.dot;
      entry.heading.setAttribute("x1", fix.x_m);
      entry.heading.setAttribute("y1", fix.y_m);
      entry.heading.setAttribute("x2", fix.x_m + length * Math.sin(heading));
      entry.heading.setAttribute("y2", fix.y_m + length * Math.cos(heading));
    }
  }

  /** Add fixes of this floor to a session's track (kept in time order, one per time, the
   * last MAX_TRACK); with `replace`, they are its whole track. */
  addToTrack(id, colour, fixes, { replace = false } = {}) {
    const entry = this.#session(id, colour);
    const last = entry.fixes.at(-1);
    if (!replace && fixes.length === 1 && (!last || fixes[0].t > last.t)) entry.fixes.push(fixes[0]); // a live fix
    else {
      const byTime = new Map(replace ? [] : entry.fixes.map((f) => [f.t, f]));
      for (const f of fixes) byTime.set(f.t, f);
      entry.fixes = [...byTime.values()].sort((a, b) => a.t - b.t);
    }
    if (entry.fixes.length > MAX_TRACK) entry.fixes.splice(0, entry.fixes.length - MAX_TRACK);
    entry.track.setAttribute("points", entry.fixes.map((f) => `${f.x_m},${f.y_m}`).join(" "));
  }

  forget(id) {
    const entry = this.sessions.get(id);
    if (!entry) return;
    entry.group.remove();
    entry.track.remove();
    this.sessions.delete(id);
  }
}
