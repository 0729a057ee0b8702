// main.js - the arbor viewer: state, URL, controls and panes.
// State lives in `app.state`; the URL mirrors it (model, tree, mode, camera,
// depth, ...) so a link reopens the same frame.

import * as api from './api.js';
import { protocolOrbit, clampPitch, requestCamera, reachTo, boundsFrame, length, viewOfNewModel } from './camera.js';
import { Pane, rowSamples } from './view.js';
import { attachControls, MIN_DISTANCE, MAX_DISTANCE } from './controls.js';
import { renderStats, renderLegend, renderRay, renderRaySummary, triangles, treeLabel } from './panels.js';
import { Compare } from './compare.js';
import { Uploader } from './upload.js';
import { CostDiff } from './diff.js';
import { Slots } from './slots.js';
import { savePanes } from './save.js';
import { renderKey, treeDepths, rayParts, boxesCased } from './overlay.js';

const ACCELS = ['bvh', 'kd'];
const BUILDERS = ['spatial', 'median', 'mean', 'sah'];
const MODES = ['shaded', 'normals', 'depth', 'ao', 'heat'];
const SPPS = [1, 4, 9, 16, 64];
const REST_MS = 180;
// the depth slider's boxes are asked for once it rests this long: dragged across depths, it asks for one depth's
const DEPTH_REST_MS = 120;
// samples a request may cost: the daemon's default --max-pixels, until GET /api/stats gives its own; a 400
// naming a smaller one (another node behind a balancer) lowers it
const MAX_SAMPLES = 16777216;
// the model list is asked for again after this while the daemon cannot give it
const LIST_RETRY_MS = 2000;
// frame requests at once until GET /api/stats says how many frames the daemon renders at a time (queue.threads)
const RENDER_SLOTS = 2;

const $ = (id) => document.getElementById(id);
const num = (v) => (v === null || v === '' || v === undefined ? NaN : Number(v));

function defaultState() {
    return {
        model: '',
        accel: 'bvh',
        builder: 'sah',
        mode: 'shaded',
        spp: 4,
        res: [640, 480],
        view: { ...protocolOrbit(), target: null },
        fly: false, // a drag turns the view about its eye (controls.js) rather than orbiting its target
        boxes: { on: false, depth: 0, all: false, leaves: false },
        split: { on: false, accel: 'kd', builder: 'sah', diff: false },
        tab: 'view',
    };
}

/** The state a URL's query asks for (unknown or bad values keep the defaults). */
export function stateFromURL(search) {
    const s = defaultState(), q = new URLSearchParams(search);
    if (q.get('model')) s.model = q.get('model');
    if (ACCELS.includes(q.get('accel'))) s.accel = q.get('accel');
    if (BUILDERS.includes(q.get('builder'))) s.builder = q.get('builder');
    if (MODES.includes(q.get('mode'))) s.mode = q.get('mode');
    if (SPPS.includes(num(q.get('spp')))) s.spp = num(q.get('spp'));
    const res = /^(\d{1,4})x(\d{1,4})$/.exec(q.get('res') || '');
    if (res) s.res = [Math.max(16, Math.min(8192, +res[1])), Math.max(16, Math.min(8192, +res[2]))];
    const v = s.view;
    if (Number.isFinite(num(q.get('yaw')))) v.yaw = num(q.get('yaw'));
    if (Number.isFinite(num(q.get('pitch')))) v.pitch = clampPitch(num(q.get('pitch')));
    if (num(q.get('dist')) > 0) v.distance = Math.min(MAX_DISTANCE, Math.max(MIN_DISTANCE, num(q.get('dist'))));
    if (num(q.get('fov')) >= 1 && num(q.get('fov')) <= 179) v.fov = num(q.get('fov'));
    const t = (q.get('target') || '').split(',').map(Number);
    if (t.length === 3 && t.every(Number.isFinite)) v.target = t;
    s.fly = q.get('cam') === 'fly';
    if (q.has('depth') && Number.isInteger(num(q.get('depth'))) && num(q.get('depth')) >= 0) {
        s.boxes.on = true;
        s.boxes.depth = num(q.get('depth'));
        s.boxes.all = q.get('boxes') === 'all';
        s.boxes.leaves = q.get('boxes') === 'leaves';
    }
    const split = /^(bvh|kd):(spatial|median|mean|sah)$/.exec(q.get('split') || '');
    if (split) s.split = { on: true, accel: split[1], builder: split[2], diff: q.get('diff') === '1' };
    if (q.get('tab') === 'compare') s.tab = 'compare';
    return s;
}

