// Uploads and their status: the server's list when it has one, else the uploads looked
// up by id in this tab.

import { ApiError, capabilities, get, list, request } from "./api.js";
import { ago, fill, h, shortId } from "./dom.js";

const SEEN_NAME = "indoorpos.console.uploads";
const MAX_SEEN = 50;
const UNSETTLED = new Set(["queued", "processing"]);
const REFRESH_MS = 3000;

function seen() {
  try {
    return JSON.parse(sessionStorage.getItem(SEEN_NAME) ?? "[]");
  } catch {
    return [];
  }
}

function remember(id) {
  const ids = [id, ...seen().filter((x) => x !== id)].slice(0, MAX_SEEN);
  sessionStorage.setItem(SEEN_NAME, JSON.stringify(ids));
}

function reason(report) {
  if (!report) return "";
  return report.reason ?? report.last_error ?? "";
}

function row(u) {
  return h(
    "tr",
    { "data-upload": u.id },
    h("td", { title: u.id }, h("code", {}, shortId(u.id))),
    h("td", {}, h("span", { class: `status status-${u.status}` }, u.status)),
    h("td", {}, u.floor ?? "—"),
    h("td", {}, u.device_model ?? "—"),
    h("td", { class: "n" }, u.attempts),
    h("td", { title: u.created_at }, ago(u.created_at)),
    h("td", { title: u.updated_at }, ago(u.updated_at)),
    h(
      "td",
      { class: "wrap" },
      reason(u.report),
      u.report ? h("details", {}, h("summary", {}, "report"), h("pre", {}, JSON.stringify(u.report, null, 2))) : "",
    ),
  );
}

function table(uploads) {
  if (!uploads.length) return h("p", { class: "muted" }, "No uploads yet.");
  return h(
    "div",
    { class: "scroll" },
    h(
      "table",
      { class: "uploads" },
      h("thead", {}, h("tr", {}, ...["id", "status", "floor", "device", "tries", "created", "updated", "reason"].map((t) => h("th", {}, t)))),
      h("tbody", {}, uploads.map(row)),
    ),
  );
}

/** The uploads panel: of one site (siteId) or of every site looked at (none). */
export async function uploadsPanel(container, { siteId } = {}, signal) {
  const caps = await capabilities();
  const route = caps.uploadList;
  const body = h("div", { class: "uploads-body" });
  const note = h("p", { class: "muted" });
  let timer;
  signal.addEventListener("abort", () => clearTimeout(timer));

  async function fromServer() {
    const { path, query } = request(route, { site_id: siteId }, { limit: 100 });
    return list(path, query, { signal });
  }

  async function looked() {
    const found = [];
    for (const id of seen()) {
      try {
        const u = await get(`/v1/uploads/${id}`, {}, { signal });
        if (!siteId || u.site_id === siteId) found.push(u);
      } catch (error) {
        if (error.name === "AbortError") throw error;
      }
    }
    return found;
  }

  async function refresh() {
    try {
      const uploads = route && (siteId || !route.template.includes("{site_id}")) ? await fromServer() : await looked();
      fill(body, table(uploads));
      if (uploads.some((u) => UNSETTLED.has(u.status))) timer = setTimeout(refresh, REFRESH_MS);
    } catch (error) {
      if (error.name !== "AbortError") fill(body, h("p", { class: "error" }, error.message));
    }
  }

  const input = h("input", { name: "upload", placeholder: "upload id (32 hex digits)", pattern: "[0-9a-f]{32}", required: true, autocomplete: "off" });
  const status = h("span", { class: "error", role: "status" });
  const form = h(
    "form",
    {
      class: "inline",
      onsubmit: async (event) => {
        event.preventDefault();
        const id = input.value.trim().toLowerCase();
        status.textContent = "";
        try {
          await get(`/v1/uploads/${id}`, {}, { signal });
          remember(id);
          input.value = "";
          clearTimeout(timer);
          await refresh();
        } catch (error) {
          status.textContent = error instanceof ApiError && error.status === 404 ? "no such upload" : error.message;
        }
      },
    },
    h("label", {}, "Look up an upload ", input),
    h("button", { type: "submit" }, "Look up"),
    status,
  );
  if (!route) note.textContent = "This server lists no uploads (no GET /v1/uploads): the uploads looked up by id here are shown.";
  fill(container, h("h2", {}, "Uploads"), note, form, body);
  await refresh();
}
