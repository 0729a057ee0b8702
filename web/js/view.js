// view.js - one frame pane: a canvas with arbord's frames, an overlay canvas
// for tree boxes and the inspected ray, and the frame loop. While the view
// moves the pane asks for quick frames (a fraction of the resolution, 1 spp);
// at rest, for the full frame, as horizontal strips (`region`) drawn as each
// arrives, asked for no more at once than the daemon renders at a time
// (slots.js), so that the first strips come early rather than all together
// (the strips are the whole frame's pixels, bit for bit). An expensive full
// frame is preceded by a quick frame of its view, which the strips replace.
// A frame of another tree or mode than the pane's is dimmed and named as
// such until the pane's own arrives. Heat frames stay whole (their
// colours scale to the whole frame's 99th percentile; in split view to the
// larger of both panes', so one colour is one cost) unless the daemon's
// budget of samples per request (--max-pixels) splits them too. Never more
// than one frame in flight: a quick frame is awaited, a full frame the view
// no longer wants is aborted and superseded on the daemon by the next frame
// with the same `stream` key (the pane's, one per strip).

import * as api from './api.js';
import { cameraFromRequest, requestCamera } from './camera.js';
import { canvasView, drawContent } from './overlay.js';
import { treeLabel } from './panels.js';

const QUICK_PIXELS = 80000;
const STRIP_ROWS = 128;
// strips of a full frame (more only when the daemon's samples per request need it): enough to watch it fill in
const MAX_STRIPS = 8;
// a full frame costing more samples than this (the default 640x480 at 4 spp costs 1.2 M) is previewed by a quick frame
const PREVIEW_SAMPLES = 2 ** 21;
// the daemon's default ao_samples (API.md), part of an ao frame's cost
const AO_SAMPLES = 8;
// a failed frame, tree statistics or boxes that may succeed later (the daemon was away or busy) are asked again after this
const RETRY_MS = 2000;

/** Samples one row of a frame costs on the daemon: width x spp (x ao_samples in ao mode), as --max-pixels counts. */
export function rowSamples(req) {
    return req.width * req.spp * (req.mode === 'ao' ? req.ao_samples ?? AO_SAMPLES : 1);
}

/** Samples a whole frame costs (rowSamples per row). */
const frameSamples = (req) => rowSamples(req) * req.height;

/** Whether two render requests show the same view: model, tree, mode, size and camera (their samples may differ). */
const sameView = (a, b) => ['model', 'accel', 'builder', 'mode', 'width', 'height'].every((k) => a[k] === b[k])
    && JSON.stringify(a.camera) === JSON.stringify(b.camera);

/** A failure worth asking again for later: the daemon unreachable, busy or failing for now. */
const transient = (e) => e.status === 0 || e.status >= 500;

/**
 * The regions of a full frame: horizontal strips of about STRIP_ROWS rows, at
 * most MAX_STRIPS, or more when a strip would cost more than maxSamples
 * (rowCost per row); null when a single row already does.
 */
export function stripRegions(w, h, rowCost = 0, maxSamples = Infinity) {
    const rows = Math.floor(maxSamples / rowCost);
    if (rows < 1) return null;
    const n = Math.max(1, Math.min(MAX_STRIPS, Math.round(h / STRIP_ROWS)), Math.ceil(h / rows));
    const out = [];
    for (let i = 0; i < n; i++) {
        const y0 = Math.floor((h * i) / n), y1 = Math.floor((h * (i + 1)) / n);
        out.push({ x: 0, y: y0, w, h: y1 - y0 });
    }
    return out;
}

/** Power-of-two divisor giving a quick frame of at most QUICK_PIXELS pixels (at least 2). */
export function quickDivisor(w, h) {
    let q = 2;
    while ((w / q) * (h / q) > QUICK_PIXELS && q < 16) q *= 2;
    return q;
}

let paneCounter = 0;

