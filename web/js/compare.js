// compare.js - the "Compare trees" tab: an /api/bench job over the eight trees
// of the model chosen (two kinds, four builders) with its progress (which tree
// is being measured, which wait), then its figures as a sortable table with
// the best of each column marked, and as one bar chart per measure with the
// study's figures beside ours for galleon and castle and Embree's figure as a
// line where the job measured it (the "Beside" choice: Embree at its default
// or in its robust mode, sent as the job's `embree`). A re-run that is
// cancelled or fails leaves the last finished run's figures. Finished runs are
// kept per model and version (a replaced model's are dropped); this tab's
// sessionStorage remembers the jobs, so a reload follows a running job rather
// than leaving it to run unseen, and shows the finished ones again.

import * as api from './api.js';
import { withToken } from './token.js';
import { STUDY_SOURCE, studyFigure, studyTable, hasStudy } from './study.js';
import { esc, fmt, fmtBytes, triangles, treeLabel } from './panels.js';

// The job's order of its rows (kinds, then builders), which is the study's order of its columns.
const TREES = [
    ['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'], ['bvh', 'sah'],
    ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah'],
];

// A bench row's figures (API.md "Bench jobs"; docs/BENCH.md says how they are measured) in the table's order:
// head: the column's heading; title: the chart's; group: the columns' group; what: what it measures, for a
// person. chart: drawn as a bar chart too (line: with Embree's figure as a line).
const METRICS = [
    {
        key: 'build_ms', head: 'Build', title: 'Build time', unit: 'ms', better: 'lower', group: 'Time', chart: true,
        what: 'Wall time to build the tree from the triangles already in memory. The job builds trees of its own: the ' +
            "Viewer's build time of the same tree (from /api/stats) is another measurement.",
    },
    {
        key: 'render_ms', head: 'Render', title: 'Render time, one 1024 × 768 frame', unit: 'ms', better: 'lower', group: 'Time',
        chart: true,
        what: 'Wall time of one shaded 1024 × 768 frame of the model from the protocol view, 1 sample per pixel, with hard ' +
            'shadows and mirrors. The study timed frames of its own.',
    },
    {
        key: 'sah_cost', head: 'SAH cost', title: 'SAH cost', unit: '', better: 'lower', group: 'Tree quality', chart: true,
        what: "The surface area heuristic's estimate of a ray's work through the model's box: node steps plus triangle " +
            'tests, each node weighted by the chance that such a ray enters its box. Of the binary tree the builder made.',
    },
    {
        key: 'mean_leaf_depth', head: 'Leaf depth', title: 'Mean leaf depth', unit: '', better: 'lower', group: 'Tree quality', chart: true,
        what: 'The mean depth of the leaves of the binary tree the builder made; the root is at depth 0.',
    },
    {
        key: 'mean_tris_per_leaf', head: 'Tris / leaf', title: 'Mean triangles per leaf', unit: '', better: 'lower', group: 'Tree quality',
        chart: true,
        what: 'Triangle references over the leaves that hold any; a k-d tree refers to a triangle in every cell it crosses. ' +
            'Fewer tests in a leaf reached, not by itself a faster tree.',
    },
    {
        key: 'bytes_per_tri', head: 'Bytes / tri', title: 'Bytes per triangle', unit: 'B', better: 'lower', group: 'Tree quality',
        what: "Bytes of the tree rays traverse, over the model's triangles: a BVH's wide tree (the binary one is freed " +
            "once collapsed; /api/stats calls it \"wide\"), a k-d tree's own.",
    },
    {
        key: 'primary_mrays', head: 'Primary', title: 'Primary rays', unit: 'Mrays/s', better: 'higher', group: 'Rays', chart: true,
        line: true,
        what: "Millions of rays a second: the protocol view's 1024 × 768 camera rays to their closest hits, traced over " +
            'and over for at least 200 ms.',
    },
    {
        key: 'diffuse_mrays', head: 'Diffuse', title: 'Diffuse rays', unit: 'Mrays/s', better: 'higher', group: 'Rays', chart: true,
        line: true,
        what: 'Rays from the primary hits in random directions to their closest hits: incoherent rays, where the trees ' +
            'differ most.',
    },
    {
        key: 'shadow_mrays', head: 'Shadow', title: 'Shadow rays', unit: 'Mrays/s', better: 'higher', group: 'Rays', chart: true,
        line: true,
        what: 'Rays from the primary hits towards a point light, stopping at any hit.',
    },
    {
        key: 'diffuse_nodes_per_ray', head: 'Nodes / ray', title: 'Node steps per diffuse ray', unit: '', better: 'lower',
        group: 'Rays', chart: true,
        what: 'The tree nodes a diffuse ray steps through, on average: the work behind its rate.',
    },
    {
        key: 'diffuse_tris_per_ray', head: 'Tests / ray', title: 'Triangle tests per diffuse ray', unit: '', better: 'lower',
        group: 'Rays', chart: true,
        what: 'The triangles a diffuse ray is tested against, on average.',
    },
];

