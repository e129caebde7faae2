// A floor's zones (GET /v1/floors/{id}/zones): drawn in floor metres inside the floor
// map's y-flipped group, named, and lit while a followed session is in one (a fix's
// `zones`). The list beside the map counts who is in each.

import { get } from "./api.js";
import { fill, h, s } from "./dom.js";

const ringPath = (ring) => ring.map(([x, y], i) => `${i ? "L" : "M"}${x} ${y}`).join("") + "Z";

function polygons(geometry) {
  if (geometry?.type === "Polygon") return [geometry.coordinates];
  if (geometry?.type === "MultiPolygon") return geometry.coordinates;
  return [];
}

/** The middle of a polygon's bounding box, for its label. */
function middle(polys) {
  const xs = polys.flatMap((p) => p[0].map(([x]) => x));
  const ys = polys.flatMap((p) => p[0].map(([, y]) => y));
  return [(Math.min(...xs) + Math.max(...xs)) / 2, (Math.min(...ys) + Math.max(...ys)) / 2];
}

export class ZoneLayer {
  /** `layer`: the floor map's SVG group to draw in; `dot`: a text size in metres. */
  constructor(layer, dot) {
    this.layer = layer;
    this.dot = dot;
    this.zones = new Map(); // id -> {name, path, item}
    this.occupants = new Map(); // session id -> zone ids it is in
    this.list = h("ul", { class: "zone-list" });
    this.note = h("p", { class: "muted" }, "loading…");
    this.element = h("div", { class: "zones" }, this.note, this.list);
  }

  async load(floorId, options) {
    const body = await get(`/v1/floors/${floorId}/zones`, {}, options);
    this.draw(body.features ?? []);
  }

  draw(features) {
    this.layer.replaceChildren();
    this.zones.clear();
    const items = [];
    for (const feature of features) {
      const polys = polygons(feature.geometry);
      if (!polys.length) continue;
      const name = feature.name ?? feature.id;
      const path = s("path", { class: "zone", d: polys.map((p) => p.map(ringPath).join("")).join(""), "data-zone": feature.id }, s("title", { text: name }));
      const [x, y] = middle(polys);
      const size = this.dot() * 2.5;
      // text is drawn upright: the group flips y, the label flips it back
      const text = s("text", { class: "zone-label", x, y: -y, "font-size": size, transform: "scale(1 -1)", "text-anchor": "middle" }, name);
      this.layer.append(path, text);
      const count = h("span", { class: "zone-count" });
      const item = h("li", { "data-zone": feature.id }, h("span", { class: "zone-name" }, name), " ", count);
      this.zones.set(feature.id, { name, path, count });
      items.push(item);
    }
    fill(this.list, items);
    this.note.textContent = this.zones.size
      ? `${this.zones.size} zone${this.zones.size === 1 ? "" : "s"}; lit while a followed session is in it.`
      : "No zones on this floor: PUT /v1/floors/{id}/zones.";
    this.#light();
  }

  /** The zones a session is in after its newest fix (none once it leaves the floor). */
  occupy(sessionId, zoneIds) {
    if (zoneIds?.length) this.occupants.set(sessionId, zoneIds);
    else this.occupants.delete(sessionId);
    this.#light();
  }

  #light() {
    const counts = new Map();
    for (const ids of this.occupants.values()) for (const id of ids) counts.set(id, (counts.get(id) ?? 0) + 1);
    for (const [id, zone] of this.zones) {
      const n = counts.get(id) ?? 0;
      zone.path.classList.toggle("occupied", n > 0);
      zone.count.textContent = n ? `${n} in` : "";
    }
  }
}