export class Pane {
    constructor(app, index) {
        this.app = app;
        this.index = index;
        this.stream = `view-${index}-${Math.random().toString(36).slice(2, 10)}-${++paneCounter}`;
        this.inflight = null;      // {key, quick, controller}
        // renderMs, mrays: over the browser's wall time; daemonMs, daemonMrays: over the daemon's render time (fetchFrame)
        this.shown = null;         // {key, quick, req, cam (basis), heatScale, renderMs, mrays, daemonMs, daemonMrays, rays}
        this.lastFull = null;      // {key, blob, req}: the last full frame; its blob comes later for a frame in strips
        this.error = null;
        this.stats = null;         // STATS | {error, at}
        this.statsKey = '';
        this.statsNotice = null;   // the notice of a failed build, removed once the statistics come
        this.building = null;      // {key, start, timer}
        this.boxes = null;         // {key, data} | {key, error}
        this.boxesLoading = '';
        this.boxesAbort = null;    // the AbortController of the boxes being loaded
        this.retryTimer = 0;
        this.overlayDrawn = null;  // {camera, boxes, ray} the overlay shows: drawOverlay skips redrawing them
        this.ray = null;           // {req, data, heat}
        this.heat = null;          // {key (scaleKey), scale}: the last full heat frame's X-Heat-Scale
        this.frameTimes = [];      // arrival times of quick frames while moving (FPS)
        this.fps = null;
        this.buildDoneKeys = new Set();
        this.el = this.makeDom();
    }

    makeDom() {
        const el = document.createElement('div');
        el.className = 'pane';
        // the frame is an application, not an image, to assistive technology: it takes arrow keys, +/- and Enter itself
        el.innerHTML = `
          <div class="pane-title"><strong class="tree-name"></strong><span class="frame-info"></span></div>
          <div class="frame" id="frame-${this.index}" tabindex="0" role="application" aria-describedby="hint">
            <canvas class="image" width="640" height="480"></canvas>
            <canvas class="overlay" width="640" height="480" aria-hidden="true"></canvas>
            <span class="badge building" hidden></span>
            <span class="badge quality" hidden></span>
            <span class="badge stale" hidden></span>
            <span class="badge error" role="alert" hidden></span>
          </div>`;
        this.frame = el.querySelector('.frame');
        this.canvas = el.querySelector('canvas.image');
        this.overlay = el.querySelector('canvas.overlay');
        this.badgeBuilding = el.querySelector('.badge.building');
        this.badgeQuality = el.querySelector('.badge.quality');
        this.badgeStale = el.querySelector('.badge.stale');
        this.badgeError = el.querySelector('.badge.error');
        this.titleName = el.querySelector('.tree-name');
        this.titleInfo = el.querySelector('.frame-info');
        this.canvas.dataset.pane = String(this.index);
        new ResizeObserver(() => this.app.scheduleDraw()).observe(this.frame);
        return el;
    }

    tree() {
        return this.app.treeOf(this.index);
    }

    /** The tree's model, kind and builder; the model's version too, so a model replaced under the same name is another. */
    treeKey() {
        const t = this.tree(), model = this.app.model();
        return `${this.app.state.model}@${model ? model.version : ''}/${t.accel}/${t.builder}`;
    }

    /** What the pane's heat colours depend on: its tree, and in split view every pane's (they share one scale). */
    scaleKey() {
        const app = this.app;
        return app.panes.length > 1 && app.state.mode === 'heat' ? app.panes.map((p) => p.treeKey()).join(' ') : this.treeKey();
    }

    /** What identifies a frame: its request, and what its heat colours depend on. */
    frameKey(req) {
        return `${this.scaleKey()} ${JSON.stringify(req)}`;
    }

