// A floor: its plan to scale, the map-quality layers, the live positions of the
// sessions followed (over the live socket) with their accuracy circles, tracks and
// navigation, and routes picked on it.

import { ApiError, capabilities, follow, get, key, request } from "./api.js";
import { ago, fill, h, num, percent, shortId } from "./dom.js";
import { FloorMap } from "./plan.js";
import { HistoryPanel } from "./history.js";
import { Heatmap } from "./heatmap.js";
import { ZoneLayer } from "./zones.js";
import { NavigationView } from "./navigation.js";
import { RouteTool } from "./routes.js";

const COLOURS = ["#d6336c", "#1c7ed6", "#f08c00", "#2f9e44", "#7048e8", "#0c8599", "#e8590c", "#5c940d"];
const LIST_REFRESH_MS = 5000;
const MAX_AUTO_FOLLOW = 25;
const LAYER_NAMES = [
  ["walkable", "Walkable area", true],
  ["walls", "Walls", true],
  ["doors", "Doors", true],
  ["beacons", "Beacons (plan points)", true],
  ["heatmap", "Coverage heatmap", true],
  ["zones", "Zones", true],
  ["coverage", "Radio map coverage", false], // off under the heatmap: their colours mix
  ["magnetic", "Magnetic grid", false],
  ["emitters", "Located emitters", true],
  ["routes", "Routes", true],
  ["tracks", "Tracks", true],
  ["live", "Live positions", true],
];

function section(title, ...children) {
  return h("section", { class: "panel" }, h("h2", {}, title), ...children);
}

function dl(rows) {
  return h("dl", { class: "facts" }, rows.flatMap(([term, value]) => [h("dt", {}, term), h("dd", {}, value)]));
}

const p50 = (p, digits = 1) => (p ? num(p.p50, digits) : "—");

function share(value) {
  return h("span", { class: "share" }, h("meter", { min: 0, max: 1, value: value ?? 0 }), " ", percent(value));
}

function qualityFacts(q, placement) {
  const rows = [
    ["Radio map", q.radio_map ? `v${q.radio_map.version}` : "none"],
    ["Magnetic map", q.magnetic_map ? `v${q.magnetic_map.version}` : "none"],
    ["Radio coverage", share(q.coverage.radio)],
    ["Magnetic coverage", share(q.coverage.magnetic)],
    ["Over", q.coverage.walkable_area_known ? "the walkable area" : "the maps' own extent (no plan)"],
    ["Reference points", q.radio_cells.n_reference_points],
    ["Readings per point (p50)", p50(q.radio_cells.readings_per_rp, 0)],
    ["Emitters per point (p50)", p50(q.radio_cells.emitters_per_rp, 0)],
    ["RSS variance (p50)", q.radio_cells.var_db2 ? `${p50(q.radio_cells.var_db2)} dB²` : "—"],
    ["Magnetic cells known", q.magnetic_cells.known_cells],
    ["Samples per cell (p50)", p50(q.magnetic_cells.samples_per_cell, 0)],
    ["Newest survey point", q.freshness.newest ? ago(q.freshness.newest) : "—"],
    ["Cell age (p50)", q.freshness.cell_age_days ? `${p50(q.freshness.cell_age_days)} days` : "—"],
    ["Survey points", `${q.freshness.n_points} (${q.freshness.n_surveyed_points} surveyed, ${q.freshness.n_uploads} uploads)`],
    ["Emitters", `${q.emitters.seen} heard, ${q.emitters.positions.length} located, ${q.emitters.fixed} fixed, ${q.emitters.retired} retired`],
  ];
  if (placement) {
    const sp = placement.properties;
    rows.push(
      ["Planned points", `${sp.n_surveyed} of ${sp.n_points} surveyed (${sp.grid_m} m grid)`],
      ["Expected error once surveyed", `${num(sp.expected_error_m)} m (p90 ${num(sp.expected_error_p90_m)} m)`],
    );
  }
  return dl(rows);
}

