// Thin fetch wrappers: every API error is JSON {code, message}, so callers get one shape back.

/** Fetch JSON; resolves to {ok, status, body, etag} and never throws for HTTP errors. */
export async function request(url, options = {}) {
  let response;
  try {
    response = await fetch(url, options);
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
