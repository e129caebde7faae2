// A followed session's history on the floor page: every fix it made (GET
// /v1/sessions/{id}/history, page by page), drawn as its track, and a time slider that
// moves the session's dot back through them. While the slider is not at its newest fix,
// live fixes leave the dot where the slider put it (`holds`).

import { capabilities, get, request } from "./api.js";
import { h, num, shortId } from "./dom.js";
import { MAX_TRACK } from "./plan.js";

const PAGE = 1000;
const MAX_FIXES = MAX_TRACK; // the newest are kept past this, as the track keeps them

/** Every fix of the session's history (at most MAX_FIXES, the newest), oldest first. */
export async function loadHistory(sessionId, credential, signal) {
  const route = (await capabilities()).sessionHistory;
  if (!route) throw new Error("this server keeps no history of sessions");
  const fixes = [];
  let after = 0;
  for (;;) {
    const { path, query } = request(route, { session_id: sessionId }, { after_seq: after, limit: PAGE });
    const body = await get(path, query, { signal, credential });
    fixes.push(...body.items);
    if (fixes.length > MAX_FIXES) fixes.splice(0, fixes.length - MAX_FIXES);
    if (!body.more || body.last_seq === null) return fixes;
    after = body.last_seq;
  }
}

export class HistoryPanel {
  /** `map`: the FloorMap; `onFloor(fix)`: whether a fix is on the floor drawn. */
  constructor(map, onFloor, signal) {
    this.map = map;
    this.onFloor = onFloor;
    this.element = h("div", { class: "history", hidden: true });
    this.shown = null; // {id, colour, fixes, index}
    this.loading = null; // the AbortController of the history being loaded
    signal.addEventListener("abort", () => this.loading?.abort());
  }

  /** Whether live fixes must leave this session's dot alone (the slider is back in time). */
  holds(id) {
    return this.shown?.id === id && this.shown.index < this.shown.fixes.length - 1;
  }

  /** Load the session's history and show its slider (`credential`: its token, else the key). */
  async open(id, colour, credential) {
    this.close(); // and the loading of another's (or the same) history stops
    const loading = new AbortController();
    this.loading = loading;
    this.element.hidden = false;
    this.element.replaceChildren(h("p", { class: "muted" }, `loading the history of ${shortId(id)}…`));
    let fixes;
    try {
      fixes = await loadHistory(id, credential, loading.signal);
    } catch (error) {
      if (loading.signal.aborted) return;
      this.element.replaceChildren(h("p", { class: "error" }, `history: ${error.message}`), this.#closeButton());
      return;
    } finally {
      if (this.loading === loading) this.loading = null;
    }
    if (loading.signal.aborted) return;
    fixes.sort((a, b) => a.t - b.t);
    if (!fixes.length) {
      this.element.replaceChildren(h("p", { class: "muted" }, `${shortId(id)} has no fixes kept yet.`), this.#closeButton());
      return;
    }
    // the track already holds the fixes it loaded and those that came live: one per time
    this.map.addToTrack(id, colour, fixes.filter(this.onFloor));
    this.shown = { id, colour, fixes, index: fixes.length - 1 };
    const slider = h("input", {
      type: "range",
      name: "history",
      min: 0,
      max: fixes.length - 1,
      step: 1,
      value: fixes.length - 1,
      "aria-label": "time",
      oninput: (event) => this.show(Number(event.target.value)),
    });
    this.label = h("span", { class: "history-when" });
    this.element.replaceChildren(
      h("div", { class: "history-head" }, h("strong", {}, `History of ${shortId(id)}`), " ", h("span", { class: "muted" }, `${fixes.length} fixes`), this.#closeButton()),
      slider,
      this.label,
    );
    this.element.dataset.session = id;
    this.show(fixes.length - 1);
  }

  /** Put the session's dot at its fix number `index` (the newest: back to live). */
  show(index) {
    const shown = this.shown;
    if (!shown) return;
    shown.index = Math.max(0, Math.min(index, shown.fixes.length - 1));
    const fix = shown.fixes[shown.index];
    const here = this.onFloor(fix);
    this.map.place(shown.id, shown.colour, here ? fix : null);
    const when = new Date(fix.t).toLocaleTimeString();
    const where = here ? `(${num(fix.x_m)}, ${num(fix.y_m)}) m ± ${num(fix.accuracy_68_m ?? fix.uncertainty_m)} m` : `on level ${fix.floor ?? "?"}`;
    const live = shown.index === shown.fixes.length - 1 ? " · newest (live fixes move the dot)" : "";
    this.label.textContent = `${when}: ${where}${live}`;
    this.element.dataset.t = fix.t;
  }

  forget(id) {
    if (this.shown?.id === id || this.element.dataset.session === id) this.close();
  }

  close() {
    this.loading?.abort();
    this.loading = null;
    this.shown = null;
    this.element.hidden = true;
    delete this.element.dataset.session;
    this.element.replaceChildren();
  }

  #closeButton() {
    return h("button", { type: "button", class: "history-close", onclick: () => this.close() }, "Close");
  }
}
