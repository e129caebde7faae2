// The console's calls to the API: the key, JSON reads, lists, the live socket, and what
// this server offers (read from its OpenAPI document, so that the console uses routes
// added later and leaves out those a server does not have).

const KEY_NAME = "indoorpos.console.key";
// the page is /console/ (under any path prefix): the API is one level up
const BASE = new URL("../", location.href);

export const key = {
  get: () => sessionStorage.getItem(KEY_NAME),
  set: (value) => sessionStorage.setItem(KEY_NAME, value),
  clear: () => sessionStorage.removeItem(KEY_NAME),
};

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

export function url(path, query = {}) {
  const target = new URL(path.replace(/^\//, ""), BASE);
  for (const [name, value] of Object.entries(query)) {
    if (value !== undefined && value !== null) target.searchParams.set(name, String(value));
  }
  return target;
}

async function errorOf(response) {
  let message = `${response.status} ${response.statusText}`;
  try {
    const body = await response.json();
    if (typeof body.message === "string") message = body.message;
  } catch {
    // not JSON: keep the status line
  }
  return new ApiError(response.status, message);
}

// the JSON of a 2xx answer (null when it has none), else an ApiError (a 401 for the key
// also tells the page, which asks for a key again)
async function answer(response, credential) {
  if (!response.ok) {
    const error = await errorOf(response);
    if (response.status === 401 && !credential) window.dispatchEvent(new CustomEvent("key-refused", { detail: error.message }));
    throw error;
  }
  return response.status === 204 ? null : response.json();
}

const headersFor = (credential) => ({ Authorization: `Bearer ${credential || key.get() || ""}`, Accept: "application/json" });

/** GET a JSON document with the key (or with `credential`, a session's token, say);
 * ApiError on any non-2xx answer. */
export async function get(path, query, { signal, credential } = {}) {
  return answer(await fetch(url(path, query), { headers: headersFor(credential), signal }), credential);
}

/** Send a JSON body (POST, PUT; none for DELETE) with the key or `credential`; the
 * answer's JSON (null when it has none); ApiError on any non-2xx answer. */
export async function send(method, path, body, { signal, credential } = {}) {
  const headers = headersFor(credential);
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const payload = body === undefined ? undefined : JSON.stringify(body);
  return answer(await fetch(url(path), { method, headers, body: payload, signal }), credential);
}

const MAX_PAGES = 20;

/** Every item of a list answer ({items, count}), following its cursor while the answer
 * names a next one (at most MAX_PAGES pages). */
export async function list(path, query = {}, options = {}) {
  const items = [];
  let cursor;
  for (let page = 0; page < MAX_PAGES; page += 1) {
    const body = await get(path, cursor ? { ...query, cursor } : query, options);
    items.push(...(body.items ?? []));
    const next = body.next_cursor ?? null;
    if (!next || next === cursor || !(body.items ?? []).length) break;
    cursor = next;
  }
  return items;
}

/** The ws(s) URL of an API path. */
export function socketUrl(path) {
  const target = url(path);
  target.protocol = target.protocol === "https:" ? "wss:" : "ws:";
  return target;
}

// ------------------------------------------------------------------ what the server has

let offered;

function finder(paths) {
  return (...templates) => {
    for (const template of templates) {
      const operation = paths[template]?.get;
      if (operation) {
        const params = new Set((operation.parameters ?? []).map((p) => p.name));
        return { template, params };
      }
    }
    return null;
  };
}

/** The optional routes this server has: {sessionList, sessionTrack, sessionHistory,
 * uploadList}, each null or {template, params}; and whether it plans routes
 * (`routePlanning`) and guides sessions (`navigation`). */
export function capabilities() {
  offered ??= fetch(url("openapi.json"))
    .then((r) => (r.ok ? r.json() : { paths: {} }))
    .catch(() => ({ paths: {} }))
    .then((doc) => {
      const find = finder(doc.paths ?? {});
      return {
        sessionList: find("/v1/sessions", "/v1/sites/{site_id}/sessions", "/v1/floors/{floor_id}/sessions"),
        sessionTrack: find("/v1/sessions/{session_id}/track", "/v1/sessions/{session_id}/fixes"),
        sessionHistory: find("/v1/sessions/{session_id}/history"),
        uploadList: find("/v1/uploads", "/v1/sites/{site_id}/uploads"),
        routePlanning: Boolean(doc.paths?.["/v1/sites/{site_id}/routes"]?.post),
        navigation: Boolean(doc.paths?.["/v1/sessions/{session_id}/navigation"]?.put),
      };
    });
  return offered;
}

/** The path and query of an optional route for the ids known: path parameters filled in,
 * the ids it takes as query parameters added. */
export function request(route, ids, extra = {}) {
  let path = route.template;
  const query = {};
  for (const [name, value] of Object.entries(ids)) {
    if (path.includes(`{${name}}`)) path = path.replace(`{${name}}`, encodeURIComponent(value));
    else if (route.params.has(name)) query[name] = value;
  }
  for (const [name, value] of Object.entries(extra)) if (route.params.has(name)) query[name] = value;
  return { path, query };
}

// ------------------------------------------------------------------ the live socket

const RETRIES = 6;

/** Follow a session's fixes over its live socket, authenticated with `credential` (the
 * key, or the session's own token). Calls on.state(state, detail) with "connecting",
 * "live", "retrying", "ended", "refused" or "lost", and on.fix(fix) for every fix. */
export function follow(sessionId, credential, on) {
  let socket;
  let tries = 0;
  let stopped = false;
  let timer;
  let lastError = "";

  function open() {
    on.state(tries ? "retrying" : "connecting", lastError);
    socket = new WebSocket(socketUrl(`/v1/sessions/${sessionId}/live`));
    socket.onopen = () => socket.send(JSON.stringify({ type: "auth", token: credential }));
    socket.onmessage = (event) => {
      let message;
      try {
        message = JSON.parse(event.data);
      } catch {
        return;
      }
      if (message.type === "ready") {
        tries = 0;
        on.state("live", "");
      } else if (message.type === "fix") on.fix(message.fix);
      else if (message.type === "error") lastError = message.message ?? `error ${message.status}`;
    };
    socket.onclose = (event) => {
      if (stopped) return;
      if (event.code === 1000) on.state("ended", "the session ended");
      else if (event.code >= 4400 && event.code < 4500 && event.code !== 4429)
        on.state("refused", lastError || `closed with ${event.code}`);
      else if (tries < RETRIES) {
        tries += 1;
        on.state("retrying", lastError);
        timer = setTimeout(open, Math.min(30000, 1000 * 2 ** tries));
      } else on.state("lost", lastError || "the socket keeps closing");
    };
  }

  open();
  return {
    stop() {
      stopped = true;
      clearTimeout(timer);
      socket?.close(1000);
    },
  };
}
