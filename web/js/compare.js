// compare.js - the compare view: an /api/bench job over the eight trees with a
// progress bar, then one SVG bar chart per measure (eight bars each, ours;
// rates and the work per diffuse ray behind them),
// with the study's figures beside ours for galleon and castle and Embree's
// figure as a line where the job measured it (the "Beside" choice: Embree at
// its default or in its robust mode, sent as the job's `embree`). A re-run
// that is cancelled or fails leaves the last finished run's charts.

import * as api from './api.js';
import { withToken } from './token.js';
import { STUDY_SOURCE, studyFigure, hasStudy } from './study.js';
import { fmt } from './panels.js';

const TREES = [
    ['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'], ['bvh', 'sah'],
    ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah'],
];

export const CHARTS = [
    { key: 'build_ms', title: 'Build time', unit: 'ms', log: true, better: 'lower', study: 1 },
    { key: 'render_ms', title: 'Render time (the study\'s protocol frame)', unit: 'ms', log: true, better: 'lower', study: 4 },
    { key: 'mean_leaf_depth', title: 'Mean leaf depth', unit: '', better: 'lower', study: 2 },
    { key: 'mean_tris_per_leaf', title: 'Mean triangles per leaf', unit: '', better: 'lower', study: 3 },
    { key: 'sah_cost', title: 'SAH cost', unit: '', better: 'lower' },
    { key: 'primary_mrays', title: 'Primary rays', unit: 'Mrays/s', better: 'higher', embree: true },
    { key: 'diffuse_mrays', title: 'Diffuse rays', unit: 'Mrays/s', better: 'higher', embree: true },
    { key: 'shadow_mrays', title: 'Shadow rays', unit: 'Mrays/s', better: 'higher', embree: true },
    // The work behind the diffuse rate, where the trees differ most.
    { key: 'diffuse_nodes_per_ray', title: 'Node steps per diffuse ray', unit: '', better: 'lower' },
    { key: 'diffuse_tris_per_ray', title: 'Triangle tests per diffuse ray', unit: '', better: 'lower' },
];

const esc = (s) => String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
const treeLabel = (a, b) => `${a === 'kd' ? 'k-d' : 'BVH'} ${b}`;
const $ = (id) => document.getElementById(id);

export class Compare {
    constructor(app) {
        this.app = app;
        this.job = null;       // {id, model}
        this.pollTimer = 0;
        this.results = new Map(); // model -> rows
        $('cmp-start').addEventListener('click', () => this.start());
        $('cmp-cancel').addEventListener('click', () => this.cancel());
    }

    /** The viewer's model changed: its charts and no status, unless a job's are being drawn (they stay until it ends). */
    modelChanged() {
        if (this.job) return;
        // the last run's progress and error were another model's
        $('cmp-progress-wrap').hidden = true;
        this.setError('');
        this.showCharts();
    }

    /** The charts of the viewer's model's last finished run, or none. */
    showCharts() {
        const m = this.app.state.model;
        this.draw(m, this.results.get(m) || null);
    }

    /** The daemon has no Embree (/api/stats says so; why: the words shown): Embree is not offered. */
    noEmbree(why) {
        const peer = $('cmp-peer');
        for (const o of peer.options) {
            o.disabled = o.value !== '';
            o.title = o.disabled ? why : '';
        }
        peer.value = '';
        const note = $('cmp-peer-why');
        note.textContent = `Embree: ${why}`;
        note.hidden = false;
    }

    setError(text) {
        const el = $('cmp-error');
        el.hidden = !text;
        el.textContent = text || '';
    }

    async start() {
        const model = this.app.state.model;
        if (!model || this.job) return;
        this.setError('');
        $('cmp-start').disabled = true;
        $('cmp-progress-wrap').hidden = false;
        $('cmp-progress').removeAttribute('value'); // indeterminate until the job reports
        $('cmp-progress-text').textContent = 'starting…';
        const body = {
            model,
            accel: ['bvh', 'kd'],
            builder: ['spatial', 'median', 'mean', 'sah'],
            runs: Number($('cmp-runs').value) || 1,
            embree: { embree: true, robust: 'robust' }[$('cmp-peer').value] || false,
        };
        let j;
        try {
            j = await withToken(`Starting the benchmark of ${model}`, () => api.startBench(body));
        } catch (e) {
            this.fail(e.words || String(e));
            return;
        }
        this.job = { id: j.id, model, start: performance.now(), peer: body.embree !== false };
        $('cmp-cancel').disabled = false;
        this.poll();
    }

