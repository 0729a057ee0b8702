// overlay.js - what is drawn over a frame with the camera that frame used
// (camera.js, the renderer's maths): the tree's boxes, a colour per depth, and
// an inspected ray's path (the boxes it visited, the ray, its hit), and the key
// under the frames that names those colours. The tree's colours are cool and
// the path's warm with a dark casing, so that the path stands out from the
// tree it runs through; tree colours are darker on a light frame background.

import { BOX_EDGES, boxCorners, projectSegment, project, boundsFrame, add, scale, NEAR } from './camera.js';

// depth d's hue: d times the golden ratio, modulo 1, of the cool arc, so that neighbouring depths lie far apart
const GOLDEN = 0.6180339887;
const HUE_FROM = 140, HUE_SPAN = 140; // green through cyan and blue to violet: no red, orange, yellow or magenta
// more boxes than this are drawn one device pixel wide: Chromium strokes such hairlines 10 to 40 times
// faster than wider lines, which is what lets 20,000 boxes redraw while orbiting
const WIDE_BOXES = 300;
const CASING = 'rgba(0, 0, 0, 0.75)';
const EDGES = BOX_EDGES.flat();

/** A tree box's colour at `depth` (CSS); light: for a light frame background. */
function depthColour(depth, light = false) {
    const hue = HUE_FROM + ((depth * GOLDEN) % 1) * HUE_SPAN;
    return `hsl(${Math.round(hue)}, 80%, ${light ? 30 : 64}%)`;
}

/** The parts of a ray's path, as drawn and as the key names them. */
const RAY_PARTS = {
    inner: { colour: '#ffc53d', label: 'inner box entered' },
    leaf: { colour: '#ff5b2e', label: 'leaf, triangles tested' },
    empty: { colour: '#ff5b2e', dash: [4, 3], label: 'empty leaf' },
    ray: { colour: '#ffffff', label: 'the ray (a line once the view turns)' },
    hit: { colour: '#ffffff', label: 'hit point' },
    miss: { colour: '#a0a8b8', label: 'no hit' },
};

/**
 * The projection of frame camera `cam` onto a canvas of w x h pixels showing
 * that frame scaled: camera.js's cameraToImage with its constants taken once.
 */
export function canvasView(cam, w, h) {
    const aspect = cam.width / cam.height;
    return { cam, w, h, sx: w / cam.width, sy: h / cam.height, kx: (0.5 * w) / (cam.tanHalfFov * aspect), ky: (0.5 * h) / cam.tanHalfFov };
}

const CULL_MARGIN = 8; // canvas pixels
// a box's corners in camera space (x, y, z) and on the canvas (x, y): reused for every box
const Q = new Float64Array(24), P = new Float64Array(16);

/**
 * Adds box b's twelve edges to `path`: its eight corners projected once each,
 * nothing for a box wholly off the canvas; a box reaching behind the eye has
 * each edge clipped by camera.js's projectSegment.
 */
function addBox(path, v, b) {
    const { eye, right: r, up: u, forward: f } = v.cam, lo = b.min, hi = b.max;
    let zmin = Infinity, zmax = -Infinity, zabs = 0;
    for (let i = 0; i < 8; i++) {
        const x = (i & 1 ? hi[0] : lo[0]) - eye[0], y = (i & 2 ? hi[1] : lo[1]) - eye[1], z = (i & 4 ? hi[2] : lo[2]) - eye[2];
        const qz = x * f[0] + y * f[1] + z * f[2];
        Q[3 * i] = x * r[0] + y * r[1] + z * r[2];
        Q[3 * i + 1] = x * u[0] + y * u[1] + z * u[2];
        Q[3 * i + 2] = qz;
        zmin = Math.min(zmin, qz);
        zmax = Math.max(zmax, qz);
        zabs = Math.max(zabs, Math.abs(qz));
    }
    if (zmax <= 0) return; // wholly behind the eye: every edge would be clipped away
    // projectSegment's near plane for any edge of the box: at or past it, no edge is clipped
    if (zmin < NEAR * (1 + 2 * zabs)) {
        const k = boxCorners(b);
        for (let e = 0; e < EDGES.length; e += 2) {
            const s = projectSegment(v.cam, k[EDGES[e]], k[EDGES[e + 1]]);
            if (!s) continue;
            path.moveTo(s[0][0] * v.sx, s[0][1] * v.sy);
            path.lineTo(s[1][0] * v.sx, s[1][1] * v.sy);
        }
        return;
    }
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (let i = 0; i < 8; i++) {
        const z = Q[3 * i + 2];
        const x = 0.5 * v.w + (v.kx * Q[3 * i]) / z, y = 0.5 * v.h - (v.ky * Q[3 * i + 1]) / z;
        P[2 * i] = x;
        P[2 * i + 1] = y;
        x0 = Math.min(x0, x); x1 = Math.max(x1, x);
        y0 = Math.min(y0, y); y1 = Math.max(y1, y);
    }
    // off the canvas by more than the widest stroke's half (a cased ray line at 2 device pixels per CSS pixel)
    if (x1 < -CULL_MARGIN || y1 < -CULL_MARGIN || x0 > v.w + CULL_MARGIN || y0 > v.h + CULL_MARGIN) return;
    // the twelve edges as the two faces of constant z, closed, and the four edges between them: fewer path calls
    for (const z of [0, 8]) {
        path.moveTo(P[z], P[z + 1]);
        path.lineTo(P[z + 2], P[z + 3]);
        path.lineTo(P[z + 6], P[z + 7]);
        path.lineTo(P[z + 4], P[z + 5]);
        path.lineTo(P[z], P[z + 1]);
    }
    for (let i = 0; i < 8; i += 2) {
        path.moveTo(P[i], P[i + 1]);
        path.lineTo(P[i + 8], P[i + 9]);
    }
}