    /** The render request for the current view; quick: the moving-view frame. */
    request(quick) {
        const s = this.app.state, t = this.tree(), model = this.app.model();
        const [W, H] = s.res;
        const q = quick ? quickDivisor(W, H) : 1;
        const req = {
            model: s.model,
            accel: t.accel,
            builder: t.builder,
            mode: s.mode,
            width: Math.max(1, Math.round(W / q)),
            height: Math.max(1, Math.round(H / q)),
            spp: quick ? 1 : s.spp,
            camera: requestCamera(model.bounds, s.view),
            background: this.app.background(),
        };
        if (quick && s.mode === 'ao') req.ao_samples = 2;
        // quick heat frames keep the last full frame's colour scale, so colours hold still while orbiting
        if (quick && s.mode === 'heat' && this.heat && this.heat.key === this.scaleKey() && this.heat.scale > 0) {
            req.heat_scale = this.heat.scale;
        }
        return req;
    }

    setAspect() {
        const [W, H] = this.app.state.res;
        this.frame.style.aspectRatio = `${W} / ${H}`;
        this.app.viewportAspect(W / H);
    }

    /** Forgets what the pane shows and knows of the model: another model was chosen, or this one replaced. */
    clearModel() {
        if (this.inflight) this.inflight.controller.abort();
        this.inflight = null;
        this.stopBuilding();
        this.shown = null;
        this.lastFull = null;
        this.heat = null;
        this.stats = null;
        this.statsKey = '';
        this.boxes = null;
        this.cancelBoxes();
        this.clearError();
        this.canvas.getContext('2d').clearRect(0, 0, this.canvas.width, this.canvas.height);
        delete this.canvas.dataset.frame;
        delete this.canvas.dataset.camera;
        this.badgeQuality.hidden = true;
        this.markStale();
        this.app.scheduleDraw();
    }

    /** The frame shown is of another tree or mode than the pane's: its own is still to come. */
    frameIsStale() {
        const s = this.shown, t = this.tree();
        return !!s && (s.req.accel !== t.accel || s.req.builder !== t.builder || s.req.mode !== this.app.state.mode);
    }

    /**
     * Dims a stale frame with what is coming over it, and names the frame
     * shown in the pane's title: the title's tree is the one chosen, and the
     * image, its numbers and legend stay the old tree's until the new frame.
     */
    markStale() {
        const s = this.shown, stale = this.frameIsStale();
        this.frame.classList.toggle('stale', stale);
        this.badgeStale.hidden = !stale;
        if (stale) {
            const mode = this.app.state.mode;
            this.badgeStale.textContent = `${this.building ? 'building' : 'rendering'} ${treeLabel(this.tree())}` +
                `${s.req.mode !== mode ? ` · ${mode}` : ''}…`;
        }
        this.titleInfo.textContent = !s ? '' : `${stale ? `${treeLabel(s.req)} · ${s.req.mode} frame · ` : ''}` +
            `${s.req.width}×${s.req.height} · ${s.req.spp} spp${s.quick ? ' (quick)' : ''}`;
    }

    /**
     * Whether the pane shows the whole full frame of the current view (what
     * Save PNG may save): the last full frame is of this view and on screen,
     * not a quick frame of another (a reset before the orbit's frames came).
     */
    complete() {
        const f = this.lastFull;
        return !!(f && f.blob && this.app.model() && !this.building && f.key === this.frameKey(this.request(false)) &&
            this.shown && this.shown.key === f.key);
    }

    /**
     * Whether the full frame `full` should be preceded by a quick frame of its
     * view: it is expensive, and neither that quick frame nor a full frame of
     * the same view (at other samples) is shown.
     */
    wantsPreview(full) {
        if (frameSamples(full) < PREVIEW_SAMPLES) return false;
        const s = this.error ? null : this.shown;
        return !(s && (s.key === this.frameKey(this.request(true)) || (!s.quick && sameView(s.req, full))));
    }

