// The public REST API, with the session's API key (sessionStorage only, never in a URL).

const KEY = "shsas.apiKey";

export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
    this.detail = detail;
  }
}

export const key = {
  get: () => sessionStorage.getItem(KEY) || "",
  set: (v) => (v ? sessionStorage.setItem(KEY, v.trim()) : sessionStorage.removeItem(KEY)),
};

function authHeaders() {
  const k = key.get();
  return k ? { Authorization: `Bearer ${k}` } : {};
}

async function detailOf(resp) {
  try {
    const body = await resp.json();
    if (typeof body.detail === "string") return body.detail;
    if (Array.isArray(body.detail)) {
      // FastAPI's own 422 list: "loc: msg" per problem
      return body.detail.map((d) => `${(d.loc || []).slice(1).join(".")}: ${d.msg}`).join("; ");
    }
    return JSON.stringify(body);
  } catch {
    return `${resp.status} ${resp.statusText}`;
  }
}

/** fetch() against the API; throws ApiError with the API's message on a non-2xx answer. */
export async function api(path, { method = "GET", as = "json", headers = {}, body } = {}) {
  let resp;
  try {
    resp = await fetch(path, { method, body, headers: { ...authHeaders(), ...headers } });
  } catch (e) {
    throw new ApiError(0, `the server did not answer (${e.message}); is it running?`);
  }
  if (!resp.ok) throw new ApiError(resp.status, await detailOf(resp));
  if (as === "json") return resp.json();
  if (as === "text") return resp.text();
  if (as === "blob") return resp.blob();
  return resp.arrayBuffer();
}

/**
 * POST /reconstructions with upload progress (XMLHttpRequest: fetch has no upload progress).
 * The Idempotency-Key makes a retry after a dropped connection safe: the server answers the
 * same job instead of queueing a second one.
 */
export function upload(form, idempotencyKey, onProgress) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", "/reconstructions");
    for (const [k, v] of Object.entries(authHeaders())) xhr.setRequestHeader(k, v);
    xhr.setRequestHeader("Idempotency-Key", idempotencyKey);
    xhr.upload.onprogress = (e) => e.lengthComputable && onProgress(e.loaded / e.total);
    xhr.onerror = () => reject(new ApiError(0, "the connection dropped during the upload"));
    xhr.onabort = () => reject(new ApiError(0, "the upload was stopped"));
    xhr.onload = () => {
      let body = null;
      try {
        body = JSON.parse(xhr.responseText);
      } catch {
        /* not JSON: a proxy's page */
      }
      if (xhr.status >= 200 && xhr.status < 300) resolve(body);
      else reject(new ApiError(xhr.status, body && typeof body.detail === "string" ? body.detail : `${xhr.status} ${xhr.statusText}`));
    };
    xhr.send(form);
  });
}
