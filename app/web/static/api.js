// Thin fetch wrappers: every API error is JSON {code, message}, so callers get one shape back.

export const TOKEN_KEY = 'ugvmap.token';
// Network data (lists, TileJSON, styles, MVT tiles, features, routes) may need a reader token
// (UGVMAP_NETWORK_READ_ROLE); raster layers and tiles never do.
const GUARDED = /^\/(networks|collections|change-sets)(\/|$)/;
let readsNeedToken = false;

/** The token pasted in the panel, kept for this tab only, or ''. */
export function savedToken() {
  return sessionStorage.getItem(TOKEN_KEY) || '';
}

/**
 * Authorization for a read of this server's network data, once the server has asked for a
 * token (a 401): sent only then, so on a public server tile requests carry no token and the
 * front cache (which bypasses requests with one) keeps serving them; never sent elsewhere.
 */
export function readHeaders(url) {
  const target = new URL(url, window.location.href);
  const token = savedToken();
  if (!readsNeedToken || !token || target.origin !== window.location.origin
      || !GUARDED.test(target.pathname)) return {};
  return { Authorization: `Bearer ${token}` };
}

/** Headers of a write with the token pasted in the panel. */
export function editorHeaders() {
  return { Authorization: `Bearer ${savedToken()}`, 'Content-Type': 'application/json' };
}

/** Fetch JSON; resolves to {ok, status, body, etag} and never throws for HTTP errors. */
export async function request(url, options = {}) {
  let response;
  const send = () => fetch(url, { ...options, headers: { ...readHeaders(url), ...options.headers } });
  try {
    response = await send();
    const read = (options.method || 'GET') === 'GET' && !options.headers?.Authorization;
    if (response.status === 401 && read && !readsNeedToken && savedToken()) {
      readsNeedToken = true; // the server guards reads: from now on every read carries the token
      response = await send();
    }
  } catch (err) {
    return { ok: false, status: 0, body: { code: 'NetworkError', message: `server unreachable (${err.message})` } };
  }
  let body = null;
  try {
    body = await response.json();
  } catch {
    body = { code: 'BadResponse', message: `${response.status} ${response.statusText}` };
  }
  return { ok: response.ok, status: response.status, body, etag: response.headers.get('ETag') };
}

/** The message to show a person for a failed request. */
export function describeError(result) {
  const body = result.body || {};
  return body.message || body.code || `request failed (${result.status})`;
}

export function setStatus(text) {
  document.getElementById('status').textContent = text;
}