    /** Asks for whatever frame the view wants now, if it can. */
    pump() {
        const app = this.app;
        const model = app.model();
        if (!model) return;
        const t = this.tree();
        this.titleName.textContent = `${treeLabel(t)} · ${app.state.mode}`;
        this.frame.setAttribute('aria-label',
            `Frame of ${app.state.model}, ${t.accel} ${t.builder} tree, ${app.state.mode} mode. ` +
            'Its controls are described below it.');
        this.ensureTree();
        this.markStale();
        // building this tree: its frame waits; frames of a hidden viewer would compete with a benchmark
        if (this.building || app.state.tab !== 'view') return;
        const full = this.request(false);
        const quick = app.moving || this.wantsPreview(full);
        const req = quick ? this.request(true) : full;
        const key = this.frameKey(req);
        if (this.inflight) {
            if (this.inflight.key === key) return;
            if (!this.inflight.quick) {
                // the full frame is no longer wanted: drop it; the next frame with
                // this stream key supersedes it on the daemon
                this.inflight.controller.abort();
                this.inflight = null;
            } else {
                return; // a quick frame: wait for it, then ask again
            }
        }
        if (this.shown && this.shown.key === key && !this.error) return;
        if (this.error && this.error.key === key && !this.error.retry) return;
        this.send(req, key, quick);
    }

    /** The regions to ask a frame as (null: whole), within the daemon's samples per request; null if it cannot be. */
    regionsOf(req, quick) {
        const budget = this.app.maxSamples, perRow = rowSamples(req);
        if ((quick || req.mode === 'heat') && perRow * req.height <= budget) return [null];
        return stripRegions(req.width, req.height, perRow, budget);
    }

    async send(req, key, quick) {
        const controller = new AbortController();
        const flight = { key, quick, controller };
        this.inflight = flight;
        const regions = this.regionsOf(req, quick);
        if (!regions) {
            this.inflight = null;
            this.showError(key, { words: `A ${req.width}×${req.height} frame at ${req.spp} spp${req.mode === 'ao' ? ` with ${AO_SAMPLES} occlusion samples` : ''} ` +
                `costs more than this daemon renders in one request, even one row at a time (--max-pixels ${this.app.maxSamples.toLocaleString('en-US')} samples): ` +
                'choose fewer samples per pixel or a smaller resolution.' });
            this.app.panesChanged();
            return;
        }
        this.showProgress(req, quick, 0, regions.length);
        let frame;
        try {
            frame = await this.fetchFrame(req, regions, flight);
        } catch (e) {
            controller.abort();
            if (this.inflight === flight) this.inflight = null;
            if (e.name === 'AbortError' || this.inflight) return;
            if (e.code === 'superseded') { this.pump(); return; }
            // a daemon started with a smaller --max-pixels than assumed says its limit: split by it
            const limit = e.status === 400 && /over the limit of (\d+)/.exec(e.daemonMessage || '');
            if (limit && Number(limit[1]) < this.app.maxSamples) {
                this.app.setMaxSamples(Number(limit[1]));
                return;
            }
            this.showError(key, e);
            if (transient(e)) {
                const wait = Math.min(5000, Math.max(200, e.retryAfter ? e.retryAfter * 1000 : RETRY_MS));
                setTimeout(() => { if (this.error && this.error.key === key) { this.error.retry = true; this.pump(); } }, wait);
            }
            this.app.panesChanged();
            return;
        }
        if (this.inflight !== flight) return;
        this.inflight = null;
        this.clearError();
        const [W, H] = this.app.state.res;
        const model = this.app.model();
        const perMs = (ms) => (ms > 0 && frame.rays !== null ? frame.rays / ms / 1e3 : null);
        this.shown = {
            key, quick, req,
            cam: cameraFromRequest(model.bounds, req.camera, W, H),
            heatScale: frame.heatScale,
            renderMs: frame.wallMs,
            mrays: perMs(frame.wallMs),
            daemonMs: frame.daemonMs,
            daemonMrays: perMs(frame.daemonMs),
            rays: frame.rays,
        };
        this.canvas.dataset.frame = quick ? 'quick' : 'full';
        this.canvas.dataset.camera = JSON.stringify(req.camera);
        if (!quick) {
            const full = { key, blob: frame.blob, req };
            this.lastFull = full;
            if (!frame.blob) {
                this.canvas.toBlob((b) => {
                    full.blob = b;
                    this.app.panesChanged();
                });
            }
            if (req.mode === 'heat' && frame.heatScale > 0) this.heat = { key: this.scaleKey(), scale: frame.heatScale };
        }
        const now = performance.now();
        if (quick) {
            this.frameTimes.push(now);
            while (this.frameTimes.length && now - this.frameTimes[0] > 1000) this.frameTimes.shift();
            const span = this.frameTimes.length > 1 ? now - this.frameTimes[0] : 0;
            this.fps = span > 0 ? ((this.frameTimes.length - 1) * 1000) / span : this.fps;
        } else {
            this.frameTimes = [];
        }
        this.badgeQuality.hidden = true;
        this.markStale();
        this.app.panesChanged();
        this.pump();
    }

