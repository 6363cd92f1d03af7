// The daemon's public API, as any client uses it: JSON bodies with
// `Content-Type: application/json`, the token as `Authorization: Bearer`.
// The token lives in sessionStorage (gone when the tab closes).

const KEY = 'springbench.token';

export const token = {
  get: () => sessionStorage.getItem(KEY),
  set: (t) => sessionStorage.setItem(KEY, t),
  clear: () => sessionStorage.removeItem(KEY),
};

/**
 * Which daemon serves the page: a station, or the fleet's center (issue 20:
 * reads only, the station of every row; no jobs, benches or writes). Set
 * from `GET /api/v1/session` at sign-in.
 */
export const daemon = { center: false };

/** An answer of the daemon that is not 2xx (body: the RFC 9457 problem document). */
export class ApiError extends Error {
  constructor(status, problem) {
    const p = problem && typeof problem === 'object' ? problem : {};
    const fields = (p.errors || []).map((e) => (e.field ? `${e.field}: ${e.message}` : e.message));
    super(fields.length ? fields.join('; ') : p.detail || p.title || `HTTP ${status}`);
    this.status = status;
    this.problem = p;
  }
}

/** The daemon did not answer at all. */
export class Unreachable extends Error {}

// Listeners told when reachability changes or a token is refused.
const listeners = { reachable: [], unauthorized: [] };
export function on(what, f) {
  listeners[what].push(f);
}
let lastReachable = true;
function reachable(ok, detail) {
  if (ok === lastReachable) return;
  lastReachable = ok;
  for (const f of listeners.reachable) f(ok, detail);
}
export function isReachable() {
  return lastReachable;
}

/** Calls the API; resolves to the parsed JSON (or text), throws ApiError / Unreachable. */
export async function api(path, { method = 'GET', body, headers = {}, raw = false } = {}) {
  const h = { Accept: 'application/json, application/problem+json', ...headers };
  const t = token.get();
  if (t) h.Authorization = `Bearer ${t}`;
  let payload;
  if (body !== undefined) {
    h['Content-Type'] = 'application/json';
    payload = JSON.stringify(body);
  }
  let r;
  try {
    r = await fetch(path, { method, headers: h, body: payload, cache: 'no-store' });
  } catch (e) {
    reachable(false, String(e));
    throw new Unreachable(`the daemon at ${location.host} does not answer (${e.message})`);
  }
  reachable(true);
  if (r.status === 401) for (const f of listeners.unauthorized) f();
  if (raw && r.ok) return r;
  const ct = r.headers.get('content-type') || '';
  const data = ct.includes('json') ? await r.json() : await r.text();
  if (!r.ok) throw new ApiError(r.status, data);
  return data;
}

/** Downloads a file of the API with the token (a plain link cannot send it). */
export async function download(path, filename) {
  const r = await api(path, { raw: true, headers: { Accept: '*/*' } });
  const blob = await r.blob();
  const url = URL.createObjectURL(blob);
  const a = document.createElement('a');
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

/**
 * The event stream (websocket): calls onEvent for each event, reconnects
 * with backoff, catches up on stored events after a reconnect.
 */
export function events(onEvent, onState) {
  let ws = null;
  let last = null;
  let closed = false;
  let delay = 500;
  function connect() {
    const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const params = new URLSearchParams();
    if (last !== null) params.set('after', String(last));
    const t = token.get();
    if (t) params.set('token', t);
    const qs = params.toString();
    ws = new WebSocket(`${proto}//${location.host}/api/v1/events${qs ? `?${qs}` : ''}`);
    ws.onopen = () => {
      delay = 500;
      onState && onState(true);
    };
    ws.onmessage = (m) => {
      let ev;
      try {
        ev = JSON.parse(m.data);
      } catch {
        return;
      }
      if (!ev.live && typeof ev.seq === 'number') last = ev.seq;
      onEvent(ev);
    };
    ws.onclose = () => {
      onState && onState(false);
      if (closed) return;
      setTimeout(connect, delay);
      delay = Math.min(delay * 2, 8000);
    };
  }
  connect();
  return {
    close() {
      closed = true;
      if (ws) ws.close();
    },
  };
}