const $ = (id) => document.getElementById(id);
const label = (a, b) => treeLabel({ accel: a, builder: b });
const num = (r, key) => (r && r[key] !== null && r[key] !== undefined ? Number(r[key]) : null);
const plural = (n, word) => `${n} ${word}${n === 1 ? '' : 's'}`;

const POLL_MS = 400;
// Polls that find no daemon before the job is given up (a blip, a proxy restarting): a second apart.
const LOST_TRIES = 5;
// sessionStorage: the job running, and each model's last finished job ({model: {id, version}}).
const RUNNING_KEY = 'arbor.bench.running';
const DONE_KEY = 'arbor.bench.done';

function load(key) {
    try {
        return JSON.parse(sessionStorage.getItem(key) || 'null');
    } catch {
        return null;
    }
}
const store = (key, value) => (value === null ? sessionStorage.removeItem(key) : sessionStorage.setItem(key, JSON.stringify(value)));

/** Sets the progress line (a live region): only a new text, so that a poll saying the same is not read out again. */
function say(text) {
    const el = $('cmp-progress-text');
    if (el.textContent !== text) el.textContent = text;
}

/** A memory error's byte counts in MiB too, which a person compares at a glance: "needs 97574912 bytes (93.1 MiB)". */
function readableBytes(error) {
    if (!/memory budget/.test(error)) return error;
    return error.replace(/\b(\d{5,})(-byte| bytes)?/g, (_, n, unit) => `${n}${unit || ''} (${fmtBytes(Number(n))})`);
}

/** One of our figures as the table and the charts show it. */
const shown = (v) => fmt(v);

/** The trees whose figure for metric m is the best of the eight, or none until all eight are measured. Judged as
 *  shown: figures that read alike ("0.02" and "0.02", or "2" and "2.00") tie, all starred, not the raw smallest. */
function bestOf(m, ours) {
    const vals = TREES.map(([a, b]) => num(ours(a, b), m.key));
    if (vals.some((v) => v === null)) return new Set();
    const read = vals.map((v) => Number(shown(v).replace(/,/g, '')));
    const best = m.better === 'lower' ? Math.min(...read) : Math.max(...read);
    return new Set(TREES.filter((_, i) => read[i] === best).map(([a, b]) => `${a} ${b}`));
}