    /** The rendering badge: the frame asked for and, for one in strips, how many of them have come. */
    showProgress(req, quick, done, total) {
        const [W, H] = this.app.state.res, spp = this.app.state.spp;
        this.badgeQuality.hidden = false;
        this.badgeQuality.textContent = this.app.moving ? 'moving: quick frame'
            : quick ? `quick preview, then ${W}×${H} at ${spp} spp…`
                : `rendering ${req.width}×${req.height}, ${req.spp} spp…${total > 1 ? ` ${done} of ${total} strips` : ''}`;
    }

    /**
     * Asks for the frame's regions (null: the whole frame, scaled to the
     * canvas) through the app's slots, and draws each as it arrives; the
     * canvas takes the frame's size and aspect with the first. Resolves to
     * the frame's totals: wallMs, from the first request of the frame's
     * regions to the last answer (what the browser waited, queueing included;
     * not the heat scale's renders before them); daemonMs, the daemon's
     * render times (X-Render-Ms) summed over the requests: each renders on
     * one worker, so this is the frame's cost however its strips were queued
     * or spread; the rays; the PNG of a whole frame. A heat frame in strips
     * is coloured to one scale: the 99th percentile of the same view at 1
     * spp, asked for first; a full heat frame in split view to the larger of
     * both panes' such scales, so that a colour is the same cost in each.
     */
    async fetchFrame(req, regions, flight) {
        const [W, H] = this.app.state.res;
        const { signal } = flight.controller;
        let heatScale = null;
        const shared = this.app.panes.length > 1 && !flight.quick;
        if (req.mode === 'heat' && (regions[0] || shared) && !req.heat_scale) {
            const views = shared ? this.app.panes.map((p) => p.request(false)) : [req];
            heatScale = await this.app.heatScale(views, signal);
            req = { ...req, heat_scale: heatScale };
        }
        // the clock starts after the scale's renders: not this frame's (in split view both panes' would count in each)
        const start = performance.now();
        let done = 0;
        const part = async (region, i) => {
            const body = region ? { ...req, region, stream: `${this.stream}/${i}` } : { ...req, stream: this.stream };
            const got = await this.app.slots.run(this, () => api.renderFrame(body, { signal }), signal);
            let bitmap;
            try {
                bitmap = await createImageBitmap(got.blob);
            } catch (e) {
                throw new api.ApiError('Decoding the frame', 200, '', e.message);
            }
            if (this.inflight !== flight) { bitmap.close(); return got; }
            if (this.canvas.width !== W || this.canvas.height !== H) {
                this.canvas.width = W;
                this.canvas.height = H;
                this.setAspect();
            }
            const ctx = this.canvas.getContext('2d');
            ctx.imageSmoothingEnabled = true;
            ctx.imageSmoothingQuality = flight.quick ? 'low' : 'high';
            if (region) ctx.drawImage(bitmap, region.x, region.y);
            else ctx.drawImage(bitmap, 0, 0, W, H);
            bitmap.close();
            this.showProgress(req, flight.quick, ++done, regions.length);
            return got;
        };
        const parts = await Promise.all(regions.map(part));
        const sum = (k) => parts.reduce((a, p) => (p[k] === null || a === null ? null : a + p[k]), 0);
        const whole = parts.length === 1;
        return {
            blob: whole ? parts[0].blob : null,
            heatScale: whole ? parts[0].heatScale : heatScale,
            wallMs: performance.now() - start,
            daemonMs: sum('renderMs'),
            rays: sum('rays'),
        };
    }

