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

/**
 * Follow a job's Server-Sent Events (GET /v1/jobs/{id}/events) over fetch, so that a bearer key
 * goes with them (EventSource cannot send one). Calls onEvent(name, data) for each event and
 * resolves with the data of the final `done` (the job); rejects if the stream fails or ends
 * before it.
 */
export async function followEvents(path, onEvent) {
  const r = await request(path, { headers: { accept: 'text/event-stream' } });
  const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = '';
  for (;;) {
    const { value, done } = await reader.read();
    if (done) throw new Error('the event stream ended before the job did');
    buffer += value.replace(/\r\n?/g, '\n');
    let end;
    while ((end = buffer.indexOf('\n\n')) >= 0) {
      const block = buffer.slice(0, end);
      buffer = buffer.slice(end + 2);
      let name = 'message';
      const data = [];
      for (const line of block.split('\n')) {
        const colon = line.indexOf(':');
        if (colon === 0) continue; // a comment (keep-alive)
        const field = colon < 0 ? line : line.slice(0, colon);
        const text = colon < 0 ? '' : line.slice(colon + 1).replace(/^ /, '');
        if (field === 'event') name = text;
        if (field === 'data') data.push(text);
      }
      if (!data.length) continue;
      const parsed = JSON.parse(data.join('\n'));
      onEvent(name, parsed);
      if (name === 'done') { reader.cancel().catch(() => {}); return parsed; }
    }
  }
}

export const getJson = async (path) => (await request(path)).json();
export const getBinary = async (path) => (await request(path)).arrayBuffer();
export const postJson = async (path, body) => (await request(path, {
  method: 'POST', headers: { 'content-type': 'application/json' }, body: JSON.stringify(body),
})).json();