const r4 = (x) => String(Math.round(x * 1e4) / 1e4);

export function stateToURL(s) {
    const q = new URLSearchParams();
    if (s.model) q.set('model', s.model);
    q.set('accel', s.accel);
    q.set('builder', s.builder);
    q.set('mode', s.mode);
    q.set('spp', String(s.spp));
    q.set('res', `${s.res[0]}x${s.res[1]}`);
    q.set('yaw', r4(s.view.yaw));
    q.set('pitch', r4(s.view.pitch));
    q.set('dist', r4(s.view.distance));
    q.set('fov', r4(s.view.fov));
    if (s.view.target) q.set('target', s.view.target.map((x) => String(Math.round(x * 1e6) / 1e6)).join(','));
    if (s.fly) q.set('cam', 'fly');
    if (s.boxes.on) {
        q.set('depth', String(s.boxes.depth));
        if (s.boxes.all) q.set('boxes', 'all');
        if (s.boxes.leaves) q.set('boxes', 'leaves');
    }
    if (s.split.on) q.set('split', `${s.split.accel}:${s.split.builder}`);
    if (s.split.on && s.split.diff) q.set('diff', '1');
    if (s.tab === 'compare') q.set('tab', 'compare');
    return `?${q.toString()}`;
}

class App {
    constructor() {
        this.state = stateFromURL(location.search);
        // a URL camera is taken as it is; the view is pitch-clamped like the renderer's
        this.models = new Map();
        this.panes = [];
        this.moving = false;
        this.restTimer = 0;
        this.urlTimer = 0;
        this.rayInspect = null;
        this.rayShown = undefined; // the rayInspect the ray panel shows: it is rebuilt only for another
        this.rayToken = 0;
        this.heatMeasure = null;   // {key, promise, controller, users}: the heat scale being measured (heatScale)
        this.depthTimer = 0;
        // a second tree the URL or the user chose is kept while split view is off
        this.splitChosen = this.state.split.on;
        this.drawQueued = false;
        this.maxSamples = MAX_SAMPLES;
        this.slots = new Slots(RENDER_SLOTS);
        this.dark = matchMedia('(prefers-color-scheme: dark)');
        // frames take the scheme's background, the overlay and its key the scheme's colours
        this.dark.addEventListener('change', () => { this.pumpAll(); this.scheduleDraw(); });
    }

    model() {
        return this.models.get(this.state.model) || null;
    }

    treeOf(i) {
        return i === 0 ? { accel: this.state.accel, builder: this.state.builder }
            : { accel: this.state.split.accel, builder: this.state.split.builder };
    }

    background() {
        return this.dark.matches ? [0.1, 0.1, 0.12] : [0.86, 0.88, 0.91];
    }

    notify(text, kind = 'info', actions = []) {
        const box = document.createElement('div');
        box.className = `notice ${kind}`;
        if (kind === 'error') box.setAttribute('role', 'alert');
        const span = document.createElement('span');
        span.textContent = text;
        box.append(span);
        for (const [label, fn] of actions) {
            const b = document.createElement('button');
            b.type = 'button';
            b.textContent = label;
            b.addEventListener('click', () => { box.remove(); fn(); });
            box.append(b);
        }
        const close = document.createElement('button');
        close.type = 'button';
        close.textContent = 'Dismiss';
        close.addEventListener('click', () => box.remove());
        box.append(close);
        $('notices').append(box);
        if (kind !== 'error') setTimeout(() => box.remove(), 6000);
        return box;
    }

