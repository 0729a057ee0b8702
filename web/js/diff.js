// diff.js - where the split panes' trees differ in work: per pixel, the
// second tree's node steps + triangle tests minus the first's, for the ray
// through the pixel's centre (POST /api/render format=costs at 1 spp, the
// counts the ray inspector shows), drawn in a diverging colour map beside
// its scale and a summary of where each tree does less; the figure drawn is
// kept for Save PNG to put under the frames it was measured for.

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

// the key's colours from its negative end to its positive one
const STOPS = [LESS, SAME, MORE].map((c) => `rgb(${c.join(', ')})`);

/** What of a render request its costs depend on: what a figure is of. */
const costRequest = (r) => ({ model: r.model, accel: r.accel, builder: r.builder, width: r.width, height: r.height, camera: r.camera });

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

/**
 * The words and figures of summary s of the costs of reqs (the first and the
 * second tree's), as plain text: the page's figure shows them and Save PNG
 * draws them, so both say the same.
 */
function figureText(reqs, s) {
    const [a, b] = reqs.map(treeLabel);
    const pct = (k) => (s.working ? `${fmt((100 * k) / s.working, 1)}%` : '—');
    return {
        title: `${b} − ${a}: node steps + triangle tests per pixel`,
        ticks: [`−${fmt(s.scale)}`, '0', `+${fmt(s.scale)}`],
        // the key's words, a line each in Save PNG's key, one paragraph on the page
        note: [
            `Blue: ${b} does less work than ${a}; red: more;`,
            `the ends, a difference of ${fmt(s.scale)} or more (the 99th percentile).`,
            'Rays that touch nothing in either tree take the background.',
        ],
        rows: [
            { key: 'mean_a', label: `Mean per pixel, ${a}`, value: fmt(s.meanA) },
            { key: 'mean_b', label: `Mean per pixel, ${b}`, value: fmt(s.meanB) },
            { key: 'ratio', label: `${b} / ${a}`, value: s.meanA > 0 ? `${fmt(s.meanB / s.meanA)}×` : '—' },
            { key: 'working', label: 'Pixels where either tree works', value: fmt(s.working) },
            { key: 'less', label: `…${b} does less`, value: pct(s.less) },
            { key: 'same', label: '…the same', value: pct(s.same) },
            { key: 'more', label: `…${b} does more`, value: pct(s.more) },
        ],
    };
}

export class CostDiff {
    constructor(app) {
        this.app = app;
        this.key = '';          // the requests whose costs are shown or on their way
        this.shown = null;      // the figure drawn: {key, image (ImageData), stops, title, ticks, note, rows}
        this.controller = null; // aborts the costs on their way
        this.el = $('diff');
    }

    /** The two trees' cost requests for the current view (the panes' full frames at 1 spp), or null when hidden. */
    requests() {
        const app = this.app;
        if (!app.state.split.on || !app.state.split.diff || app.panes.length < 2 || !app.model() || app.state.tab !== 'view') return null;
        return app.panes.map((p) => costRequest(p.request(false)));
    }

    /** What identifies a figure: its cost requests, the model's version (one replaced under its name is measured again) and the background drawn. */
    keyOf(reqs, background) {
        return `${this.app.model().version} ${background} ${JSON.stringify(reqs)}`;
    }

    /**
     * The figure drawn, for Save PNG to put under frames (the panes'
     * lastFull), while the page shows it and it is of these very frames:
     * their view, trees, size and background; else null (hidden, or left
     * from another view while this one's costs are measured).
     */
    figureOf(frames) {
        if (!this.requests() || !this.shown) return null;
        const key = this.keyOf(frames.map((f) => costRequest(f.req)), frames[0].req.background);
        return this.shown.key === key ? this.shown : null;
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
        const key = this.keyOf(reqs, this.app.background());
        this.el.classList.toggle('stale', this.shown?.key !== key);
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
            this.shown = { key, ...this.draw(reqs, a, b) };
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

    /** Draws the figure of costs a and b of reqs; returns its image and text (figureText). */
    draw(reqs, a, b) {
        const { width: W, height: H } = reqs[0];
        const s = diffSummary(a, b), text = figureText(reqs, s);
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
        $('diff-title').textContent = text.title;
        $('diff-bar').style.background = `linear-gradient(to right, ${STOPS.join(', ')})`;
        $('diff-ticks').innerHTML = text.ticks.map((t, i) => `<span style="left:${i * 50}%">${esc(t)}</span>`).join('');
        $('diff-note').textContent = text.note.join(' ');
        $('diff-stats').innerHTML = `<tbody>${text.rows.map((r) =>
            `<tr data-key="${r.key}"><th scope="row">${esc(r.label)}</th><td>${esc(r.value)}</td></tr>`).join('')}</tbody>`;
        return { image: img, stops: STOPS, ...text };
    }

    status(text, error = false) {
        const el = $('diff-status');
        el.textContent = text;
        el.classList.toggle('error', error);
        el.hidden = !text;
    }
}