export class Compare {
    constructor(app) {
        this.app = app;
        this.job = null;          // {id, model, version, runs, peer, start, cancelling, lost, drawn}
        this.pollTimer = 0;
        this.results = new Map(); // model -> {version, rows, runs, peer}
        this.sort = { key: null, dir: 1 }; // null: the study's order
        this.shown = null;        // what the table and charts show: {model, rows, runs, peer, state}
        this.heldFocus = false;   // the Run or Cancel button had the focus when the last one was disabled
        $('cmp-start').addEventListener('click', () => this.start());
        $('cmp-cancel').addEventListener('click', () => this.cancel());
        $('cmp-table-wrap').addEventListener('click', (e) => {
            const b = e.target.closest('button[data-sort]');
            if (b) this.sortBy(b.dataset.sort);
        });
        $('cmp-defs').innerHTML = METRICS.map((m) => `<dt>${esc(m.title)}${m.unit ? ` <span class="muted">(${esc(m.unit)})</span>` : ''}</dt>
            <dd>${esc(m.what)} ${m.better === 'lower' ? 'Lower' : 'Higher'} is better.${studyTable(m.key) ? ` The study's table ${studyTable(m.key)}.` : ''}</dd>`).join('');
        this.resume();
    }

    /** The model's version on the daemon (a replaced model has a new one), or undefined before the listing. */
    version(model) {
        return this.app.models.get(model)?.version;
    }

    /** The viewer's model changed: its figures and no status, unless a job's are being drawn (they stay until it ends). */
    modelChanged() {
        if (this.job) {
            this.note();
            return;
        }
        // the last run's progress and error were another model's
        $('cmp-progress-wrap').hidden = true;
        this.setError('');
        this.showResults();
    }

    /** The figures of the viewer's model's last finished run, or none (asking the daemon for one this tab ran before). */
    showResults() {
        const m = this.app.state.model;
        const r = this.results.get(m);
        const fresh = r && (r.version === undefined || r.version === this.version(m));
        this.draw(m, fresh ? r : null);
        if (!fresh) this.recall(m);
    }

    /** A job this tab finished for `model` before a reload: its rows, if the daemon still has them. */
    async recall(model) {
        const known = (load(DONE_KEY) || {})[model];
        if (!known || known.version !== this.version(model)) return;
        let j;
        try {
            j = await api.getJob(known.id);
        } catch {
            return; // the daemon restarted (its ids are its own) or dropped it: nothing to show
        }
        // a run that finished meanwhile is newer
        if (j.state !== 'done' || j.model !== model || (load(DONE_KEY) || {})[model]?.id !== known.id) return;
        this.results.set(model, { version: known.version, rows: j.rows || [], runs: known.runs, peer: known.peer });
        if (!this.job && this.app.state.model === model) this.showResults();
    }

    /** A job this tab started before a reload and that may still run: followed again. */
    resume() {
        const r = load(RUNNING_KEY);
        if (!r || !r.id) return;
        this.job = { ...r, start: performance.now(), cancelling: false, lost: 0, drawn: '' };
        this.running(true);
        say('following the benchmark started before…');
        this.poll();
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

    /** The buttons and the progress line of a job starting or running (on), or of none. A keyboard user's focus
     *  follows the button that can act next (Cancel once the daemon named the job, then Run again) rather than
     *  falling to the page when the focused button is disabled. */
    running(on) {
        const start = $('cmp-start'), cancel = $('cmp-cancel'), job = this.job;
        const focused = document.activeElement;
        const held = focused === start || focused === cancel || (focused === document.body && this.heldFocus);
        const ready = on && !!job && !!job.id;
        start.disabled = on;
        cancel.disabled = !ready;
        cancel.textContent = job && job.cancelling ? 'Cancelling…' : 'Cancel';
        if (on) $('cmp-progress-wrap').hidden = false;
        this.heldFocus = held;
        if (held && (ready || !on)) (on ? cancel : start).focus({ preventScroll: true });
    }

    async start() {
        const model = this.app.state.model;
        if (!model || this.job) return;
        const runs = Number($('cmp-runs').value) || 1;
        const peer = $('cmp-peer').value;
        // the job is this one from now on: a model chosen while the daemon answers does not hide its progress
        const job = { id: null, model, version: this.version(model), runs, peer, start: performance.now(), cancelling: false, lost: 0, drawn: '' };
        this.job = job;
        this.setError('');
        this.running(true); // Cancel waits for the daemon to name the job
        $('cmp-progress').removeAttribute('value'); // indeterminate until the job reports
        say('starting…');
        $('cmp-elapsed').textContent = '';
        const body = {
            model,
            accel: ['bvh', 'kd'],
            builder: ['spatial', 'median', 'mean', 'sah'],
            runs,
            embree: { embree: true, robust: 'robust' }[peer] || false,
        };
        let j;
        try {
            j = await withToken(`Starting the benchmark of ${model}`, () => api.startBench(body));
        } catch (e) {
            const wait = e.retryAfter ? ` Try again in ${plural(e.retryAfter, 'second')}.` : '';
            this.job = null;
            this.fail(`${e.words || String(e)}${wait}`);
            this.showResults();
            return;
        }
        job.id = j.id;
        store(RUNNING_KEY, { id: job.id, model, version: job.version, runs, peer });
        this.running(true);
        this.poll();
    }

    async poll() {
        const job = this.job;
        if (!job) return;
        let j;
        try {
            j = await api.getJob(job.id);
        } catch (e) {
            if (this.job !== job) return;
            if (e.status === 0 && ++job.lost <= LOST_TRIES) {
                say(`lost touch with the daemon (${e.daemonMessage || 'network error'}); trying again (${job.lost} of ${LOST_TRIES})…`);
                this.pollTimer = setTimeout(() => this.poll(), 1000);
                return;
            }
            this.ended(job, e.status === 404 ? `The benchmark of ${job.model} is no longer on the daemon, which keeps ` +
                'its jobs only until it restarts.' : e.words || String(e), null);
            return;
        }
        if (this.job !== job) return;
        job.lost = 0;
        const rows = j.rows || [];
        const p = j.progress || {};
        const done = Number(p.done) || 0, total = Number(p.total) || 0;
        const bar = $('cmp-progress');
        if (total > 0) { bar.max = total; bar.value = done; } else bar.removeAttribute('value');
        const ms = j.elapsed_ms ?? performance.now() - job.start;
        $('cmp-elapsed').textContent = `${(ms / 1000).toFixed(1)} s`;
        if (j.state === 'done') {
            this.results.set(job.model, { version: job.version, rows, runs: job.runs, peer: job.peer });
            store(DONE_KEY, { ...load(DONE_KEY), [job.model]: { id: job.id, version: job.version, runs: job.runs, peer: job.peer } });
            this.finish();
            const elsewhere = job.model !== this.app.state.model ? `, of ${job.model}: choose it to see them` : '';
            say(`done: ${plural(rows.length, 'row')} in ${(ms / 1000).toFixed(1)} s (${plural(job.runs, 'run')} each${elsewhere})`);
            this.showResults();
            return;
        }
        if (j.state === 'failed' || j.state === 'cancelled') {
            const run = this.results.has(job.model) ? 'The re-run of the benchmark' : 'The benchmark';
            this.ended(job, j.state === 'failed'
                ? `${run} of ${job.model} failed: ${j.error ? readableBytes(j.error) : 'the daemon gave no reason'}.`
                : `${run} of ${job.model} was cancelled.`, rows);
            return;
        }
        say(this.progressWords(job, j.state, rows, total));
        // drawn again only when there is something new: a redraw would take the focus from a sort button
        const drawn = `${j.state} ${rows.length}`;
        if (drawn !== job.drawn) {
            job.drawn = drawn;
            const last = this.results.get(job.model);
            if (j.state === 'running' && rows.length) this.draw(job.model, { rows, runs: job.runs, peer: job.peer }, 'running');
            else if (!last) this.draw(job.model, { rows, runs: job.runs, peer: job.peer }, j.state);
        }
        this.pollTimer = setTimeout(() => this.poll(), POLL_MS);
    }

    /** The progress line of a job queued or running: which tree is being measured, or what it waits for. */
    progressWords(job, state, rows, total) {
        if (job.cancelling) return 'cancelling: the daemon stops the job at its next check…';
        if (state === 'queued') return 'queued: another benchmark is running (the daemon runs one at a time)…';
        const next = TREES.find(([a, b]) => !rows.some((r) => r.accel === a && r.builder === b));
        const now = next ? `measuring ${label(...next)}` : 'measuring Embree';
        return `running: ${rows.length} of ${total || '?'} trees measured; ${now}…`;
    }

    async cancel() {
        const job = this.job;
        if (!job || !job.id || job.cancelling) return;
        job.cancelling = true;
        this.running(true);
        say(this.progressWords(job));
        try {
            await withToken(`Cancelling the benchmark of ${job.model}`, () => api.cancelJob(job.id));
        } catch (e) {
            if (this.job !== job) return;
            job.cancelling = false;
            this.running(true);
            this.setError(e.words || String(e));
        }
    }

    finish() {
        clearTimeout(this.pollTimer);
        this.job = null;
        store(RUNNING_KEY, null);
        this.running(false);
        this.note();
    }

    fail(text) {
        this.finish();
        $('cmp-progress-wrap').hidden = true;
        this.setError(text);
    }

    /** The job ended unfinished: the figures go back to the model's last finished run, or,
     *  without one, show what the job measured (rows) and which trees it did not. */
    ended(job, text, rows) {
        if (job.model !== this.app.state.model) {
            // the viewer moved on to another model meanwhile: its figures
            this.fail(text);
            this.showResults();
            return;
        }
        const last = this.results.get(job.model);
        this.fail(last ? `${text} The charts show the last finished run.` : text);
        this.draw(job.model, last || (rows && rows.length ? { rows, runs: job.runs, peer: job.peer } : null), last ? 'done' : 'ended');
    }

    /** Shows a run's figures (run: {rows, runs, peer}, or null) for a model; state: 'done', 'queued' or 'running'
     *  (figures still coming), or 'ended' (a run stopped short: what it did not measure is said so). */
    draw(model, run, state = 'done') {
        this.shown = run ? { model, ...run, state } : { model, state };
        this.render();
    }

    /** Sorts the table by a column (best first; again: the other way), or by tree: the study's order. */
    sortBy(key) {
        const m = METRICS.find((x) => x.key === key);
        if (!m) this.sort = { key: null, dir: 1 };
        else if (this.sort.key === key) this.sort = { key, dir: -this.sort.dir };
        else this.sort = { key, dir: m.better === 'lower' ? 1 : -1 };
        this.render();
    }

    /** Says when the figures shown are of another model than the one chosen (a job's, while it runs). */
    note() {
        const el = $('cmp-note');
        const chosen = this.app.state.model, shown = this.shown && this.shown.model;
        el.hidden = !this.job || !shown || shown === chosen;
        el.textContent = el.hidden ? '' : `These are ${shown}'s figures (its benchmark is running); ${chosen}, the model ` +
            'chosen, shows when the run ends or is cancelled.';
    }

    render() {
        const s = this.shown || { model: this.app.state.model };
        const model = s.model;
        // the heading names the model whose figures these are
        $('cmp-model').textContent = model || '—';
        const info = this.app.models.get(model);
        $('cmp-model-size').textContent = info ? `(${triangles(info.triangles)})` : '';
        this.note();
        const focusedSort = document.activeElement?.closest?.('#cmp-table-wrap') ? document.activeElement.dataset.sort : null;
        if (!s.rows) {
            $('cmp-results').hidden = true;
            $('cmp-table-wrap').innerHTML = '';
            $('charts').innerHTML = '';
            return;
        }
        const rows = s.rows;
        const v = {
            model,
            rows,
            state: s.state,
            partial: s.state === 'running' || s.state === 'queued',
            peerAsked: !!s.peer,
            ours: (a, b) => rows.find((r) => r.accel === a && r.builder === b) || null,
            embree: rows.find((r) => r.accel === 'embree') || null,
            study: hasStudy(model, info ? info.triangles : undefined),
        };
        v.best = new Map(METRICS.map((m) => [m.key, bestOf(m, v.ours)]));
        $('cmp-results').hidden = false;
        const first = rows.find((r) => r.threads);
        $('cmp-about').textContent = `Figures of ${model}: ${plural(s.runs || 1, 'run')} each (the median)` +
            (first ? `, ${plural(first.threads, 'thread')}, ${first.kernel} kernel.` : '.');
        $('cmp-legend').textContent = [
            'Under each heading: its unit, and whether lower or higher is better.',
            v.partial ? '★ marks the best of each column once all eight trees are measured.'
                : v.state === 'ended' ? 'This run stopped short: no column has a best.'
                    : '★ marks the best of the eight in each column.',
            v.study ? "In orange under ours, the study's figures (its tables 1–4)." : '',
        ].filter(Boolean).join(' ');
        $('cmp-table-wrap').innerHTML = this.tableHTML(v);
        if (focusedSort) $('cmp-table-wrap').querySelector(`button[data-sort="${focusedSort}"]`)?.focus();
        $('charts').innerHTML = METRICS.filter((m) => m.chart).map((m) => chartHTML(m, v)).join('') +
            (v.study ? `<p class="muted small chart-note">Study figures: ${esc(STUDY_SOURCE)}; measured on another machine
              and ray tracer (no BVH-SAH there), shown for shape, not as a race.</p>` : '');
    }

    /** The eight trees in the order chosen: sorted by a column, best first, trees without the figure last. */
    order(v) {
        const { key, dir } = this.sort;
        const list = TREES.map(([a, b]) => ({ a, b, r: v.ours(a, b) }));
        if (!key) return list;
        return list.sort((x, y) => {
            const p = num(x.r, key), q = num(y.r, key);
            if (p === null || q === null) return (p === null) - (q === null);
            return (p - q) * dir;
        });
    }

    /** The table of the eight trees (and Embree's row, beside), sortable by its headings' buttons. */
    tableHTML(v) {
        const { key, dir } = this.sort;
        const groups = [];
        for (const m of METRICS) {
            if (groups.length && groups.at(-1).name === m.group) groups.at(-1).n++;
            else groups.push({ name: m.group, n: 1 });
        }
        // a group's first column is ruled off from the one before
        const starts = new Set(METRICS.filter((m, i) => i > 0 && METRICS[i - 1].group !== m.group).map((m) => m.key));
        const classes = (...names) => (names.some(Boolean) ? ` class="${names.filter(Boolean).join(' ')}"` : '');
        const sortAttr = (k) => (key === k || (k === 'tree' && !key) ? ` aria-sort="${k === 'tree' || dir === 1 ? 'ascending' : 'descending'}"` : '');
        const arrow = (k) => (key === k ? `<span aria-hidden="true">${dir === 1 ? ' ▲' : ' ▼'}</span>` : '');
        const head = METRICS.map((m) => `<th scope="col" data-key="${m.key}"${classes(starts.has(m.key) && 'cmp-first')}${sortAttr(m.key)}>
            <button type="button" class="sort" data-sort="${m.key}" title="${esc(m.what)}">${esc(m.head)}${arrow(m.key)}
            <span class="unit">${esc(m.unit) || '&nbsp;'}</span><span class="unit">${m.better}</span></button></th>`).join('');
        const next = v.state === 'running' ? TREES.find(([a, b]) => !v.ours(a, b)) : null;
        const rowState = (a, b, r) => {
            if (r) return '';
            if (v.state === 'queued') return 'queued';
            if (v.partial) return next && next[0] === a && next[1] === b ? 'measuring…' : 'waiting';
            return 'not measured';
        };
        const body = this.order(v).map(({ a, b, r }) => {
            const state = rowState(a, b, r);
            // the study had no BVH SAH: said once for the row rather than under each figure
            const unstudied = v.study && studyFigure(v.model, 'build_ms', a, b) === null
                ? '<span class="study-fig">not in the study</span>' : '';
            const cells = METRICS.map((m) => {
                const val = num(r, m.key);
                const best = v.best.get(m.key).has(`${a} ${b}`);
                const fig = v.study ? studyFigure(v.model, m.key, a, b) : null;
                const study = fig === null ? '' : `<span class="study-fig">study ${fmt(fig)}</span>`;
                const text = val !== null ? shown(val) : state === 'measuring…' ? '…' : '—';
                return `<td data-key="${m.key}" data-value="${val ?? ''}"${classes(starts.has(m.key) && 'cmp-first', best && 'best')}>${text}${best
                    ? '<span class="best-mark" aria-hidden="true"> ★</span><span class="visually-hidden"> (best)</span>' : ''}${study}</td>`;
            }).join('');
            return `<tr data-accel="${a}" data-builder="${b}"${state ? ` class="pending" data-state="${state}"` : ''}>
                <th scope="row">${label(a, b)}${state ? `<span class="row-state">${state}</span>` : ''}${unstudied}</th>${cells}</tr>`;
        }).join('');
        let foot = '';
        if (v.embree || (v.peerAsked && v.partial)) {
            const e = v.embree;
            const name = e && e.builder === 'robust' ? 'Embree, robust' : 'Embree';
            foot = `<tfoot><tr class="peer" data-accel="embree"><th scope="row">${name}<span class="row-state">${e
                ? 'beside, not ranked' : 'its figures come last'}</span></th>${METRICS.map((m) => {
                const val = num(e, m.key);
                return `<td data-key="${m.key}" data-value="${val ?? ''}"${classes(starts.has(m.key) && 'cmp-first')}>${val === null ? '—' : fmt(val)}</td>`;
            }).join('')}</tr></tfoot>`;
        }
        return `<table id="cmp-table" class="cmp" aria-labelledby="cmp-about">
            <thead><tr><td></td>${groups.map((g) => `<th scope="colgroup" colspan="${g.n}" class="cmp-group">${g.name}</th>`).join('')}</tr>
            <tr><th scope="col"${sortAttr('tree')}><button type="button" class="sort" data-sort="tree" title="The study's order">Tree</button></th>${head}</tr></thead>
            <tbody>${body}</tbody>${foot}</table>`;
    }
}

// Axis ticks at least this far apart, so that they stay few, and their labels (each centred on its tick) at least
// this far from each other (SVG units).
const TICK_APART = 34, TICK_GAP = 10;
// A value label's width per character (10 px text, SVG units), a little over the widest digit.
const CHAR_W = 6.5;
const textW = (text) => text.length * CHAR_W;

/** The ticks ([x, label]) of an axis from 0 at k SVG units per unit, up to x = extent: at the finest
 *  1-2-5 step whose labels fit side by side, so that they read as round numbers. */
function ticks(k, extent) {
    for (let e = Math.floor(Math.log10(TICK_APART / k)); ; e++) {
        for (const m of [1, 2, 5]) {
            const step = m * 10 ** e, digits = Math.max(0, Math.ceil(-Math.log10(step) - 1e-9));
            const list = [];
            for (let i = 0; i * step * k <= extent + 0.01; i++) list.push([i * step * k, fmt(i * step, digits)]);
            if (step * k >= Math.max(TICK_APART, ...list.map((t) => textW(t[1]) + TICK_GAP))) return list;
        }
    }
}

/** A linear scale from zero (value -> SVG units from the axis), so that bars' lengths compare as their figures do:
 *  as long as the plot (plotW) lets it be, and as each bar's value label (text), past its end, lets it be within
 *  the room to the chart's edge. A tiny figure still gets a sliver. bars: [{value, text}]. */
function linearScale(bars, plotW, room) {
    const drawn = bars.filter((b) => b.value > 0);
    const k = Math.min(...drawn.map((b) => Math.min(plotW, room - 4 - textW(b.text)) / b.value));
    const scale = (x) => (x > 0 ? Math.max(2, x * k) : 0);
    scale.ticks = drawn.length ? ticks(k, plotW) : [];
    return scale;
}

/** One metric's bar chart of the eight trees (v: the view render() built), the best bar outlined and named. */
function chartHTML(c, v) {
    const table = v.study ? studyTable(c.key) : 0;
    const rows = TREES.map(([a, b]) => {
        const ours = num(v.ours(a, b), c.key), study = table ? studyFigure(v.model, c.key, a, b) : null;
        return {
            a, b, v: ours, s: study,
            text: ours === null ? (v.partial ? '…' : '—') : shown(ours),
            studyText: study === null ? 'not in the study' : `study ${fmt(study)}`,
        };
    });
    const e = c.line ? num(v.embree, c.key) : null;
    const W = 360, labelW = 84, valueW = 58, plotW = W - labelW - valueW;
    const barH = table ? 10 : 14, gap = table ? 9 : 7, groupH = table ? barH * 2 + 2 : barH;
    // a line above the bars for Embree's label
    const top = c.line && (e !== null || v.peerAsked) ? 20 : 6, H = top + TREES.length * (groupH + gap) + 16;
    // every figure drawn sets the scale; Embree's line has its label above the bars, none past its end
    const scale = linearScale(rows.flatMap((r) => [{ value: r.v, text: r.text }, { value: r.s, text: r.studyText }])
        .concat([{ value: e, text: '' }]), plotW, W - labelW);
    const ex = e === null ? null : labelW + scale(e);
    // a bar's value label starts past the bar's end, or past Embree's line where it would cross it
    const valueAt = (end, y, text, cls = '') => {
        const x = end + 4, crosses = ex !== null && x - 2 < ex && x + textW(text) + 2 > ex;
        return `<text class="value${cls}" x="${(crosses ? ex + 4 : x).toFixed(1)}" y="${y}">${text}</text>`;
    };
    const best = v.best.get(c.key);
    let svg = '';
    rows.forEach((r, i) => {
        const y = top + i * (groupH + gap);
        const isBest = best.has(`${r.a} ${r.b}`) ? ' best' : '';
        svg += `<text x="${labelW - 6}" y="${y + barH - 2}" text-anchor="end">${label(r.a, r.b)}</text>`;
        const w = r.v === null ? 0 : scale(r.v);
        svg += `<rect class="bar ours${isBest}" x="${labelW}" y="${y}" width="${w.toFixed(1)}" height="${barH}" rx="2"
                 data-accel="${r.a}" data-builder="${r.b}" data-value="${r.v ?? ''}"><title>ours, ${label(r.a, r.b)}: ${r.text} ${c.unit}${isBest ? ' (best)' : ''}</title></rect>`;
        svg += valueAt(labelW + w, y + barH - 2, r.text, isBest);
        if (table) {
            const ys = y + barH + 2;
            const ws = r.s === null ? 0 : scale(r.s);
            if (r.s !== null) {
                svg += `<rect class="bar study" x="${labelW}" y="${ys}" width="${ws.toFixed(1)}" height="${barH}" rx="2"
                         data-accel="${r.a}" data-builder="${r.b}" data-value="${r.s}"><title>study, ${label(r.a, r.b)}: ${fmt(r.s)} ${c.unit}</title></rect>`;
                svg += valueAt(labelW + ws, ys + barH - 2, r.studyText);
            } else {
                svg += `<text class="value" x="${labelW + 2}" y="${ys + barH - 2}">${r.studyText}</text>`;
            }
        }
    });
    const axisY = top + TREES.length * (groupH + gap) - gap + 4;
    svg += `<line class="axis" x1="${labelW}" y1="${top - 2}" x2="${labelW}" y2="${axisY}"/>`;
    for (const [px, tick] of scale.ticks) {
        svg += `<text class="value tick" x="${(labelW + px).toFixed(1)}" y="${axisY + 11}" text-anchor="middle">${tick}</text>`;
    }
    const peer = v.embree && v.embree.builder === 'robust' ? 'Embree, robust' : 'Embree';
    if (ex !== null) {
        const right = ex > labelW + plotW / 2; // the label on the side with room
        svg += `<line class="embree" x1="${ex}" y1="${top - 2}" x2="${ex}" y2="${axisY}"/>`;
        svg += `<text class="embree-label" x="${right ? ex - 3 : ex + 3}" y="${top - 6}"
                 text-anchor="${right ? 'end' : 'start'}">${peer} ${fmt(e)}</text>`;
    }
    const bestNames = TREES.filter(([a, b]) => best.has(`${a} ${b}`)).map(([a, b]) => label(a, b)).join(', ');
    const aria = `${c.title} of the eight trees of ${v.model}${c.unit ? ', ' + c.unit : ''}, ${c.better} is better` +
        (bestNames ? `; best: ${bestNames}` : '') + (table ? `, with the study's table ${table} beside` : '');
    const scaleWords = [c.unit, `${c.better} is better`].filter(Boolean).join(', ');
    return `<figure class="card chart" data-metric="${c.key}">
        <h3>${esc(c.title)} <span class="muted small">(${esc(scaleWords)})</span></h3>
        <svg viewBox="0 0 ${W} ${H}" role="img" aria-label="${esc(aria)}">${svg}</svg>
        <figcaption class="key"><span><i class="swatch" style="background:var(--ours)"></i>ours (arbord)</span>
          ${table ? `<span><i class="swatch" style="background:var(--study)"></i>study, table ${table}</span>` : ''}
          ${e !== null ? `<span><i class="swatch" style="background:var(--embree)"></i>${peer}</span>` : ''}
          ${bestNames ? `<span class="best-key"><i class="swatch best"></i>best: ${bestNames}</span>` : ''}</figcaption>
      </figure>`;
}
