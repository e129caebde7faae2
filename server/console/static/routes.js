// Routes on the floor page: a route picked on the floor (click its origin, then its
// destination: on this floor, or on another one opened with the level links, the picking
// goes on there), asked of POST /v1/sites/{id}/routes, drawn on each floor shown (that
// floor's legs, their steps numbered, a label where the route changes floor) and listed
// step by step beside the map. The picking and the route outlive the page: the next floor
// of the site shown draws its own legs.

import { ApiError, send } from "./api.js";
import { duration, fill, h, num, s } from "./dom.js";

// what the tool holds from one floor page to the next (of one site)
const held = {
  siteId: null,
  accessible: false,
  picking: null, // "origin" | "destination" | null
  origin: null, // {floor_id, level, x_m, y_m}
  destination: null,
  route: null, // the answer of POST /v1/sites/{id}/routes
  message: "", // what the last request said (an error, or "Finding the way…")
  failed: false,
  asked: 0, // the number of the last request: an older answer is dropped
  view: null, // the RouteTool of the page shown
};

// no route, nothing picked; a request still out is dropped when it answers
function reset(extra = {}) {
  Object.assign(held, { picking: null, origin: null, destination: null, route: null, message: "", failed: false }, extra);
  held.asked += 1;
}

const CHANGE_ARROW = (from, to) => (to > from ? "↑" : "↓");
const round = (value) => Math.round(value * 100) / 100;
const pointsOf = (coords) => coords.map(([x, y]) => `${x},${y}`).join(" ");
const metres = (m) => `${num(m, m < 10 ? 1 : 0)} m`;

// text drawn upright in the floor map's y-flipped group
function label(x, y, size, text, attrs = {}) {
  return s("text", { x, y: -y, "font-size": size, transform: "scale(1 -1)", ...attrs }, text);
}

/** Draw the legs of `route` that lie on floor `floorId` into `group` (floor metres): the
 * line, its ends, a label where it leaves or joins the floor and, with `numbered`, every
 * step's number (the list beside the map uses the same). `size`: a text height in metres;
 * `colour`: the line's colour (the stylesheet's when none). */
export function drawRoute(group, route, floorId, size, { numbered = false, colour = null } = {}) {
  group.replaceChildren();
  const legs = (route?.legs ?? []).filter((leg) => leg.floor_id === floorId);
  for (const leg of legs) {
    const points = pointsOf(leg.geometry.coordinates);
    const line = s("polyline", { class: "route-line", points, "data-level": leg.level });
    if (colour) line.style.stroke = colour;
    group.append(s("polyline", { class: "route-casing", points }), line);
  }
  const steps = route?.steps ?? [];
  const r = 0.6 * size;
  steps.forEach((step, i) => {
    if (step.floor_id !== floorId) return;
    const last = i === steps.length - 1;
    const changes = step.to_level !== null && step.to_level !== undefined;
    const before = steps[i - 1];
    const arrives = before && before.floor_id !== floorId; // came up or down to this floor
    if (!numbered && !last && !changes && !arrives) return;
    const kind = i === 0 ? "start" : last ? "arrive" : changes ? "change" : "turn";
    const mark = s("g", { class: `route-step step-${kind}`, "data-step": i, "data-kind": step.kind }, s("title", { text: `${i + 1}. ${step.text}` }));
    mark.append(s("circle", { cx: step.x_m, cy: step.y_m, r }));
    if (numbered) mark.append(label(step.x_m, step.y_m, 0.75 * size, String(i + 1), { class: "route-number", "text-anchor": "middle", "dominant-baseline": "central" }));
    if (changes) mark.append(label(step.x_m + 1.5 * r, step.y_m, size, `${CHANGE_ARROW(step.level, step.to_level)} to level ${step.to_level}`, { class: "route-label", "dominant-baseline": "central" }));
    else if (arrives) mark.append(label(step.x_m + 1.5 * r, step.y_m, size, `${CHANGE_ARROW(before.level, step.level)} from level ${before.level}`, { class: "route-label", "dominant-baseline": "central" }));
    group.append(mark);
  });
}