export async function floorPage(main, { id }, query, signal) {
  const map = new FloorMap();
  const heatmap = new Heatmap(map.layers.heatmap);
  const zones = new ZoneLayer(map.layers.zones, () => map.dot);
  const crumbs = h("nav", { class: "crumbs", "aria-label": "breadcrumb" }, h("a", { href: "#/" }, "Sites"));
  const title = h("h1", {}, "Floor");
  const levels = h("nav", { class: "levels", "aria-label": "levels" });
  const planNote = h("p", { class: "muted plan-note" });
  const layersBox = h("div", { class: "layers" });
  const qualityBox = h("div", { class: "quality" }, h("p", { class: "muted" }, "loading…"));
  const liveBox = h("div", { class: "live" });
  const routeBox = h("div", { class: "routes" });
  fill(
    main,
    crumbs,
    h("div", { class: "title-row" }, title, levels),
    h(
      "div",
      { class: "floor-grid" },
      h("div", { class: "floor-map" }, map.element, planNote),
      h("aside", { class: "floor-side" }, section("Layers", layersBox), section("Route", routeBox), section("Coverage heatmap", heatmap.element), section("Zones", zones.element), section("Live sessions", liveBox), section("Map quality", qualityBox)),
    ),
  );
  for (const [name, text, on] of LAYER_NAMES) {
    map.show(name, on);
    layersBox.append(
      h("label", { class: "check" }, h("input", { type: "checkbox", name, checked: on, onchange: (e) => map.show(name, e.target.checked) }), " ", text),
    );
  }

  const floor = await get(`/v1/floors/${id}`, {}, { signal });
  title.textContent = `Level ${floor.level}${floor.name ? ` · ${floor.name}` : ""}`;
  document.title = `${title.textContent} · indoorpos`;
  const tool = new RouteTool(map, floor);
  routeBox.append(tool.element);
  const navigation = new NavigationView(map, floor, tool, signal);
  const live = liveSessions(liveBox, map, floor, query, signal, zones, navigation);

  const context = (async () => {
    const building = await get(`/v1/buildings/${floor.building_id}`, {}, { signal });
    const [site, floors] = await Promise.all([
      get(`/v1/sites/${building.site_id}`, {}, { signal }),
      get(`/v1/buildings/${building.id}/floors`, {}, { signal }),
    ]);
    crumbs.append(" / ", h("a", { href: `#/sites/${site.id}` }, site.name), " / ", h("a", { href: `#/buildings/${building.id}` }, building.name));
    fill(
      levels,
      [...floors.items]
        .sort((a, b) => a.level - b.level)
        .map((f) => h("a", { href: `#/floors/${f.id}`, class: f.id === id ? "current" : "", "aria-current": f.id === id ? "page" : undefined }, String(f.level))),
    );
    live.siteKnown(site.id);
    const offered = await capabilities();
    tool.siteKnown(site.id, offered.routePlanning);
    navigation.offer(offered.navigation);
  })();

  const plan = (async () => {
    if (!floor.has_plan) {
      planNote.textContent = "This floor has no plan: PUT /v1/floors/{id}/plan.";
      return;
    }
    const counts = map.setPlan(await get(`/v1/floors/${id}/plan`, {}, { signal }));
    const parts = [`${counts.walkable} walkable areas`, `${counts.walls} walls`, `${counts.doors} doors`, `${counts.beacons} points`];
    if (counts.connectors) parts.push(`${counts.connectors} stairs, lifts, escalators or ramps`);
    if (counts.other) parts.push(`${counts.other} features without a kind the positioning knows (dashed)`);
    planNote.textContent = parts.join(", ");
  })();

  const quality = (async () => {
    await plan.catch(() => {}); // the layers are framed by the plan, when there is one
    const [q, placement, magnetic] = await Promise.all([
      get(`/v1/floors/${id}/maps/quality`, {}, { signal }),
      get(`/v1/floors/${id}/maps/placement`, {}, { signal }).catch((error) => {
        if (error instanceof ApiError && error.status === 422) return null; // no plan, no points
        throw error;
      }),
      get(`/v1/floors/${id}/magnetic-maps`, {}, { signal }),
    ]);
    map.setEmitters(q.emitters.positions);
    if (placement) map.setCoverage(placement);
    const current = magnetic.items.find((m) => m.id === q.magnetic_map?.id);
    map.setMagneticGrid(current);
    fill(qualityBox, qualityFacts(q, placement));
    qualityBox.dataset.loaded = "true";
  })();

  const report = (box) => (error) => {
    if (error.name !== "AbortError") box.append(h("p", { class: "error" }, error.message));
  };
  plan.catch(() => {}).then(() => tool.render()); // the route's marks are sized by the plan
  const zoneDrawing = plan.catch(() => {}).then(() => zones.load(id, { signal })).catch(report(zones.element));
  // where the radio map is thin, cell by cell (framed by the plan, when there is one)
  const coverage = plan.catch(() => {}).then(() => heatmap.load(id, { signal })).catch(report(heatmap.element));
  await Promise.all([context.catch(report(crumbs)), plan.catch(report(planNote)), quality.catch((e) => {
    if (e.name !== "AbortError") fill(qualityBox, h("p", { class: "error" }, e.message));
  })]);
  await coverage;
  await zoneDrawing;
}