    showError(key, e) {
        this.error = { key, e, retry: false };
        this.badgeQuality.hidden = true;
        this.badgeError.hidden = false;
        this.badgeError.textContent = e.words || String(e.message || e);
    }

    clearError() {
        this.error = null;
        this.badgeError.hidden = true;
        this.badgeError.textContent = '';
    }

    /** Asks again for what failed for now (statistics, boxes, the frame) after RETRY_MS, unasked. */
    retryLater() {
        clearTimeout(this.retryTimer);
        this.retryTimer = setTimeout(() => {
            this.pump();
            this.loadBoxes();
        }, RETRY_MS);
    }

    /** Stops showing a build: its tree is no longer the pane's (the daemon still finishes it). */
    stopBuilding() {
        if (!this.building) return;
        clearInterval(this.building.timer);
        this.building = null;
        this.badgeBuilding.hidden = true;
    }

    /** The pane's tree's statistics came, or failed (kept with the time, to be asked again after RETRY_MS). */
    statsArrived(key, stats, error) {
        if (this.statsKey !== key) return;
        if (error) {
            this.stats = { error: error.words, at: performance.now() };
            if (transient(error)) this.retryLater();
            return;
        }
        this.stats = stats;
        if (this.statsNotice) this.statsNotice.remove();
        this.statsNotice = null;
    }

    /** Builds the pane's tree (showing "building" with the elapsed time) and fetches its statistics. */
    ensureTree() {
        const app = this.app;
        const key = this.treeKey();
        if (this.building && this.building.key === key) return;
        const failed = this.stats && this.stats.error;
        if (this.statsKey === key && !(failed && performance.now() - this.stats.at >= RETRY_MS)) return;
        this.stopBuilding();
        const t = this.tree(), name = app.state.model;
        const model = app.model();
        const entry = (model.trees || []).find((e) => e.accel === t.accel && e.builder === t.builder);
        const ready = entry && entry.state === 'ready';
        if (this.statsKey !== key) this.boxes = null;
        this.statsKey = key;
        this.stats = null;
        if (ready || this.buildDoneKeys.has(key)) {
            api.treeStats(name, t.accel, t.builder).then((s) => this.statsArrived(key, s), (e) => this.statsArrived(key, null, e))
                .finally(() => app.panesChanged());
            app.panesChanged();
            return;
        }
        const start = performance.now();
        const building = { key, start, timer: 0 };
        this.building = building;
        const tick = () => {
            const s = ((performance.now() - start) / 1000).toFixed(1);
            this.badgeBuilding.textContent = `building ${treeLabel(t)} tree of ${name}… ${s} s`;
        };
        tick();
        this.badgeBuilding.hidden = false;
        building.timer = setInterval(tick, 100);
        app.panesChanged();
        // GET /api/stats of one tree builds it if absent and answers once it is
        // built; it is open where POST .../trees needs a token (--token-file)
        api.treeStats(name, t.accel, t.builder).then((s) => {
            this.buildDoneKeys.add(key);
            this.statsArrived(key, s);
            app.refreshModel(name);
        }, (e) => {
            this.statsArrived(key, null, e);
            if (this.building === building) {
                if (this.statsNotice) this.statsNotice.remove();
                this.statsNotice = app.notify(e.words, 'error');
            }
        }).finally(() => {
            if (this.building !== building) return; // another tree's build, or none, is shown now
            this.stopBuilding();
            app.panesChanged();
            this.pump();
            app.loadBoxes();
        });
    }

    /** Drops the boxes on their way: they are no longer wanted (another depth, tree or model). */
    cancelBoxes() {
        if (this.boxesAbort) this.boxesAbort.abort();
        this.boxesAbort = null;
        this.boxesLoading = '';
    }