    async start() {
        this.bindControls();
        this.compare = new Compare(this);
        this.uploader = new Uploader(this);
        this.costDiff = new CostDiff(this);
        this.rebuildPanes();
        this.syncControls();
        this.showTab(this.state.tab);
        for (const m of await this.listModels()) this.models.set(m.name, m);
        // frames are split by the daemon's own budget; a daemon that does not say keeps the default
        const daemon = await api.daemonInfo().catch(() => ({}));
        if (daemon.limits?.max_pixels > 0) this.maxSamples = daemon.limits.max_pixels;
        // more requests than the daemon renders at once would only wait in its queue (API.md: queue.threads)
        if (daemon.queue?.threads > 0) this.slots.resize(daemon.queue.threads);
        if (daemon.embree === false) this.compare.noEmbree('this daemon was built without Embree: `make bench-embree` builds one with it');
        this.fillModels();
        if (!this.models.has(this.state.model)) {
            if (this.state.model) this.notify(`There is no model "${this.state.model}" on the daemon; showing another.`, 'error');
            const names = [...this.models.keys()];
            this.state.model = names.includes('cornell') ? 'cornell' : names[0] || '';
            this.state.view = viewOfNewModel(this.state.view); // the URL's target and distance were the missing model's
        }
        $('model').value = this.state.model;
        this.syncControls();
        this.pumpAll();
        this.loadBoxes();
        this.saveURL(true);
        this.compare.modelChanged();
    }

    /** The daemon's models, asked for until it answers (the URL's model is kept meanwhile). */
    async listModels() {
        let notice = null;
        for (;;) {
            try {
                const list = await api.listModels();
                if (notice) notice.remove();
                return list;
            } catch (e) {
                const text = `${e.words || String(e)} Trying again every ${LIST_RETRY_MS / 1000} s…`;
                if (!notice || !notice.isConnected) notice = this.notify(text, 'error');
                else notice.querySelector('span').textContent = text;
            }
            await new Promise((r) => setTimeout(r, LIST_RETRY_MS));
        }
    }

    fillModels(select) {
        const sel = $('model');
        sel.innerHTML = '';
        for (const m of [...this.models.values()].sort((a, b) => a.name.localeCompare(b.name))) {
            const o = document.createElement('option');
            o.value = m.name;
            o.textContent = `${m.name} (${triangles(m.triangles)})`;
            sel.append(o);
        }
        if (!this.models.size) {
            const o = document.createElement('option');
            o.value = '';
            o.textContent = 'no models loaded';
            sel.append(o);
        }
        sel.value = select || this.state.model;
    }

    async refreshModel(name) {
        try {
            const m = await api.getModel(name);
            this.models.set(m.name, m);
        } catch { /* keep the old record */ }
    }

    /** An uploaded model, new or replacing one of the same name: shown afresh either way. */
    addModel(m) {
        this.models.set(m.name, m);
        this.fillModels(m.name);
        this.setModel(m.name, true);
    }

    /** Shows model `name`; replaced: the same name holds another model now. */
    setModel(name, replaced = false) {
        if (name === this.state.model && !replaced) return;
        this.state.model = name;
        $('model').value = name;
        this.state.view = viewOfNewModel(this.state.view);
        this.clearRay();
        for (const p of this.panes) p.clearModel();
        this.changed({ boxes: true });
        this.compare.modelChanged();
    }