/** The route tool of a floor page: its panel (`element`) and its drawing on `map`. */
export class RouteTool {
  constructor(map, floor) {
    this.map = map;
    this.floor = floor; // {id, level}
    this.siteId = null;
    this.forSession = null; // {prompt, done}: a point picked for another use (navigation)
    this.group = s("g", { class: "route", "data-route": "planned" });
    this.picks = s("g", { class: "route-picks" });
    map.layers.routes.append(this.group, this.picks);
    this.accessible = h("input", {
      type: "checkbox",
      name: "accessible",
      checked: held.accessible,
      onchange: (event) => {
        held.accessible = event.target.checked;
        if (held.origin && held.destination) this.#ask();
      },
    });
    this.pickButton = h("button", { type: "button", class: "route-pick", disabled: true, onclick: () => this.#toggle() });
    this.clearButton = h("button", { type: "button", class: "route-clear", onclick: () => this.clear() }, "Clear");
    this.status = h("p", { class: "route-status", role: "status" });
    this.summary = h("div", { class: "route-summary" });
    this.steps = h("ol", { class: "route-steps" });
    this.element = h(
      "div",
      { class: "route-tool" },
      h("div", { class: "route-actions" }, this.pickButton, this.clearButton),
      h("label", { class: "check" }, this.accessible, " Step-free (lifts and ramps only)"),
      this.status,
      this.summary,
      this.steps,
    );
    held.view = this;
    this.render();
  }

  /** The floor's site is known (and whether the server plans routes): picking may start. */
  siteKnown(siteId, offered) {
    if (held.siteId !== siteId) reset({ siteId });
    this.siteId = siteId;
    this.offered = offered;
    this.render();
  }

  /** Pick one point on this floor for `done({floor_id, level, x_m, y_m})` (a session's
   * destination, say), `prompt` saying what for; a route being picked gives way. */
  pickFor(prompt, done) {
    held.picking = null;
    this.forSession = { prompt, done };
    this.render();
    this.map.element.scrollIntoView({ block: "nearest" }); // the button may be far below the map
  }

  clear() {
    reset();
    this.forSession = null;
    this.render();
  }

  // the button: pick a route, or cancel the picking going on
  #toggle() {
    if (this.forSession) this.forSession = null;
    else reset(held.picking ? {} : { picking: "origin" });
    this.render();
  }

  #picked([x, y]) {
    const point = { floor_id: this.floor.id, level: this.floor.level, x_m: round(x), y_m: round(y) };
    if (this.forSession) {
      const { done } = this.forSession;
      this.forSession = null;
      this.render();
      done(point);
    } else if (held.picking === "origin") {
      Object.assign(held, { picking: "destination", origin: point });
      this.render();
    } else if (held.picking === "destination") {
      Object.assign(held, { picking: null, destination: point });
      this.#ask();
    }
  }

