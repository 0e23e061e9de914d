// Requests to the API this page was served by (any path prefix in front of /v1 is kept).
const KEY = 'vpp-api-key';
export const base = location.pathname.slice(0, location.pathname.indexOf('/v1/'));

export class AuthError extends Error {}
export class HttpError extends Error {
  constructor(status, problem) {
    super(problem?.detail || problem?.title || `HTTP ${status}`);
    this.status = status;
  }
}

export function setKey(key) { sessionStorage.setItem(KEY, key); }

async function request(path, init = {}) {
  const headers = { ...(init.headers || {}) };
  const key = sessionStorage.getItem(KEY);
  if (key) headers.Authorization = `Bearer ${key}`;
  const r = await fetch(base + path, { ...init, headers });
  if (r.status === 401 || r.status === 403) throw new AuthError(`HTTP ${r.status}`);
  if (!r.ok) throw new HttpError(r.status, await r.json().catch(() => null));
  return r;
}

export const getJson = async (path) => (await request(path)).json();
export const getBinary = async (path) => (await request(path)).arrayBuffer();
export const postJson = async (path, body) => (await request(path, {
  method: 'POST', headers: { 'content-type': 'application/json' }, body: JSON.stringify(body),
})).json();