/**
 * Strokes `paths` (a Path2D or null for each of `layers`, in drawing order);
 * a layer is {colour, width, alpha, dash, casing}. The casings, a dark line
 * under a layer's own, go first, so that none cuts through another's lines.
 */
function strokeLayers(ctx, layers, paths) {
    for (const pass of ['casing', 'colour']) {
        layers.forEach((l, i) => {
            if (!paths[i] || (pass === 'casing' && !l.casing)) return;
            // round ends close a cased box's corners; hairlines keep the default, their fast path
            ctx.lineCap = l.casing ? 'round' : 'butt';
            ctx.globalAlpha = l.alpha ?? 1;
            ctx.setLineDash(pass === 'colour' && l.dash ? l.dash.map((d) => d * l.width) : []);
            ctx.strokeStyle = pass === 'casing' ? CASING : l.colour;
            ctx.lineWidth = pass === 'casing' ? l.width + l.casing : l.width;
            ctx.stroke(paths[i]);
        });
    }
    ctx.globalAlpha = 1;
    ctx.setLineDash([]);
}

/** Adds `boxes` to one path per layer: layerOf(box) is the index of its layer, or -1 for none. */
function boxPaths(v, boxes, layerCount, layerOf) {
    const paths = new Array(layerCount).fill(null);
    for (const b of boxes) {
        const k = layerOf(b);
        if (k >= 0) addBox(paths[k] ??= new Path2D(), v, b);
    }
    return paths;
}

const depthsOf = new WeakMap(); // boxes answer -> its depths: asked for at every redraw of the panels

/** The depths of a boxes answer's boxes (a box without one is at the depth asked), shallowest first. */
export function treeDepths(data) {
    let depths = depthsOf.get(data);
    if (!depths) {
        const seen = new Set();
        for (const b of data.boxes || []) seen.add(b.depth ?? data.depth);
        depths = [...seen].sort((a, b) => a - b);
        depthsOf.set(data, depths);
    }
    return depths;
}

/** Whether drawTree draws a boxes answer's boxes cased: over a heat frame, when few enough to draw wide. */
export const boxesCased = (data, heat) => heat && (data.boxes || []).length <= WIDE_BOXES;

/**
 * Draws a boxes answer's boxes, a colour per depth, the deepest first so that
 * the few large boxes of the top levels stay visible over the many small
 * ones; fainter under a ray's path, which is about the boxes it visited.
 * Over a heat frame, whose own blues, cyans and greens are the tree's
 * colours, a box has a dark casing, as the path's lines do (hairlines, past
 * WIDE_BOXES boxes, go without: they must stay fast).
 */
function drawTree(ctx, v, data, { dpr, light, heat, underRay }) {
    const list = data.boxes || [];
    const depths = treeDepths(data).slice().reverse();
    const alpha = (list.length > 2000 ? 0.55 : list.length > 200 ? 0.75 : 0.95) * (underRay ? 0.4 : 1);
    const wide = list.length <= WIDE_BOXES;
    const width = wide ? Math.max(1, dpr) : 1, casing = boxesCased(data, heat) ? 2 * dpr : 0;
    const layers = depths.map((d) => ({ colour: depthColour(d, light), alpha, width: d === 0 ? 2 * dpr : width, casing }));
    const layerOf = new Map(depths.map((d, i) => [d, i]));
    strokeLayers(ctx, layers, boxPaths(v, list, layers.length, (b) => layerOf.get(b.depth ?? data.depth)));
}

/**
 * Draws a pane's overlay content ({boxes, ray}: Pane.overlayContent) through
 * view v: on the page's overlay canvas, and over a saved frame (save.js);
 * heat: the frame is a heat frame.
 */
export function drawContent(ctx, v, { boxes, ray }, { dpr, light, heat, bounds }) {
    if (boxes) drawTree(ctx, v, boxes.data, { dpr, light, heat, underRay: !!ray });
    if (ray) drawRay(ctx, v, ray, bounds, dpr);
}

/** A ray step's box as {min, max, leaf, tris} (steps carry it as {box: {min, max}}, API.md; a flat one is taken too). */
const stepBoxes = (data) => (data.steps || []).map((s) => ({ ...s, ...(s.box || {}) }))
    .filter((s) => Array.isArray(s.min) && Array.isArray(s.max));

