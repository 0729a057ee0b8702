// api.js - talking to arbord (docs/API.md). Every failure becomes an
// ApiError whose .words is a sentence for a person: what was asked, the
// daemon's error code and its message, never swallowed. Requests that change
// the daemon's state carry the bearer token the user gave (token.js), if any.

export class ApiError extends Error {
    constructor(what, status, code, message, extra = {}) {
        const words = describe(what, status, code, message);
        super(words);
        this.what = what;
        this.status = status;
        this.code = code;
        this.daemonMessage = message;
        this.words = words;
        Object.assign(this, extra);
    }
}

const CODE_WORDS = {
    bad_request: 'the request was not valid',
    unauthorized: 'this daemon needs its bearer token (it was started with --token-file)',
    forbidden: 'the daemon does not allow changes from here',
    not_found: 'not found',
    method_not_allowed: 'the daemon does not take that method here',
    conflict: 'the name is already taken',
    superseded: 'a newer frame replaced it',
    too_large: 'too large for the daemon',
    unsupported_media_type: 'the file is neither OBJ nor PLY nor gzip',
    busy: 'the daemon is busy',
    timeout: 'it took longer than the daemon allows',
    insufficient_memory: 'not enough memory on the daemon',
    insufficient_storage: 'the daemon could not save the file in its models folder',
    not_implemented: 'the daemon does not do this yet',
    internal: 'the daemon hit an internal error',
};

function describe(what, status, code, message) {
    if (status === 0) return `${what} failed: the daemon could not be reached (${message || 'network error'}).`;
    const gist = CODE_WORDS[code] || `HTTP ${status}`;
    const detail = message ? `: ${message}` : '';
    return `${what} failed — ${gist}${detail} (${status}${code ? ' ' + code : ''}).`;
}

/** Parses an error answer (JSON {"error":{code,message}} or anything else). */
export async function errorFrom(what, res) {
    let code = '', message = '';
    const text = await res.text().catch(() => '');
    try {
        const j = JSON.parse(text);
        if (j && j.error) {
            code = j.error.code || '';
            message = j.error.message || '';
        }
    } catch {
        message = text.trim().slice(0, 300);
    }
    if (!message && !code) message = res.statusText || '';
    return new ApiError(what, res.status, code, message, { retryAfter: Number(res.headers.get('Retry-After')) || 0 });
}

export function errorFromText(what, status, text) {
    let code = '', message = '';
    try {
        const j = JSON.parse(text);
        if (j && j.error) {
            code = j.error.code || '';
            message = j.error.message || '';
        }
    } catch {
        message = (text || '').trim().slice(0, 300);
    }
    return new ApiError(what, status, code, message);
}

// The token of a daemon started with --token-file, as the user typed it: kept for this tab only.
const TOKEN_KEY = 'arbor.token';
export const savedToken = () => sessionStorage.getItem(TOKEN_KEY) || '';
export const saveToken = (token) => sessionStorage.setItem(TOKEN_KEY, token);

/** A state-changing request sent with `sent` (maybe '') was answered 401: that token is wrong. */
export function tokenRefused(sent) {
    // a token typed in while the request was on its way is not the one refused
    if (sent === savedToken()) sessionStorage.removeItem(TOKEN_KEY);
}

/** auth: the request changes state, so it carries the token; a 401 error says whether it did (tokenSent). */
async function call(what, url, init = {}, auth = false) {
    const sent = auth ? savedToken() : '';
    if (sent) init = { ...init, headers: { ...init.headers, Authorization: `Bearer ${sent}` } };
    let res;
    try {
        res = await fetch(url, init);
    } catch (e) {
        if (e.name === 'AbortError') throw e;
        throw new ApiError(what, 0, '', e.message);
    }
    if (!res.ok) {
        const err = await errorFrom(what, res);
        if (auth && res.status === 401) {
            tokenRefused(sent);
            err.tokenSent = sent !== '';
        }
        throw err;
    }
    return res;
}