    async poll() {
        const job = this.job;
        if (!job) return;
        let j;
        try {
            j = await api.getJob(job.id);
        } catch (e) {
            this.ended(job, e.words || String(e), null);
            return;
        }
        if (this.job !== job) return;
        const p = j.progress || {};
        const done = Number(p.done) || 0, total = Number(p.total) || 0;
        const bar = $('cmp-progress');
        if (total > 0) { bar.max = total; bar.value = done; } else bar.removeAttribute('value');
        const secs = ((j.elapsed_ms ?? performance.now() - job.start) / 1000).toFixed(1);
        $('cmp-progress-text').textContent = `${j.state}: ${done} of ${total || '?'} steps, ${secs} s`;
        if (j.rows && j.rows.length) this.draw(job.model, j.rows, true, job.peer);
        if (j.state === 'done') {
            this.results.set(job.model, j.rows || []);
            this.finish();
            $('cmp-progress-text').textContent = `done: ${(j.rows || []).length} rows in ${secs} s`;
            this.showCharts();
        } else if (j.state === 'failed' || j.state === 'cancelled') {
            const run = this.results.has(job.model) ? 'The re-run of the benchmark' : 'The benchmark';
            this.ended(job, j.state === 'failed'
                ? `${run} of ${job.model} failed: ${j.error || 'the daemon gave no reason'}.`
                : `${run} of ${job.model} was cancelled.`, j.rows);
        } else {
            this.pollTimer = setTimeout(() => this.poll(), 400);
        }
    }

    async cancel() {
        if (!this.job) return;
        const { id, model } = this.job;
        try {
            await withToken(`Cancelling the benchmark of ${model}`, () => api.cancelJob(id));
        } catch (e) {
            this.setError(e.words || String(e));
        }
    }

    finish() {
        clearTimeout(this.pollTimer);
        this.job = null;
        $('cmp-start').disabled = false;
        $('cmp-cancel').disabled = true;
    }

    fail(text) {
        this.finish();
        $('cmp-progress-wrap').hidden = true;
        this.setError(text);
    }

    /** The job ended unfinished: the charts go back to the model's last finished run, or,
     *  without one, show what the job measured (rows) with no placeholders for the rest. */
    ended(job, text, rows) {
        if (job.model !== this.app.state.model) {
            // the viewer moved on to another model meanwhile: its charts
            this.fail(text);
            this.showCharts();
            return;
        }
        const last = this.results.get(job.model);
        this.fail(last ? `${text} The charts show the last finished run.` : text);
        this.draw(job.model, last || (rows && rows.length ? rows : null));
    }

    /** Draws the eight charts for a model's bench rows (partial while running; peer: the job
     *  asked for Embree, whose row comes last, so its charts keep room for it from the start). */
    draw(model, rows, partial = false, peer = false) {
        // the heading names the model whose charts these are
        $('cmp-model').textContent = model || '—';
        const el = $('charts');
        if (!rows) {
            el.innerHTML = '';
            return;
        }
        const ours = (a, b) => rows.find((r) => r.accel === a && r.builder === b) || null;
        const embree = rows.find((r) => r.accel === 'embree') || null;
        const study = hasStudy(model);
        el.innerHTML = CHARTS.map((c) => chartHTML(c, model, ours, embree, study, partial, peer)).join('') +
            (study ? `<p class="muted small chart-note">Study figures: ${esc(STUDY_SOURCE)}; measured on another machine
              and ray tracer (no BVH-SAH there), shown for shape, not as a race. Times on a log scale.</p>` : '');
    }
}

// Axis labels are centred on their ticks, at least this far apart (SVG units: 1M, 100k).
const TICK_GAP = 34;
// A value label's width per character (10 px text, SVG units), a little over the widest digit.
const CHAR_W = 6.5;

/** 1, 10, 100, 1k, 10k, 100k, 1M: log-axis ticks that fit side by side. */
function compact(v) {
    if (v >= 1e6) return `${v / 1e6}M`;
    if (v >= 1e3) return `${v / 1e3}k`;
    return String(v);
}