/** The part of RAY_PARTS that ray step s is: 'inner', 'leaf' or 'empty'. */
const stepPart = (s) => (!s.leaf ? 'inner' : s.tris > 0 ? 'leaf' : 'empty');

/** Which of RAY_PARTS a ray's path shows, in the key's order. */
export function rayParts(data) {
    const steps = new Set(stepBoxes(data).map(stepPart));
    return [...['inner', 'leaf', 'empty'].filter((k) => steps.has(k)), ...(data.ray ? ['ray'] : []), data.hit ? 'hit' : 'miss'];
}

/**
 * Draws ray `r` ({req, data} of POST /api/ray) over the frame: the boxes it
 * visited, the ray from its origin to the hit (past the model for a miss),
 * which the traced view sees end on, and a ring at the hit (for a miss, at
 * the model's distance along the ray: the pixel, in the traced view).
 */
function drawRay(ctx, v, r, bounds, dpr) {
    const order = ['inner', 'empty', 'leaf', 'ray'];
    const layers = order.map((k) => ({
        colour: RAY_PARTS[k].colour, dash: RAY_PARTS[k].dash, casing: 2 * dpr, width: (k === 'inner' || k === 'ray' ? 1.5 : 2) * dpr,
    }));
    const paths = boxPaths(v, stepBoxes(r.data), layers.length, (s) => order.indexOf(stepPart(s)));
    const { origin, dir } = r.data.ray || {};
    const hit = r.data.hit;
    let end = hit ? hit.point : null;
    if (origin && dir) {
        const { centre, diagonal } = boundsFrame(bounds);
        const along = Math.hypot(...centre.map((c, i) => c - origin[i]));
        end = end || add(origin, scale(dir, along));
        const s = projectSegment(v.cam, origin, hit ? end : add(origin, scale(dir, along + diagonal)));
        if (s) {
            const line = (paths[order.indexOf('ray')] = new Path2D());
            line.moveTo(s[0][0] * v.sx, s[0][1] * v.sy);
            line.lineTo(s[1][0] * v.sx, s[1][1] * v.sy);
        }
    }
    strokeLayers(ctx, layers, paths);
    const p = end ? project(v.cam, end) : [r.req.x + 0.5, r.req.y + 0.5];
    if (p) drawMarker(ctx, [p[0] * v.sx, p[1] * v.sy], dpr, RAY_PARTS[hit ? 'hit' : 'miss'].colour);
}

/** A cross-hair with a ring at canvas point p, its size in CSS pixels whatever the frame's resolution. */
function drawMarker(ctx, p, dpr, colour) {
    const [x, y] = p, r = 7 * dpr;
    const path = new Path2D();
    path.moveTo(x + r, y);
    path.arc(x, y, r, 0, Math.PI * 2);
    path.moveTo(x - 2 * r, y); path.lineTo(x - r, y);
    path.moveTo(x + r, y); path.lineTo(x + 2 * r, y);
    path.moveTo(x, y - 2 * r); path.lineTo(x, y - r);
    path.moveTo(x, y + r); path.lineTo(x, y + 2 * r);
    strokeLayers(ctx, [{ colour, width: 2 * dpr, casing: 2 * dpr }], [path]);
}

const keyShown = new WeakMap(); // element -> the HTML it holds: rebuilt only for another key

/**
 * The key under the frames: the colours of the depths drawn (`depths`) and of
 * the ray's parts drawn (`parts`, RAY_PARTS' names); hidden when neither is.
 * Swatches take the colours the overlay strokes with, and the boxes' casing
 * when `casedBoxes` (boxesCased); the labels are the page's own words
 * (RAY_PARTS), no HTML to escape.
 */
export function renderKey(el, depths, parts, light, casedBoxes = false) {
    const item = (attr, cls, colour, text) =>
        `<li class="key-item" ${attr}><span class="key-swatch ${cls}" style="border-color:${colour}" aria-hidden="true"></span>${text}</li>`;
    let html = '';
    if (depths.length) {
        html += `<div class="key-row" id="key-depths"><span class="key-title" id="key-depths-title">Boxes by depth</span>` +
            `<ul aria-labelledby="key-depths-title">${depths.map((d) => item(`data-depth="${d}"`, casedBoxes ? 'cased' : '', depthColour(d, light), d)).join('')}</ul></div>`;
    }
    if (parts.length) {
        const shape = (k) => ['cased', RAY_PARTS[k].dash ? 'dashed' : '', k === 'ray' ? 'line' : k === 'hit' || k === 'miss' ? 'ring' : ''].join(' ');
        html += `<div class="key-row" id="key-ray"><span class="key-title" id="key-ray-title">Ray's path</span>` +
            `<ul aria-labelledby="key-ray-title">${parts.map((k) => item(`data-part="${k}"`, shape(k), RAY_PARTS[k].colour, RAY_PARTS[k].label)).join('')}</ul></div>`;
    }
    el.hidden = !html;
    if (keyShown.get(el) === html) return;
    keyShown.set(el, html);
    el.innerHTML = html;
}