// ------------------------------------------------------------------ live sessions

function liveSessions(box, map, floor, query, signal, zones, navigation) {
  const followed = new Map(); // session id -> {colour, handle, row, ...}
  const rows = h("ul", { class: "sessions" });
  const listNote = h("p", { class: "muted" });
  const idInput = h("input", { name: "session", placeholder: "session id", pattern: "[0-9a-f]{32}", required: true, autocomplete: "off" });
  const tokenInput = h("input", { name: "token", type: "password", placeholder: "session token (optional)", autocomplete: "off" });
  let listTimer;
  let caps;

  const onFloor = (fix) => (fix.floor_id ? fix.floor_id === floor.id : fix.floor === null || fix.floor === undefined || fix.floor === floor.level);
  const replay = new HistoryPanel(map, onFloor, signal); // a followed session's past fixes, by a time slider

  function render(entry) {
    const fix = entry.lastFix;
    let where = "no fix yet";
    if (fix) {
      const accuracy = fix.accuracy_68_m ?? fix.uncertainty_m;
      where = onFloor(fix)
        ? `(${num(fix.x_m)}, ${num(fix.y_m)}) m ± ${num(accuracy)} m at ${new Date(entry.receivedAt).toLocaleTimeString()}`
        : `on level ${fix.floor ?? "?"}`;
    }
    fill(
      entry.row,
      h("span", { class: "swatch", title: entry.id }, "●"),
      h("code", { title: entry.id }, shortId(entry.id)),
      h("span", { class: `state state-${entry.state}` }, entry.state),
      h("span", { class: "where" }, where),
      entry.detail ? h("span", { class: "detail" }, entry.detail) : "",
      navigation.line(entry),
      h(
        "span",
        { class: "row-actions" },
        navigation.button(entry),
        caps?.sessionTrack ? h("button", { type: "button", onclick: () => loadTrack(entry) }, "Track") : "",
        caps?.sessionHistory ? h("button", { type: "button", class: "history-open", onclick: () => replay.open(entry.id, entry.colour, entry.token) }, "History") : "",
        h("button", { type: "button", onclick: () => unfollow(entry.id) }, "Stop"),
      ),
    );
    entry.row.querySelector(".swatch").style.color = entry.colour;
  }

  async function loadTrack(entry) {
    try {
      const { path, query: q } = request(caps.sessionTrack, { session_id: entry.id }, { limit: 1000 });
      const body = await get(path, q, { signal });
      const fixes = body.items ?? body.fixes ?? (Array.isArray(body) ? body : []);
      map.addToTrack(entry.id, entry.colour, fixes.filter(onFloor));
      entry.detail = `track: the last ${fixes.length} fixes`;
    } catch (error) {
      entry.detail = `track: ${error.message}`;
    }
    render(entry);
  }

  function start(id, token) {
    if (followed.has(id) || signal.aborted) return;
    const entry = { id, colour: COLOURS[followed.size % COLOURS.length], state: "connecting", detail: "", lastFix: null, row: h("li", { "data-session": id }) };
    followed.set(id, entry);
    entry.token = token;
    rows.append(entry.row);
    entry.handle = follow(id, token || key.get(), {
      state(state, detail) {
        // the recent path, once: what the live socket does not replay
        if (state === "live" && !entry.trackLoaded && caps?.sessionTrack) {
          entry.trackLoaded = true;
          loadTrack(entry);
        }
        entry.state = state;
        entry.detail = state === "refused" && !token ? `${detail}. A key that may not follow sessions needs the session's token.` : detail;
        render(entry);
      },
      fix(fix) {
        entry.lastFix = fix;
        entry.receivedAt = Date.now();
        entry.row.dataset.t = fix.t; // the last fix's time, whatever the dot shows
        const here = onFloor(fix);
        if (!replay.holds(id)) map.place(id, entry.colour, here ? fix : null);
        zones.occupy(id, here ? fix.zones : []);
        if (here) map.addToTrack(id, entry.colour, [fix]);
        navigation.update(entry, fix);
        render(entry);
      },
    });
    render(entry);
  }

  function unfollow(id) {
    const entry = followed.get(id);
    if (!entry) return;
    entry.handle.stop();
    entry.row.remove();
    map.forget(id);
    replay.forget(id);
    navigation.forget(id);
    followed.delete(id);
  }

  signal.addEventListener("abort", () => {
    clearTimeout(listTimer);
    for (const id of [...followed.keys()]) unfollow(id);
  });

  const form = h(
    "form",
    {
      class: "follow",
      onsubmit: (event) => {
        event.preventDefault();
        const id = idInput.value.trim().toLowerCase();
        const token = tokenInput.value.trim();
        if (token && followed.has(id) && followed.get(id).token !== token) unfollow(id); // again, with its token's rights
        start(id, token);
        idInput.value = "";
        tokenInput.value = "";
      },
    },
    idInput,
    tokenInput,
    h("button", { type: "submit" }, "Follow"),
  );
  fill(box, listNote, form, rows, replay.element);

  for (const id of (query.get("follow") ?? "").split(",")) if (/^[0-9a-f]{32}$/.test(id)) start(id, "");

  async function poll(siteId) {
    const route = caps.sessionList;
    try {
      const { path, query: q } = request(route, { site_id: siteId, floor_id: floor.id }, { active: true, limit: 100 });
      const body = await get(path, q, { signal });
      const items = body.items ?? [];
      let started = 0;
      for (const item of items) {
        const id = item.id ?? item.session_id;
        const fix = item.last_fix;
        if (!id || followed.has(id) || item.active === false || (fix && !onFloor(fix))) continue;
        if (followed.size >= MAX_AUTO_FOLLOW) break;
        start(id, "");
        started += 1;
      }
      listNote.textContent = `${items.length} active session${items.length === 1 ? "" : "s"} on this site, followed as they start (at most ${MAX_AUTO_FOLLOW}); those on other levels are listed, not drawn.`;
    } catch (error) {
      if (error.name === "AbortError") return;
      listNote.textContent = `The session list failed: ${error.message}`;
    }
    listTimer = setTimeout(() => poll(siteId), LIST_REFRESH_MS);
  }

  capabilities().then((found) => {
    caps = found;
    for (const entry of followed.values()) render(entry);
    if (!caps.sessionList) listNote.textContent = "This server lists no sessions (no GET /v1/sessions): follow a session by its id.";
  });

  return {
    async siteKnown(siteId) {
      await capabilities();
      if (caps?.sessionList) poll(siteId);
    },
  };
}
