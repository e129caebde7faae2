// The console: asks for a key, then routes #/..., #/sites/{id}, #/buildings/{id},
// #/floors/{id} (?follow=id,id) and #/uploads to their pages.

import { ApiError, get, key, list } from "./api.js";
import { ago, fill, h, num } from "./dom.js";
import { floorPage } from "./floor.js";
import { uploadsPanel } from "./uploads.js";

const main = document.getElementById("main");
const forget = document.getElementById("forget");
let current = null; // AbortController of the page shown

function table(headings, rows) {
  if (!rows.length) return h("p", { class: "muted" }, "None yet.");
  return h(
    "div",
    { class: "scroll" },
    h("table", {}, h("thead", {}, h("tr", {}, headings.map((t) => h("th", {}, t)))), h("tbody", {}, rows)),
  );
}

const link = (href, text) => h("a", { href }, text);
const when = (iso) => h("span", { title: iso }, ago(iso));

async function sitesPage(el, _params, _query, signal) {
  const sites = await list("/v1/sites", {}, { signal });
  fill(
    el,
    h("h1", {}, "Sites"),
    table(
      ["name", "id", "created"],
      sites.map((x) => h("tr", {}, h("td", {}, link(`#/sites/${x.id}`, x.name)), h("td", {}, h("code", {}, x.id)), h("td", {}, when(x.created_at)))),
    ),
  );
}

async function sitePage(el, { id }, _query, signal) {
  const [site, buildings] = await Promise.all([get(`/v1/sites/${id}`, {}, { signal }), list(`/v1/sites/${id}/buildings`, {}, { signal })]);
  document.title = `${site.name} · indoorpos`;
  const uploads = h("section", { class: "panel" });
  fill(
    el,
    h("nav", { class: "crumbs" }, link("#/", "Sites")),
    h("h1", {}, site.name),
    h("section", { class: "panel" }, h("h2", {}, "Buildings"),
      table(
        ["name", "origin (lat, lon)", "rotation", "created"],
        buildings.map((b) =>
          h(
            "tr",
            {},
            h("td", {}, link(`#/buildings/${b.id}`, b.name)),
            h("td", {}, b.origin_lat === null ? "—" : `${num(b.origin_lat, 6)}, ${num(b.origin_lon, 6)}`),
            h("td", {}, `${num((b.rotation_rad * 180) / Math.PI, 1)}°`),
            h("td", {}, when(b.created_at)),
          ),
        ),
      ),
    ),
    uploads,
  );
  await uploadsPanel(uploads, { siteId: id }, signal);
}

async function buildingPage(el, { id }, _query, signal) {
  const building = await get(`/v1/buildings/${id}`, {}, { signal });
  const [site, floors, radioMaps] = await Promise.all([
    get(`/v1/sites/${building.site_id}`, {}, { signal }),
    list(`/v1/buildings/${id}/floors`, {}, { signal }),
    list(`/v1/buildings/${id}/radio-maps`, {}, { signal }),
  ]);
  document.title = `${building.name} · indoorpos`;
  floors.sort((a, b) => a.level - b.level);
  radioMaps.sort((a, b) => b.version - a.version);
  fill(
    el,
    h("nav", { class: "crumbs" }, link("#/", "Sites"), " / ", link(`#/sites/${site.id}`, site.name)),
    h("h1", {}, building.name),
    h("section", { class: "panel" }, h("h2", {}, "Floors"),
      table(
        ["level", "name", "plan", "created"],
        floors.map((f) =>
          h("tr", {}, h("td", {}, link(`#/floors/${f.id}`, `Level ${f.level}`)), h("td", {}, f.name ?? "—"), h("td", {}, f.has_plan ? "yes" : "no"), h("td", {}, when(f.created_at))),
        ),
      ),
    ),
    h("section", { class: "panel" }, h("h2", {}, "Radio map versions"),
      table(
        ["version", "reference points", "emitters", "survey points", "cell", "activated"],
        radioMaps.map((m) =>
          h(
            "tr",
            {},
            h("td", {}, `v${m.version}`),
            h("td", { class: "n" }, m.n_reference_points),
            h("td", { class: "n" }, m.n_emitters),
            h("td", { class: "n" }, m.n_survey_points),
            h("td", {}, `${m.cell_m} m`),
            h("td", {}, when(m.activated_at)),
          ),
        ),
      ),
    ),
  );
}

async function uploadsPage(el, _params, _query, signal) {
  const panel = h("section", { class: "panel" });
  fill(el, h("h1", {}, "Uploads"), panel);
  await uploadsPanel(panel, {}, signal);
}

const ROUTES = [
  [/^\/?$/, sitesPage],
  [/^\/sites\/([0-9a-f]{32})$/, sitePage],
  [/^\/buildings\/([0-9a-f]{32})$/, buildingPage],
  [/^\/floors\/([0-9a-f]{32})$/, floorPage],
  [/^\/uploads$/, uploadsPage],
];

function keyForm(message) {
  forget.hidden = true;
  const input = h("input", { name: "key", type: "password", required: true, autocomplete: "off", autofocus: true });
  const error = h("p", { class: "error", role: "alert" }, message ?? "");
  fill(
    main,
    h(
      "form",
      {
        class: "key-form panel",
        onsubmit: async (event) => {
          event.preventDefault();
          key.set(input.value.trim());
          try {
            await get("/v1/sites");
          } catch (e) {
            key.clear();
            error.textContent = e instanceof ApiError && e.status === 403 ? `${e.message}: the console needs a viewer or admin key` : e.message;
            return;
          }
          route();
        },
      },
      h("h1", {}, "indoorpos console"),
      h("p", {}, "An API key with the viewer scope shows a site; an admin key shows every site. It is kept in this tab only and sent as a bearer token."),
      h("label", {}, "API key ", input),
      h("button", { type: "submit" }, "Open"),
      error,
    ),
  );
  input.focus();
}

async function route() {
  current?.abort();
  delete main.dataset.page;
  if (!key.get()) return keyForm();
  forget.hidden = false;
  current = new AbortController();
  const { signal } = current;
  const [path, search] = location.hash.replace(/^#/, "").split("?");
  const query = new URLSearchParams(search ?? "");
  for (const link of document.querySelectorAll("header nav a")) link.classList.toggle("current", link.getAttribute("href") === `#${path || "/"}`);
  document.title = "indoorpos console";
  for (const [pattern, page] of ROUTES) {
    const match = pattern.exec(path);
    if (!match) continue;
    fill(main, h("p", { class: "muted" }, "loading…"));
    try {
      await page(main, { id: match[1] }, query, signal);
      main.dataset.page = page.name;
    } catch (error) {
      if (error.name === "AbortError" || signal.aborted) return;
      fill(main, h("p", { class: "error" }, error instanceof ApiError ? `${error.status}: ${error.message}` : String(error)));
    }
    return;
  }
  fill(main, h("h1", {}, "Not found"), h("p", {}, link("#/", "Back to the sites")));
}

window.addEventListener("hashchange", route);
window.addEventListener("key-refused", (event) => {
  key.clear();
  current?.abort();
  keyForm(`The key was refused: ${event.detail}`);
});
forget.addEventListener("click", () => {
  key.clear();
  route();
});
route();