/** init.signal aborts it. */
export async function getJSON(what, url, init = {}) {
    const res = await call(what, url, init);
    return res.json();
}

export async function postJSON(what, url, body, auth = false, init = {}) {
    const res = await call(what, url, {
        ...init,
        method: 'POST',
        headers: { 'Content-Type': 'application/json' },
        body: JSON.stringify(body),
    }, auth);
    return res.json();
}

export const enc = encodeURIComponent;

export const listModels = () => getJSON('Listing the models', '/api/models').then((j) => j.models || []);
/** What the daemon says of itself (GET /api/stats' daemon: its limits on one request, whether it has Embree). */
export const daemonInfo = () => getJSON("Reading the daemon's limits", '/api/stats').then((j) => j.daemon || {});
export const getModel = (name) => getJSON(`Reading model ${name}`, `/api/models/${enc(name)}`);

export function treeStats(model, accel, builder) {
    const q = `model=${enc(model)}&accel=${enc(accel)}&builder=${enc(builder)}`;
    return getJSON(`Statistics of ${accel} ${builder}`, `/api/stats?${q}`).then((j) => {
        const t = (j.trees || []).find((s) => s.model === model && s.accel === accel && s.builder === builder);
        return t || (j.trees || [])[0] || null;
    });
}

/** The boxes of a tree at a depth (kind: 'depth', 'all' or 'leaves'); init.signal aborts the request. */
export function treeBoxes(model, accel, builder, depth, kind, init = {}) {
    let q = `depth=${depth}`;
    if (kind === 'leaves') q += '&leaves=1';
    if (kind === 'all') q += '&all=1';
    return getJSON(`Reading the ${accel} ${builder} boxes at depth ${depth}`,
        `/api/models/${enc(model)}/trees/${enc(accel)}/${enc(builder)}/boxes?${q}`, init);
}

export const traceRay = (req) => postJSON(`Tracing the ray through pixel (${req.x}, ${req.y})`, '/api/ray', req);

const postRender = (what, req, init) => call(what, '/api/render', {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(req),
    ...init,
});

/** One frame: {blob, headers info}. init.signal aborts it. */
export async function renderFrame(req, init = {}) {
    const res = await postRender('Rendering the frame', req, init);
    const blob = await res.blob();
    const num = (h) => {
        const v = res.headers.get(h);
        return v === null || v === '' ? null : Number(v);
    };
    return {
        blob,
        renderMs: num('X-Render-Ms'),
        rays: num('X-Rays'),
        mrays: num('X-Mrays-Per-S'),
        heatScale: num('X-Heat-Scale'),
        timing: res.headers.get('Server-Timing') || '',
    };
}

/** A heat frame's cost per pixel (format=costs: little-endian float32s, rows top to bottom) as a Float32Array. */
export async function renderCosts(req, init = {}) {
    const res = await postRender(`Measuring the ${req.accel} ${req.builder} costs`, { ...req, mode: 'heat', format: 'costs' }, init);
    const bytes = new DataView(await res.arrayBuffer());
    const costs = new Float32Array(bytes.byteLength / 4);
    for (let i = 0; i < costs.length; i++) costs[i] = bytes.getFloat32(4 * i, true);
    return costs;
}

/** A frame's statistics (format=json); init.signal aborts it. */
export const renderJSON = (req, init = {}) =>
    postJSON('Measuring the frame', '/api/render', { ...req, format: 'json' }, false, init);

export const startBench = (body) => postJSON(`Starting the benchmark of ${body.model}`, '/api/bench', body, true);
export const getJob = (id) => getJSON(`Reading benchmark job ${id}`, `/api/jobs/${enc(id)}`);
export const cancelJob = (id) =>
    call(`Cancelling benchmark job ${id}`, `/api/jobs/${enc(id)}`, { method: 'DELETE' }, true).then((r) => r.json());