  async #ask() {
    const asked = (held.asked += 1);
    const end = ({ floor_id, x_m, y_m }) => ({ floor_id, x_m, y_m });
    const body = { origin: end(held.origin), destination: end(held.destination), accessible: held.accessible };
    Object.assign(held, { route: null, message: "Finding the way…", failed: false });
    this.render();
    let route = null;
    let message = "";
    try {
      route = await send("POST", `/v1/sites/${held.siteId}/routes`, body);
    } catch (error) {
      message = error instanceof ApiError && error.status === 404 ? `No route: ${error.message}` : `The route failed: ${error.message}`;
    }
    if (asked !== held.asked) return; // cleared, or asked again since
    Object.assign(held, { route, message, failed: !route });
    held.view?.render();
  }

  /** Draw and list what the tool holds, for the floor shown. */
  render() {
    const picking = held.picking || this.forSession;
    this.map.pick(picking ? (xy) => this.#picked(xy) : null);
    this.pickButton.disabled = !picking && (!this.siteId || !this.offered);
    this.pickButton.textContent = picking ? "Cancel" : held.route ? "New route" : "Pick origin and destination";
    this.clearButton.hidden = !(held.origin || held.route || held.message);
    this.element.dataset.state = this.forSession ? "picking-for" : (held.picking ?? (held.route ? "route" : held.failed ? "failed" : "idle"));

    const size = 2.2 * this.map.dot;
    this.picks.replaceChildren();
    if (held.origin?.floor_id === this.floor.id && !held.route) {
      const { x_m: x, y_m: y } = held.origin;
      this.picks.append(
        s("g", { class: "route-step step-start route-origin" }, s("circle", { cx: x, cy: y, r: 0.6 * size }), label(x, y, 0.75 * size, "A", { class: "route-number", "text-anchor": "middle", "dominant-baseline": "central" })),
      );
    }
    drawRoute(this.group, held.route, this.floor.id, size, { numbered: true });

    this.status.classList.toggle("error", held.failed);
    const where = (p) => `level ${p.level} (${num(p.x_m)}, ${num(p.y_m)})`;
    if (this.forSession) this.status.textContent = this.forSession.prompt;
    else if (held.picking === "origin") this.status.textContent = "Click the origin on the floor.";
    else if (held.picking === "destination")
      this.status.textContent = `Origin: ${where(held.origin)}. Now click the destination: on this floor, or open another level (above) and click it there.`;
    else if (held.message) this.status.textContent = held.message;
    else if (this.siteId && !this.offered) this.status.textContent = "This server plans no routes (no POST /v1/sites/{id}/routes).";
    else if (!held.route) this.status.textContent = "Pick two points on the floor to see the way between them.";
    else this.status.textContent = `From ${where(held.route.origin)} to ${where(held.route.destination)}.`;
    this.#list(held.route);
  }

  #list(route) {
    if (!route) {
      this.summary.replaceChildren();
      this.steps.replaceChildren();
      return;
    }
    const changes = route.floor_changes.map((c) => `${c.name ?? c.kind} to level ${c.to_level}`);
    const legs = route.legs.map((leg) =>
      leg.floor_id === this.floor.id
        ? h("span", { class: "route-leg current" }, `Level ${leg.level}: ${metres(leg.length_m)} (shown)`)
        : h("a", { class: "route-leg", href: `#/floors/${leg.floor_id}` }, `Level ${leg.level}: ${metres(leg.length_m)}`),
    );
    fill(
      this.summary,
      h("p", { class: "route-total" }, h("strong", {}, metres(route.length_m)), ` · about ${duration(route.duration_s)}`, changes.length ? ` · ${changes.join(", ")}` : "", route.accessible ? " · step-free" : ""),
      h("p", { class: "route-legs" }, legs.flatMap((leg, i) => (i ? [" · ", leg] : [leg]))),
    );
    const items = [];
    route.steps.forEach((step, i) => {
      if (i === 0 || step.floor_id !== route.steps[i - 1].floor_id) {
        const here = step.floor_id === this.floor.id;
        items.push(h("li", { class: "route-floor" }, here ? `Level ${step.level}` : h("a", { href: `#/floors/${step.floor_id}` }, `Level ${step.level} →`)));
      }
      const item = h(
        "li",
        { class: step.floor_id === this.floor.id ? "route-item" : "route-item elsewhere", "data-step": i, "data-kind": step.kind },
        h("span", { class: "route-n" }, String(i + 1)),
        h("span", { class: "route-text" }, step.text),
        h("span", { class: "route-distance", title: "walked from the step before" }, step.distance_m >= 0.05 ? metres(step.distance_m) : ""),
      );
      const hot = (on) => this.group.querySelector(`[data-step="${i}"]`)?.classList.toggle("hot", on);
      item.addEventListener("mouseenter", () => hot(true));
      item.addEventListener("mouseleave", () => hot(false));
      items.push(item);
    });
    fill(this.steps, items);
  }
}