function chartHTML(c, model, ours, embree, study, partial, peerAsked) {
    const withStudy = study && c.study;
    const rows = TREES.map(([a, b]) => {
        const r = ours(a, b);
        const v = r && r[c.key] !== null && r[c.key] !== undefined ? Number(r[c.key]) : null;
        const s = withStudy ? studyFigure(model, c.key, a, b) : null;
        return { a, b, v, s };
    });
    const e = c.embree && embree && embree[c.key] !== null && embree[c.key] !== undefined ? Number(embree[c.key]) : null;
    const values = rows.flatMap((r) => [r.v, r.s]).concat(e === null ? [] : [e]).filter((v) => v !== null && v > 0);
    const W = 360, labelW = 84, valueW = 58, plotW = W - labelW - valueW;
    const barH = withStudy ? 10 : 14, gap = withStudy ? 9 : 7, groupH = withStudy ? barH * 2 + 2 : barH;
    // a line above the bars for Embree's label
    const top = c.embree && (e !== null || peerAsked) ? 20 : 6, H = top + TREES.length * (groupH + gap) + 16;
    let scale;
    if (c.log && values.length) {
        const lo = Math.floor(Math.log10(Math.min(...values)) - 0.0001);
        const hi = Math.ceil(Math.log10(Math.max(...values)) + 0.0001);
        const decades = Math.max(1, hi - lo), every = Math.ceil(TICK_GAP / (plotW / decades));
        scale = (v) => (v > 0 ? Math.max(2, ((Math.log10(v) - lo) / decades) * plotW) : 0);
        scale.ticks = [];
        for (let k = lo; k <= hi; k += every) scale.ticks.push([10 ** k, ((k - lo) / decades) * plotW]);
    } else {
        const max = values.length ? Math.max(...values) : 1;
        scale = (v) => (v > 0 ? (v / max) * plotW : 0);
        scale.ticks = [[0, 0], [max, plotW]];
    }
    const ex = e === null ? null : labelW + scale(e);
    // a bar's value label starts past the bar's end, or past Embree's line where it would cross it
    const valueAt = (end, y, text) => {
        const x = end + 4, crosses = ex !== null && x - 2 < ex && x + text.length * CHAR_W + 2 > ex;
        return `<text class="value" x="${(crosses ? ex + 4 : x).toFixed(1)}" y="${y}">${text}</text>`;
    };
    let svg = '';
    rows.forEach((r, i) => {
        const y = top + i * (groupH + gap);
        svg += `<text x="${labelW - 6}" y="${y + barH - 2}" text-anchor="end">${treeLabel(r.a, r.b)}</text>`;
        const w = r.v === null ? 0 : scale(r.v);
        svg += `<rect class="bar ours" x="${labelW}" y="${y}" width="${w.toFixed(1)}" height="${barH}" rx="2"
                 data-accel="${r.a}" data-builder="${r.b}" data-value="${r.v ?? ''}"><title>ours, ${treeLabel(r.a, r.b)}: ${fmt(r.v)} ${c.unit}</title></rect>`;
        svg += valueAt(labelW + w, y + barH - 2, r.v === null ? (partial ? '…' : '—') : fmt(r.v));
        if (withStudy) {
            const ys = y + barH + 2;
            const ws = r.s === null ? 0 : scale(r.s);
            if (r.s !== null) {
                svg += `<rect class="bar study" x="${labelW}" y="${ys}" width="${ws.toFixed(1)}" height="${barH}" rx="2"
                         data-accel="${r.a}" data-builder="${r.b}" data-value="${r.s}"><title>study, ${treeLabel(r.a, r.b)}: ${fmt(r.s)} ${c.unit}</title></rect>`;
                svg += valueAt(labelW + ws, ys + barH - 2, `study ${fmt(r.s)}`);
            } else {
                svg += `<text class="value" x="${labelW + 2}" y="${ys + barH - 2}">not in the study</text>`;
            }
        }
    });
    const axisY = top + TREES.length * (groupH + gap) - gap + 4;
    svg += `<line class="axis" x1="${labelW}" y1="${top - 2}" x2="${labelW}" y2="${axisY}"/>`;
    for (const [v, x] of scale.ticks) {
        const label = c.log ? compact(v) : fmt(v, v < 1 ? 2 : 0);
        svg += `<text class="value tick" x="${labelW + x}" y="${axisY + 11}" text-anchor="middle">${label}</text>`;
    }
    const peer = embree && embree.builder === 'robust' ? 'Embree, robust' : 'Embree';
    if (ex !== null) {
        const right = ex > labelW + plotW / 2; // the label on the side with room
        svg += `<line class="embree" x1="${ex}" y1="${top - 2}" x2="${ex}" y2="${axisY}"/>`;
        svg += `<text class="embree-label" x="${right ? ex - 3 : ex + 3}" y="${top - 6}"
                 text-anchor="${right ? 'end' : 'start'}">${peer} ${fmt(e)}</text>`;
    }
    const label = `${c.title} of the eight trees of ${model}${c.unit ? ', ' + c.unit : ''}, ${c.better} is better` +
        (withStudy ? `, with the study's table ${c.study} beside` : '');
    return `<figure class="card chart" data-metric="${c.key}">
        <h3>${esc(c.title)}${c.unit ? ` <span class="muted small">(${esc(c.unit)}${c.log ? ', log scale' : ''}; ${c.better} is better)</span>` : ` <span class="muted small">(${c.better} is better)</span>`}</h3>
        <svg viewBox="0 0 ${W} ${H}" role="img" aria-label="${esc(label)}">${svg}</svg>
        <figcaption class="key"><span><i class="swatch" style="background:var(--ours)"></i>ours (arbord)</span>
          ${withStudy ? `<span><i class="swatch" style="background:var(--study)"></i>study, table ${c.study}</span>` : ''}
          ${e !== null ? `<span><i class="swatch" style="background:var(--embree)"></i>${peer}</span>` : ''}</figcaption>
      </figure>`;
}