    /**
     * The top of the heat colour scale for frames of the views `reqs` (render
     * requests): the largest of their 99th percentiles at 1 spp. Frames that
     * ask for the same views share one measurement, aborted once no frame
     * waits for it (signal: the asking frame's).
     */
    heatScale(reqs, signal) {
        const views = reqs.map((r) => ({ ...r, spp: 1 }));
        const key = JSON.stringify(views);
        let m = this.heatMeasure;
        if (!m || m.key !== key) {
            const controller = new AbortController();
            m = { key, controller, users: 0 };
            m.promise = Promise.all(views.map((v) => api.renderJSON(v, { signal: controller.signal })))
                .then((all) => Math.max(...all.map((j) => j.heat_scale)));
            // a failed measurement is asked for again by the next frame
            m.promise.catch(() => { if (this.heatMeasure === m) this.heatMeasure = null; });
            this.heatMeasure = m;
        }
        m.users++;
        signal.addEventListener('abort', () => {
            if (--m.users > 0) return;
            m.controller.abort();
            if (this.heatMeasure === m) this.heatMeasure = null;
        }, { once: true });
        return m.promise;
    }

    /** The daemon renders at most n samples per request (its --max-pixels): frames are split by that. */
    setMaxSamples(n) {
        this.maxSamples = n;
        this.syncControls();
        this.pumpAll();
    }

    rebuildPanes() {
        const vp = $('viewport');
        const want = this.state.split.on ? 2 : 1;
        while (this.panes.length > want) this.panes.pop().dispose();
        while (this.panes.length < want) {
            const p = new Pane(this, this.panes.length);
            this.panes.push(p);
            vp.append(p.el);
            attachControls(this, p.frame, p);
        }
        vp.classList.toggle('split', want > 1);
        for (const p of this.panes) p.setAspect();
    }

    bindControls() {
        const s = this.state;
        $('model').addEventListener('change', (e) => this.setModel(e.target.value));
        for (const [id, key] of [['accel', 'accel'], ['builder', 'builder'], ['mode', 'mode']]) {
            $(id).addEventListener('change', (e) => {
                s[key] = e.target.value;
                if (key !== 'mode') this.clearRay();
                this.changed({ boxes: key !== 'mode' });
            });
        }
        $('spp').addEventListener('change', (e) => { s.spp = Number(e.target.value); this.changed(); });
        $('res').addEventListener('change', (e) => {
            s.res = e.target.value.split('x').map(Number);
            this.clearRay();
            // each pane takes the new aspect with its first frame at it: the old frame is not stretched meanwhile
            this.changed();
        });
        // as an orbit does: quick frames while the slider moves, a full one once it rests
        $('fov').addEventListener('input', (e) => this.setFov(Number(e.target.value)));
        // the slider's ends are a drag away from the protocol's field of view, which Reset view keeps
        $('fov-default').addEventListener('click', () => this.setFov(protocolOrbit().fov));
        for (const id of ['cam-orbit', 'cam-fly']) {
            $(id).addEventListener('change', () => {
                const landing = s.fly && !$('cam-fly').checked;
                s.fly = $('cam-fly').checked;
                this.changed({ noFrame: true });
                if (landing) this.pivotAtCentre();
            });
        }
        $('reset').addEventListener('click', () => this.resetView());
        $('save-png').addEventListener('click', () => this.savePNG());
        $('boxes-on').addEventListener('change', (e) => { s.boxes.on = e.target.checked; this.changed({ boxes: true }); });
        $('depth').addEventListener('input', (e) => {
            s.boxes.depth = Number(e.target.value);
            $('depth-out').textContent = e.target.value;
            this.changed({ noFrame: true });
            clearTimeout(this.depthTimer);
            this.depthTimer = setTimeout(() => this.loadBoxes(), DEPTH_REST_MS);
        });
        $('boxes-all').addEventListener('change', (e) => {
            s.boxes.all = e.target.checked;
            if (s.boxes.all) s.boxes.leaves = false;
            this.changed({ boxes: true, noFrame: true });
        });
        $('boxes-leaves').addEventListener('change', (e) => {
            s.boxes.leaves = e.target.checked;
            if (s.boxes.leaves) s.boxes.all = false;
            this.changed({ boxes: true, noFrame: true });
        });
        $('split-on').addEventListener('change', (e) => {
            s.split.on = e.target.checked;
            if (s.split.on && !this.splitChosen) {
                // the natural comparison: the other kind, same builder
                s.split.accel = s.accel === 'bvh' ? 'kd' : 'bvh';
                s.split.builder = s.builder;
            }
            this.clearRay();
            this.rebuildPanes();
            this.changed({ boxes: true });
        });
        $('diff-on').addEventListener('change', (e) => {
            s.split.diff = e.target.checked;
            this.changed({ noFrame: true });
        });
        for (const [id, key] of [['accel2', 'accel'], ['builder2', 'builder']]) {
            $(id).addEventListener('change', (e) => {
                s.split[key] = e.target.value;
                this.splitChosen = true;
                this.changed({ boxes: true });
            });
        }
        $('tab-view').addEventListener('click', () => this.showTab('view'));
        $('tab-compare').addEventListener('click', () => this.showTab('compare'));
        document.addEventListener('keydown', (e) => {
            const t = e.target;
            if (e.ctrlKey || e.metaKey || e.altKey) return;
            if (t && (t.tagName === 'INPUT' || t.tagName === 'SELECT' || t.tagName === 'TEXTAREA' || t.isContentEditable)) return;
            if ((e.key === 'r' || e.key === 'R') && this.state.tab === 'view') {
                e.preventDefault();
                this.resetView();
            }
            if (e.key === 'Escape' && this.rayInspect && this.state.tab === 'view') {
                e.preventDefault();
                this.dismissRay();
            }
        });
        window.addEventListener('resize', () => this.scheduleDraw());
    }

