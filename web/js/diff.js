// diff.js - where the split panes' trees differ in work: per pixel, the
// second tree's node steps + triangle tests minus the first's, for the ray
// through the pixel's centre (POST /api/render format=costs at 1 spp, the
// counts the ray inspector shows), drawn in a diverging colour map beside
// its scale and a summary of where each tree does less.

import * as api from './api.js';
import { stripRegions, rowSamples } from './view.js';
import { esc, fmt, treeLabel } from './panels.js';

const $ = (id) => document.getElementById(id);

// the ends of the scale: this fraction of the pixels that differ lie within it, so that a few outliers
// do not wash the rest out to the neutral colour
const PERCENTILE = 0.99;
// ColorBrewer's RdBu: blue where the second tree does less work, red where it does more, near white where
// both do the same; a colour-blind reader still tells blue from red
const LESS = [33, 102, 172], SAME = [247, 247, 247], MORE = [178, 24, 43];
// a ray that touches nothing costs 0 in a k-d tree (clipped to the bounds first) and 1 in a BVH (its root)
const IDLE = 1;

const rgb = (c) => `rgb(${c.join(', ')})`;

/** The colour of difference d on a scale of +-scale. */
function diffColour(d, scale) {
    const t = Math.max(-1, Math.min(1, d / scale)), end = t < 0 ? LESS : MORE, w = Math.abs(t);
    return SAME.map((s, i) => Math.round(s + w * (end[i] - s)));
}

/**
 * The figures of costs a and b (the first and the second tree's) at the
 * same pixels: means, the share of working pixels where b is less, the same,
 * more, and the scale's end (at least 1).
 */
function diffSummary(a, b) {
    let sumA = 0, sumB = 0, less = 0, same = 0, more = 0;
    const sizes = [];
    for (let i = 0; i < a.length; i++) {
        sumA += a[i];
        sumB += b[i];
        if (a[i] <= IDLE && b[i] <= IDLE) continue;
        const d = b[i] - a[i];
        if (d < 0) less++; else if (d > 0) more++; else same++;
        if (d !== 0) sizes.push(Math.abs(d));
    }
    sizes.sort((x, y) => x - y);
    const scale = sizes.length ? Math.max(1, sizes[Math.ceil(PERCENTILE * sizes.length) - 1]) : 1;
    return { meanA: sumA / a.length, meanB: sumB / a.length, working: less + same + more, less, same, more, scale };
}

export class CostDiff {
    constructor(app) {
        this.app = app;
        this.key = '';          // the requests whose costs are shown or on their way
        this.shownKey = '';     // the requests whose costs are drawn
        this.controller = null; // aborts the costs on their way
        this.el = $('diff');
    }

    /** The two trees' cost requests for the current view (the panes' full frames at 1 spp), or null when hidden. */
    requests() {
        const app = this.app;
        if (!app.state.split.on || !app.state.split.diff || app.panes.length < 2 || !app.model() || app.state.tab !== 'view') return null;
        return app.panes.map((p) => {
            const r = p.request(false);
            return { model: r.model, accel: r.accel, builder: r.builder, width: r.width, height: r.height, camera: r.camera };
        });
    }

    /** From the panels' redraw: hidden, kept, or measured again once the view rests. */
    update() {
        const reqs = this.requests();
        this.el.hidden = !reqs;
        if (!reqs) {
            this.abort();
            this.key = '';
            return;
        }
        // a model replaced under its name is measured again; the background is drawn with the scheme's
        const key = `${this.app.model().version} ${this.app.background()} ${JSON.stringify(reqs)}`;
        this.el.classList.toggle('stale', this.shownKey !== key);
        if (key === this.key) return;
        // costs of a view left behind would hold the daemon's workers from the quick frames of the new one
        this.abort();
        this.key = '';
        if (this.app.moving) return; // asked for once the view rests
        this.key = key;
        this.measure(reqs, key);
    }

    abort() {
        if (this.controller) this.controller.abort();
        this.controller = null;
    }