    /** Loads the boxes of the pane's tree for the app's box settings. */
    loadBoxes() {
        const app = this.app, b = app.state.boxes;
        if (!b.on || !app.model()) {
            this.cancelBoxes();
            this.boxes = null;
            app.scheduleDraw();
            return;
        }
        if (this.building) return; // after the build
        const t = this.tree();
        const kind = b.leaves ? 'leaves' : b.all ? 'all' : 'depth';
        const key = `${this.treeKey()}/${b.depth}/${kind}`;
        // boxes that failed are asked for again
        if ((this.boxes && this.boxes.key === key && !this.boxes.error) || this.boxesLoading === key) return;
        this.cancelBoxes();
        const controller = new AbortController();
        this.boxesAbort = controller;
        this.boxesLoading = key;
        api.treeBoxes(app.state.model, t.accel, t.builder, b.depth, kind, { signal: controller.signal }).then((data) => {
            if (this.boxesLoading !== key) return;
            this.boxes = { key, data };
        }, (e) => {
            if (this.boxesLoading !== key) return;
            this.boxes = { key, error: e };
            if (transient(e)) this.retryLater();
        }).finally(() => {
            if (this.boxesAbort !== controller) return;
            this.boxesAbort = null;
            this.boxesLoading = '';
            app.panesChanged();
        });
    }

    /**
     * What the overlay draws: the frame shown, whose camera it draws with, and
     * the pane's boxes and ray over it; nothing while the image holds strips
     * of a frame of another size (a new resolution's), which the frame
     * shown's camera does not fit.
     */
    overlayContent() {
        const s = this.shown, b = this.app.state.boxes;
        const frame = s && this.canvas.width === s.cam.width && this.canvas.height === s.cam.height ? s : null;
        return {
            frame,
            boxes: frame && b.on && this.boxes && this.boxes.data ? this.boxes : null,
            ray: frame && this.ray && this.ray.data ? this.ray : null,
        };
    }

    /**
     * Redraws boxes and the inspected ray with the camera of the frame shown
     * (from drawPanels: once per animation frame at most), unless they, the
     * frame's camera and mode, the canvas's size and the colour scheme are
     * what the overlay shows already. The canvas has a pixel per device pixel of its
     * box on the page (inside the frame's border), so lines are sharp.
     */
    drawOverlay() {
        const o = this.overlay;
        const rect = o.getBoundingClientRect();
        const dpr = window.devicePixelRatio || 1;
        const w = Math.max(1, Math.round(rect.width * dpr)), h = Math.max(1, Math.round(rect.height * dpr));
        const { frame, boxes, ray } = this.overlayContent();
        const light = !this.app.dark.matches;
        const camera = JSON.stringify([w, h, dpr, light, frame && [frame.cam.width, frame.cam.height, frame.req.camera, frame.req.mode]]);
        const drawn = this.overlayDrawn;
        if (drawn && drawn.camera === camera && drawn.boxes === boxes && drawn.ray === ray) return;
        this.overlayDrawn = { camera, boxes, ray };
        if (o.width !== w || o.height !== h) { o.width = w; o.height = h; }
        const ctx = o.getContext('2d');
        ctx.clearRect(0, 0, w, h);
        if (!frame) return;
        drawContent(ctx, canvasView(frame.cam, w, h), { boxes, ray },
            { dpr, light, heat: frame.req.mode === 'heat', bounds: this.app.model().bounds });
    }

    /** Frame pixel under a client point, or null outside. */
    pixelAt(clientX, clientY) {
        const rect = this.frame.getBoundingClientRect();
        const [W, H] = this.app.state.res;
        const x = Math.floor(((clientX - rect.left) / rect.width) * W);
        const y = Math.floor(((clientY - rect.top) / rect.height) * H);
        if (x < 0 || y < 0 || x >= W || y >= H) return null;
        return { x, y };
    }

    dispose() {
        if (this.inflight) this.inflight.controller.abort();
        this.cancelBoxes();
        this.stopBuilding();
        clearTimeout(this.retryTimer);
        this.el.remove();
    }
}