    syncControls() {
        const s = this.state;
        $('accel').value = s.accel;
        $('builder').value = s.builder;
        $('mode').value = s.mode;
        $('spp').value = String(s.spp);
        for (const o of $('spp').options) {
            // frames are split into strips down to a row; past that the daemon refuses them
            const over = rowSamples({ width: s.res[0], spp: Number(o.value), mode: s.mode }) > this.maxSamples;
            o.disabled = over && Number(o.value) !== s.spp;
            o.title = over ? `over this daemon's ${this.maxSamples.toLocaleString('en-US')} samples per request (--max-pixels)` : '';
        }
        const res = `${s.res[0]}x${s.res[1]}`;
        if (![...$('res').options].some((o) => o.value === res)) {
            const o = document.createElement('option');
            o.value = res;
            o.textContent = `${s.res[0]} × ${s.res[1]}`;
            $('res').append(o);
        }
        $('res').value = res;
        this.showFov();
        $('cam-orbit').checked = !s.fly;
        $('cam-fly').checked = s.fly;
        $('hint-drag').textContent = s.fly ? 'Drag to look around' : 'Drag to orbit';
        $('hint-wheel').textContent = s.fly ? 'wheel or pinch to move forward' : 'wheel or pinch to zoom';
        $('hint-arrows').textContent = s.fly ? 'arrow keys look' : 'arrow keys orbit';
        $('hint-plus').textContent = s.fly ? 'move' : 'zoom';
        $('boxes-on').checked = s.boxes.on;
        const depth = $('depth');
        if (s.boxes.depth > Number(depth.max)) depth.max = String(s.boxes.depth);
        depth.value = String(s.boxes.depth);
        $('depth-out').textContent = String(s.boxes.depth);
        for (const id of ['depth', 'boxes-all', 'boxes-leaves']) $(id).disabled = !s.boxes.on;
        $('boxes-all').checked = s.boxes.all;
        $('boxes-leaves').checked = s.boxes.leaves;
        $('split-on').checked = s.split.on;
        $('accel2').value = s.split.accel;
        $('builder2').value = s.split.builder;
        $('accel2').disabled = $('builder2').disabled = $('diff-on').disabled = !s.split.on;
        $('diff-on').checked = s.split.diff;
    }

