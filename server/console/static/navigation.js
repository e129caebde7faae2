// The navigation of followed sessions on the floor page. While a session's fixes carry
// `navigation`, its route (GET /v1/sessions/{id}/navigation, fetched again whenever the
// route_version changes) is drawn in the session's colour with the fix snapped to it, and
// a line under the session's row tells the instruction, what is left, and whether the
// walker is on the route; its events (re-routed, changed floor, arrived) show for a few
// seconds. "Navigate…" guides a session to a point picked on the floor: a PUT that takes
// the session's token (when it was followed with it) or an admin key of its site.

import { ApiError, get, send } from "./api.js";
import { duration, fill, h, num, s, shortId } from "./dom.js";
import { drawRoute } from "./routes.js";

const EVENT_SHOWN_MS = 8000;
const REFUSAL_SHOWN_MS = 20000;
const MAY_NOT_GUIDE = "Guiding a session takes an admin key of its site, or the session's own token (follow it with its token)";

function eventText(event) {
  if (event.type === "rerouted") return `Re-routed, ${num(event.off_route_m)} m off the route: ${num(event.length_m, 0)} m to go`;
  if (event.type === "floor_change") return `Changed floor: level ${event.from_level} → ${event.to_level}${event.kind ? ` (${event.kind})` : ""}`;
  if (event.type === "arrived") return `Arrived${event.destination ? ` at ${event.destination}` : ""}${event.duration_s ? ` after ${duration(event.duration_s)}` : ""}`;
  return event.type;
}

export class NavigationView {
  /** `map`: the FloorMap; `floor`: {id, level}; `tool`: the RouteTool (it picks points). */
  constructor(map, floor, tool, signal) {
    this.map = map;
    this.floor = floor;
    this.tool = tool;
    this.signal = signal;
    this.offered = false; // the server guides sessions (set once its routes are known)
    this.sessions = new Map(); // session id -> what is shown of its navigation
  }

  #state(entry) {
    let state = this.sessions.get(entry.id);
    if (!state) {
      const line = h("div", { class: "nav-line", hidden: true, "data-session": entry.id });
      const button = h("button", { type: "button", class: "nav-action", hidden: !this.offered }, "Navigate…");
      const group = s("g", { class: "route nav-route", "data-session": entry.id });
      this.map.layers.routes.append(group);
      state = { entry, line, button, group, route: null, version: null, progress: null, events: [], error: "", ticket: 0, timer: null };
      button.addEventListener("click", () => (state.progress ? this.#stop(state) : this.#choose(state)));
      this.sessions.set(entry.id, state);
    }
    return state;
  }

  /** The line under a session's row (its navigation), and its row's button. */
  line(entry) {
    return this.#state(entry).line;
  }

  button(entry) {
    return this.#state(entry).button;
  }

  /** A fix of a followed session: where it stands on its route, or no navigation. */
  update(entry, fix) {
    const state = this.#state(entry);
    const progress = fix.navigation ?? null;
    const now = Date.now();
    for (const event of progress?.events ?? []) state.events.push({ text: eventText(event), type: event.type, until: now + EVENT_SHOWN_MS });
    if (progress?.events?.length) state.line.dataset.lastEvent = progress.events.at(-1).type;
    if (progress && progress.route_version !== state.version) this.#load(state, progress.route_version);
    if (!progress && state.progress) {
      state.route = null; // navigation ended: arrived, or stopped
      state.version = null;
      state.ticket += 1;
    }
    state.progress = progress;
    state.fix = fix;
    this.#show(state);
  }

  forget(id) {
    const state = this.sessions.get(id);
    if (!state) return;
    clearTimeout(state.timer);
    state.group.remove();
    this.sessions.delete(id);
  }

  async #load(state, version) {
    state.version = version;
    const ticket = (state.ticket += 1);
    try {
      const body = await get(`/v1/sessions/${state.entry.id}/navigation`, {}, { signal: this.signal, credential: state.entry.token || undefined });
      if (ticket !== state.ticket) return;
      state.route = body.route;
      state.error = "";
    } catch (error) {
      if (ticket !== state.ticket || error.name === "AbortError") return;
      state.error = error instanceof ApiError && error.status === 404 ? "" : `navigation: ${error.message}`;
    }
    this.#show(state);
  }