    async measure(reqs, key) {
        const controller = (this.controller = new AbortController());
        this.status(`Measuring the costs of ${reqs.map(treeLabel).join(' and ')}…`);
        try {
            const [a, b] = await Promise.all(reqs.map((r) => this.costsOf(r, controller.signal)));
            if (controller.signal.aborted) return;
            this.draw(reqs, a, b);
            this.shownKey = key;
            this.el.classList.remove('stale');
            this.status('');
        } catch (e) {
            if (e.name === 'AbortError') return;
            controller.abort(); // the other tree's strips
            // the key stays this view's: the next view asks again, this one does not loop on the failure
            this.status(e.words || String(e.message || e), true);
        }
    }

    /** One tree's costs, asked for in the strips a frame of the view takes (the daemon's --max-pixels). */
    async costsOf(req, signal) {
        const { width: W, height: H } = req;
        const regions = stripRegions(W, H, rowSamples({ ...req, spp: 1, mode: 'heat' }), this.app.maxSamples);
        if (!regions) throw new Error(`one row of ${W} pixels is over this daemon's ${this.app.maxSamples} samples per request`);
        const costs = new Float32Array(W * H);
        await Promise.all(regions.map(async (region) => {
            const part = await this.app.slots.run(this, () => api.renderCosts({ ...req, region }, { signal }), signal);
            costs.set(part, region.y * W);
        }));
        return costs;
    }

    draw(reqs, a, b) {
        const { width: W, height: H } = reqs[0];
        const [nameA, nameB] = reqs.map((r) => esc(treeLabel(r)));
        const s = diffSummary(a, b);
        const canvas = $('diff-canvas');
        canvas.width = W;
        canvas.height = H;
        canvas.parentElement.style.aspectRatio = `${W} / ${H}`;
        const ctx = canvas.getContext('2d'), img = ctx.createImageData(W, H);
        const bg = this.app.background().map((c) => Math.round(c * 255));
        for (let i = 0; i < a.length; i++) {
            const c = a[i] <= IDLE && b[i] <= IDLE ? bg : diffColour(b[i] - a[i], s.scale);
            img.data.set(c, 4 * i);
            img.data[4 * i + 3] = 255;
        }
        ctx.putImageData(img, 0, 0);
        canvas.dataset.scale = String(s.scale);
        canvas.setAttribute('aria-label', `${treeLabel(reqs[1])} minus ${treeLabel(reqs[0])}, node steps plus triangle tests per pixel: ` +
            `blue where it does less work, red where it does more, up to ${s.scale}`);
        $('diff-title').innerHTML = `${nameB} − ${nameA}: node steps + triangle tests per pixel`;
        $('diff-bar').style.background = `linear-gradient(to right, ${rgb(LESS)}, ${rgb(SAME)}, ${rgb(MORE)})`;
        $('diff-ticks').innerHTML = [`−${fmt(s.scale)}`, '0', `+${fmt(s.scale)}`]
            .map((t, i) => `<span style="left:${i * 50}%">${t}</span>`).join('');
        $('diff-note').innerHTML = `Blue: ${nameB} does less work than ${nameA}; red: more; the ends, a difference of ` +
            `${fmt(s.scale)} or more (the 99th percentile). Rays that touch nothing in either tree take the background.`;
        const pct = (k) => (s.working ? `${fmt((100 * k) / s.working, 1)}%` : '—');
        const row = (label, value, key) => `<tr data-key="${key}"><th scope="row">${label}</th><td>${value}</td></tr>`;
        $('diff-stats').innerHTML = '<tbody>' +
            row(`Mean per pixel, ${nameA}`, fmt(s.meanA), 'mean_a') +
            row(`Mean per pixel, ${nameB}`, fmt(s.meanB), 'mean_b') +
            row(`${nameB} / ${nameA}`, s.meanA > 0 ? `${fmt(s.meanB / s.meanA)}×` : '—', 'ratio') +
            row('Pixels where either tree works', fmt(s.working), 'working') +
            row(`…${nameB} does less`, pct(s.less), 'less') +
            row('…the same', pct(s.same), 'same') +
            row(`…${nameB} does more`, pct(s.more), 'more') +
            '</tbody>';
    }

    status(text, error = false) {
        const el = $('diff-status');
        el.textContent = text;
        el.classList.toggle('error', error);
        el.hidden = !text;
    }
}