    showTab(tab) {
        this.state.tab = tab;
        $('tab-view').setAttribute('aria-pressed', String(tab === 'view'));
        $('tab-compare').setAttribute('aria-pressed', String(tab === 'compare'));
        $('view-section').hidden = tab !== 'view';
        $('compare-section').hidden = tab !== 'compare';
        this.saveURL();
        // the hidden viewer asks for no frames (view.js pump)
        if (tab === 'view') {
            this.pumpAll();
            this.scheduleDraw();
        }
    }

    /** Something in the state changed: frames, boxes, URL, panels. */
    changed(opts = {}) {
        this.syncControls();
        if (opts.boxes) this.loadBoxes();
        if (!opts.noFrame) this.pumpAll();
        this.scheduleDraw();
        this.saveURL();
    }

    updateView(fn) {
        fn(this.state.view);
        this.moving = true;
        clearTimeout(this.restTimer);
        this.restTimer = setTimeout(() => {
            this.moving = false;
            this.pumpAll();
            this.scheduleDraw();
        }, REST_MS);
        this.pumpAll();
        this.scheduleDraw(); // Save PNG waits for the new view's frame
        this.saveURL();
    }

    setFov(fov) {
        this.updateView((v) => { v.fov = fov; });
        this.showFov();
    }

    /** The field of view's slider, its label and its way back to the protocol's. */
    showFov() {
        const fov = this.state.view.fov;
        $('fov').value = String(fov);
        $('fov-out').textContent = `${r4(fov)}°`;
        $('fov-default').hidden = fov === protocolOrbit().fov;
    }

    resetView() {
        const fov = this.state.view.fov;
        this.state.view = { ...protocolOrbit(), fov, target: null };
        this.updateView(() => {});
    }

    /**
     * Orbit about what the frame's centre shows: the target slides along the
     * line of sight to the surface there, so the picture stays as it is. A
     * fly camera's target lies its distance ahead, often outside the hall it
     * flew into; orbiting that would swing the eye out through the walls.
     * The line of sight is the only pixel of a 1 x 1 frame, traced by the
     * daemon. Nothing changes when it hits nothing, fails, or the view has
     * moved meanwhile.
     */
    async pivotAtCentre() {
        const s = this.state, model = this.model(), asked = JSON.stringify(s.view);
        if (!model) return;
        const req = { model: s.model, accel: s.accel, builder: s.builder, camera: requestCamera(model.bounds, s.view), width: 1, height: 1, x: 0, y: 0 };
        const traced = await api.traceRay(req).catch(() => null);
        if (!traced?.hit || JSON.stringify(s.view) !== asked || this.model() !== model || s.fly) return;
        // the ray is the line of sight itself: its t times its length is the distance to the surface
        const reach = (traced.hit.t * length(traced.ray.dir)) / boundsFrame(model.bounds).diagonal;
        const distance = Math.min(MAX_DISTANCE, Math.max(MIN_DISTANCE, reach));
        this.updateView((v) => Object.assign(v, reachTo(model.bounds, v, distance)));
    }

    viewportAspect(a) {
        document.getElementById('viewport').style.setProperty('--aspect', String(a));
    }

    pumpAll() {
        for (const p of this.panes) p.pump();
    }

    loadBoxes() {
        for (const p of this.panes) p.loadBoxes();
        this.boxesInfo();
    }