  // "Navigate…": a destination picked on the floor, then the PUT
  #choose(state) {
    const id = state.entry.id;
    this.tool.pickFor(`Click where ${shortId(id)} should be guided to, on this floor.`, async (point) => {
      const { floor_id, x_m, y_m } = point;
      try {
        const body = await send("PUT", `/v1/sessions/${id}/navigation`, { destination: { floor_id, x_m, y_m } }, { credential: state.entry.token || undefined });
        state.ticket += 1; // what a fetch in flight brings is older
        Object.assign(state, { route: body.route, progress: body.navigation, version: body.navigation?.route_version ?? 0, error: "" });
      } catch (error) {
        this.#refused(state, error);
      }
      this.#show(state);
    });
  }

  async #stop(state) {
    try {
      await send("DELETE", `/v1/sessions/${state.entry.id}/navigation`, undefined, { credential: state.entry.token || undefined });
      state.ticket += 1;
      Object.assign(state, { route: null, progress: null, version: null, error: "" });
    } catch (error) {
      this.#refused(state, error);
    }
    this.#show(state);
  }

  // what the server said to a PUT or a DELETE, shown for a while
  #refused(state, error) {
    const text = error instanceof ApiError && error.status === 403 ? `${MAY_NOT_GUIDE}: ${error.message}` : error.message;
    state.events.push({ text, type: "refused", until: Date.now() + REFUSAL_SHOWN_MS });
  }

  #show(state) {
    const { progress, route, line, button, group } = state;
    const now = Date.now();
    state.events = state.events.filter((e) => e.until > now);
    clearTimeout(state.timer);
    if (state.events.length) state.timer = setTimeout(() => this.#show(state), Math.min(...state.events.map((e) => e.until)) - now + 50);

    button.hidden = !this.offered;
    button.textContent = progress ? "End navigation" : "Navigate…";

    // the drawing: this floor's legs of the route, and the fix snapped to it
    const size = 2.2 * this.map.dot;
    const colour = state.entry.colour;
    drawRoute(group, progress ? route : null, this.floor.id, size, { colour });
    const snapped = progress?.snapped;
    if (snapped && snapped.floor_id === this.floor.id) {
      const fix = state.fix;
      if (fix && fix.floor_id === this.floor.id && !progress.on_route)
        group.append(s("line", { class: "nav-offset", x1: fix.x_m, y1: fix.y_m, x2: snapped.x_m, y2: snapped.y_m }));
      const mark = s("circle", { class: "nav-snapped", cx: snapped.x_m, cy: snapped.y_m, r: 0.45 * size }, s("title", { text: "the fix snapped to the route" }));
      mark.style.stroke = colour;
      group.append(mark);
    }
    group.dataset.routeVersion = state.version ?? "";

    // the line under the row
    const parts = [];
    if (progress) {
      const to = progress.destination;
      const where = to.name ?? `level ${to.level} (${num(to.x_m)}, ${num(to.y_m)})`;
      parts.push(
        h("strong", { class: "nav-instruction" }, progress.instruction),
        h("span", { class: "nav-remaining" }, `${num(progress.remaining_m, 0)} m · ${duration(progress.remaining_s)} left to ${where}`),
        progress.on_route
          ? h("span", { class: "nav-on" }, "on route")
          : h("span", { class: "nav-off" }, `off route${progress.off_route_m === null ? "" : ` by ${num(progress.off_route_m)} m`}`),
      );
      if (!route) parts.push(h("span", { class: "muted" }, "loading the route…"));
      else if (progress.snapped?.floor_id !== this.floor.id) parts.push(h("span", { class: "muted" }, `on level ${progress.snapped?.level ?? "?"}`));
    }
    for (const event of state.events)
      parts.push(event.type === "refused" ? h("span", { class: "error nav-refused" }, event.text) : h("span", { class: `nav-event nav-event-${event.type}` }, event.text));
    if (state.error) parts.push(h("span", { class: "error" }, state.error));
    fill(line, parts);
    line.hidden = !parts.length;
    line.dataset.status = progress?.status ?? "";
    line.dataset.routeVersion = state.version ?? "";
  }

  /** Whether the server guides sessions (its OpenAPI document has the route). */
  offer(offered) {
    this.offered = offered;
    for (const state of this.sessions.values()) this.#show(state);
  }
}