    boxesInfo() {
        const el = $('boxes-info'), b = this.state.boxes;
        if (!b.on) { el.textContent = ''; el.classList.remove('error'); return; }
        const parts = [];
        let err = false;
        for (const p of this.panes) {
            const name = `${p.tree().accel === 'kd' ? 'k-d' : 'BVH'} ${p.tree().builder}`;
            if (p.building) parts.push(`${name}: building…`);
            else if (!this.model()) parts.push(`${name}: waiting for the daemon's models…`);
            else if (!p.boxes) parts.push(`${name}: loading boxes…`);
            else if (p.boxes.error) {
                err = true;
                const st = p.boxes.error.status;
                parts.push(st === 404 || st === 501
                    ? `${name}: the daemon does not serve this tree's boxes yet (${st}${p.boxes.error.daemonMessage ? ': ' + p.boxes.error.daemonMessage : ''}).`
                    : `${name}: ${p.boxes.error.words}`);
            } else {
                const d = p.boxes.data;
                const n = (d.boxes || []).length, count = Math.max(n, Number(d.count) || 0);
                const num = (v) => v.toLocaleString('en-US');
                // the depth of the boxes shown, not the slider's: they may still be on their way
                const what = `${b.leaves ? 'leaf ' : ''}box${count === 1 ? '' : 'es'}` +
                    (b.leaves ? ` up to depth ${d.depth}` : b.all ? ` at depths 0–${d.depth}` : ` at depth ${d.depth}`);
                // count: every node that matches; boxes: all, or an even sample of max_boxes of them
                const cap = `(an even sample: at most ${num(Number(d.max_boxes))})`;
                parts.push(!d.truncated ? `${name}: ${num(n)} ${what}`
                    : count > n ? `${name}: ${num(n)} of ${num(count)} ${what} drawn ${cap}`
                        : `${name}: ${num(n)} ${what} drawn, more left out ${cap}`);
            }
        }
        el.textContent = parts.join(' · ');
        el.classList.toggle('error', err);
    }

    /** Pane frames or stats changed: redraw the panels on the next animation frame. */
    panesChanged() {
        this.scheduleDraw();
    }

    scheduleDraw() {
        if (this.drawQueued) return;
        this.drawQueued = true;
        requestAnimationFrame(() => {
            this.drawQueued = false;
            this.drawPanels();
        });
    }

    drawPanels() {
        renderStats($('stats'), this);
        renderLegend($('legend'), $('legend-bars'), this);
        // rebuilt only for another ray: a rebuild would drop the focus and scroll of the panel's list and button
        if (this.rayShown !== this.rayInspect) {
            renderRay($('ray-panel'), this);
            renderRaySummary($('ray-summary'), this, () => this.showRayDetails());
            this.rayShown = this.rayInspect;
        }
        this.boxesInfo();
        // the boxes are those of the tree rays traverse: a BVH's wide tree, a k-d tree's own; in split view the
        // slider reaches the deeper pane's depth (the shallower shows nothing past its own)
        const depths = this.panes.map((p) => p.stats && (p.stats.wide || p.stats).max_depth).filter(Number.isInteger);
        if (depths.length) {
            const depth = $('depth');
            const max = Math.max(...depths, this.state.boxes.depth);
            if (Number(depth.max) !== max) depth.max = String(max);
        }
        $('depth-note').textContent = this.depthNote();
        const save = $('save-png'), complete = this.framesComplete();
        save.disabled = !complete;
        save.title = complete ? (this.panes.length > 1 ? 'Both panes side by side, each under its title' : '')
            : 'Waiting for the full frame of this view';
        for (const p of this.panes) p.drawOverlay();
        this.renderOverlayKey();
        this.costDiff.update();
    }

    /** The key to what the panes' overlays draw: the depths of their boxes (in split view, of both) and the ray's parts. */
    renderOverlayKey() {
        const depths = new Set(), parts = [];
        let cased = false;
        for (const p of this.panes) {
            const { frame, boxes, ray } = p.overlayContent();
            if (boxes) for (const d of treeDepths(boxes.data)) depths.add(d);
            if (boxes) cased ||= boxesCased(boxes.data, frame?.req.mode === 'heat');
            if (ray) parts.push(...rayParts(ray.data));
        }
        renderKey($('overlay-key'), [...depths].sort((a, b) => a - b), parts, !this.dark.matches, cased);
    }

    /** Which tree's levels the depth slider walks: the one rays traverse, shallower than a BVH's binary tree in the stats. */
    depthNote() {
        const notes = this.panes.filter((p) => p.stats && !p.stats.error).map((p) => {
            const st = p.stats;
            return st.wide ? `${treeLabel(st)}: its wide tree, depths 0–${st.wide.max_depth} (the binary tree it was built as, in the stats, goes to ${st.max_depth})`
                : `${treeLabel(st)}: its own tree, depths 0–${st.max_depth}`;
        });
        return notes.length ? `Walks the tree rays traverse. ${notes.join('; ')}.` : '';
    }

    saveURL(now = false) {
        clearTimeout(this.urlTimer);
        const write = () => {
            const url = stateToURL(this.state);
            if (url !== location.search) history.replaceState(null, '', url);
        };
        if (now) write(); else this.urlTimer = setTimeout(write, 150);
    }

    async inspect(pane, clientX, clientY) {
        const px = pane.pixelAt(clientX, clientY);
        const model = this.model();
        if (!px || !model) return;
        const shown = pane.shown;
        const [W, H] = this.state.res;
        const t = pane.tree();
        const camera = shown ? shown.req.camera : requestCamera(model.bounds, this.state.view);
        const req = { model: this.state.model, accel: t.accel, builder: t.builder, camera, width: W, height: H, x: px.x, y: px.y };
        const token = ++this.rayToken;
        for (const p of this.panes) p.ray = null;
        this.rayInspect = { pane: pane.index, req, pending: true };
        pane.ray = { req, data: null };
        this.scheduleDraw();
        const heatReq = {
            model: req.model, accel: req.accel, builder: req.builder, mode: 'heat', camera,
            width: W, height: H, spp: 1, region: { x: px.x, y: px.y, w: 1, h: 1 },
        };
        const [ray, heat] = await Promise.allSettled([api.traceRay(req), api.renderJSON(heatReq)]);
        if (token !== this.rayToken) return;
        const r = { pane: pane.index, req };
        if (ray.status === 'fulfilled') r.data = ray.value;
        else r.error = ray.reason;
        if (heat.status === 'fulfilled') r.heat = heat.value;
        else r.heatError = heat.reason.words || String(heat.reason);
        this.rayInspect = r;
        pane.ray = r.data ? { req, data: r.data } : null;
        this.scheduleDraw();
    }

    /** The summary's button: the ray inspector's card scrolled to, its heading focused for a keyboard's next Tab. */
    showRayDetails() {
        const heading = $('h-ray');
        heading.closest('.card').scrollIntoView({ block: 'start', behavior: 'smooth' });
        heading.focus({ preventScroll: true });
    }

    /** The ray panel's Clear, or Escape: the ray goes and the focus returns to its frame (not to the page, with the button). */
    dismissRay() {
        const pane = this.panes[this.rayInspect.pane] || this.panes[0];
        this.clearRay();
        pane.frame.focus();
    }

    clearRay() {
        this.rayToken++;
        this.rayInspect = null;
        for (const p of this.panes) p.ray = null;
        this.scheduleDraw();
    }

    /** Whether every pane shows the whole full frame of the current view: Save PNG saves only that. */
    framesComplete() {
        return !this.moving && this.panes.every((p) => p.complete());
    }

    savePNG() {
        if (!this.framesComplete()) {
            this.notify('The frame of this view is not complete yet; Save PNG is ready once it is.', 'error');
            return;
        }
        savePanes(this.panes, !this.dark.matches, this.costDiff).catch((e) => this.notify(`Saving the PNG failed: ${e.message}`, 'error'));
    }
}

const app = new App();
window.arbor = app; // for the browser console and the e2e tests
app.start();
