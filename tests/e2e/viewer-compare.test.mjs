// viewer-compare.test.mjs - the "Compare trees" tab as its users use it: its
// table holds the bench job's figures (and /api/stats' for the same trees),
// marks the real best of each column and sorts from the keyboard; a running
// job says which tree it measures and which wait (its redraws keeping a sort
// button's focus); a model chosen mid-run or replaced never shows another's
// figures; errors (over the memory budget, a busy daemon, a job the daemon
// lost) read plainly; Cancel is reachable and says it is cancelling; a reload
// follows the job; the study's figures are STUDY.md's and only for the
// study's meshes; the charts' bars are linear from zero, their lengths
// comparing as their figures do; figures that read alike in the table are all
// the best; a phone shows the model first and scrolls the table inside its
// card.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { withViewer, screenshot, repo } from './lib.mjs';

const T = { timeout: 180000 };
const TREES = [['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'], ['bvh', 'sah'], ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah']];
// the figures of a bench row the table shows, and which way is better
const LOWER = ['build_ms', 'render_ms', 'sah_cost', 'mean_leaf_depth', 'mean_tris_per_leaf', 'bytes_per_tri', 'diffuse_nodes_per_ray', 'diffuse_tris_per_ray'];
const HIGHER = ['primary_mrays', 'diffuse_mrays', 'shadow_mrays'];
const METRICS = [...LOWER, ...HIGHER];
// requests a test refuses on purpose (a 404, a 503) are logged by the browser
const unprovoked = (errors) => errors.filter((e) => !/Failed to load resource/.test(e));

/** Rows of a bench job on `model` for the first n trees: every figure different, so each column has one best. */
function rowsFor(model, n = 8) {
    return TREES.slice(0, n).map(([accel, builder], i) => ({
        model, accel, builder, triangles: 36, kernel: 'avx2', threads: 2,
        ...Object.fromEntries(METRICS.map((k, j) => [k, (j + 1) * 10 + ((i * 5 + j * 3) % 8) + 0.25])),
    }));
}

/**
 * Serves the page's bench job from `job` ({id, model, state, rows, error, total: 9 with Embree}), which the test changes as the run
 * goes on: POST /api/bench starts it, GET /api/jobs/{id} reads it, DELETE asks to cancel (counted in `seen`).
 */
async function fakeBench(page, job) {
    const seen = { posts: [], deletes: 0 };
    await page.route('**/api/bench', (r) => {
        seen.posts.push(JSON.parse(r.request().postData()));
        r.fulfill({ status: 202, json: { id: job.id, model: job.model, state: 'queued' } });
    });
    await page.route(/\/api\/jobs\/[^/]+$/, (r) => {
        if (!r.request().url().endsWith(`/api/jobs/${job.id}`)) return r.fulfill({ status: 404, json: { error: { code: 'not_found', message: 'no job' } } });
        if (r.request().method() === 'DELETE') seen.deletes++;
        const total = job.total ?? 8;
        r.fulfill({
            json: {
                id: job.id, model: job.model, state: job.state, progress: { done: job.state === 'done' ? total : job.rows.length, total },
                elapsed_ms: 1234, rows: job.rows, error: job.error ?? null,
            },
        });
    });
    return seen;
}

/** The table as shown: per row the tree, its state, and each column's value (data-value) and shown text. */
function table(page) {
    return page.$$eval('#cmp-table tbody tr', (trs) => trs.map((tr) => ({
        tree: `${tr.dataset.accel} ${tr.dataset.builder}`,
        state: tr.dataset.state || '',
        cells: Object.fromEntries([...tr.querySelectorAll('td')].map((td) => [td.dataset.key, {
            value: td.dataset.value === '' ? null : Number(td.dataset.value),
            text: td.childNodes[0].textContent,
            best: td.classList.contains('best'),
            study: td.querySelector('.study-fig')?.textContent ?? null,
        }])),
        head: tr.querySelector('th').textContent,
    })));
}

const progress = (page) => page.textContent('#cmp-progress-text');
const waitProgress = (page, re, timeout) => page.waitForFunction((src) => new RegExp(src).test(document.getElementById('cmp-progress-text').textContent), re.source, { timeout });

/** The trees whose figure for metric k is the best as the table shows it (shown: table()'s rows): figures that
 *  read alike tie, all the best. */
function bestTrees(shown, k) {
    const read = shown.map((r) => Number(r.cells[k].text.replace(/,/g, '')));
    const best = LOWER.includes(k) ? Math.min(...read) : Math.max(...read);
    return shown.filter((_, i) => read[i] === best).map((r) => r.tree).sort();
}

test("the table holds the bench job's figures and /api/stats', marks each column's real best, and sorts from the keyboard", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const ids = [];
        page.on('response', async (r) => {
            if (new URL(r.url()).pathname === '/api/bench' && r.request().method() === 'POST') ids.push((await r.json()).id);
        });
        await page.goto(`${d.base}/?model=cornell&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'cornell');
        await page.click('#cmp-start');
        // a real benchmark: about 28 s under ASan beside two busy cores, past Playwright's default 30 s wait
        await waitProgress(page, /^done/, 150000);
        assert.equal(await page.isHidden('#cmp-error'), true, await page.textContent('#cmp-error'));
        const job = await fetch(`${d.base}/api/jobs/${ids[0]}`).then((r) => r.json());
        assert.equal(job.rows.length, 8);
        const shown = await table(page);
        assert.deepEqual(shown.map((r) => r.tree), TREES.map((t) => t.join(' ')), 'not the study\'s order');
        for (const r of job.rows) {
            const row = shown.find((s) => s.tree === `${r.accel} ${r.builder}`);
            assert.equal(row.state, '', `${row.tree} still says ${row.state}`);
            for (const k of METRICS) {
                const c = row.cells[k];
                assert.equal(c.value, r[k], `${row.tree} ${k}`);
                // the text is the figure rounded to the decimals it shows
                const digits = (c.text.split('.')[1] || '').length;
                assert.ok(Math.abs(Number(c.text.replace(/,/g, '')) - r[k]) <= 0.5 * 10 ** -digits + 1e-9, `${row.tree} ${k}: "${c.text}" for ${r[k]}`);
            }
        }
        for (const k of METRICS) {
            const marked = shown.filter((r) => r.cells[k].best).map((r) => r.tree).sort();
            assert.deepEqual(marked, bestTrees(shown, k), `${k}: the best marked`);
            const bars = await page.$$eval(`figure.chart[data-metric="${k}"] rect.bar.ours.best`, (rs) => rs.map((r) => `${r.dataset.accel} ${r.dataset.builder}`).sort());
            if (k !== 'bytes_per_tri') assert.deepEqual(bars, bestTrees(shown, k), `${k}: the best bar`);
        }
        // the tree figures are /api/stats' for the same trees (a bvh's bytes: its wide tree's, which rays traverse)
        for (const [accel, builder] of TREES) {
            const st = (await fetch(`${d.base}/api/stats?model=cornell&accel=${accel}&builder=${builder}`).then((r) => r.json())).trees[0];
            const row = shown.find((s) => s.tree === `${accel} ${builder}`).cells;
            for (const k of ['sah_cost', 'mean_leaf_depth', 'mean_tris_per_leaf']) {
                assert.ok(Math.abs(row[k].value - st[k]) <= 1e-9 * Math.abs(st[k]), `${accel} ${builder} ${k}: ${row[k].value} shown, ${st[k]} in /api/stats`);
            }
            const bytes = (st.wide || st).bytes / st.triangles;
            assert.ok(Math.abs(row.bytes_per_tri.value - bytes) <= 1e-9 * bytes, `${accel} ${builder} bytes per triangle`);
        }
        // sorting from the keyboard: best first, again the other way; the focus stays on the heading
        const order = async () => (await table(page)).map((r) => r.tree);
        const sorted = (k, dir) => [...job.rows].sort((a, b) => (a[k] - b[k]) * dir).map((r) => `${r.accel} ${r.builder}`);
        await page.focus('button[data-sort="render_ms"]');
        await page.keyboard.press('Enter');
        assert.deepEqual(await order(), sorted('render_ms', 1));
        assert.equal(await page.getAttribute('th[data-key="render_ms"]', 'aria-sort'), 'ascending');
        await page.keyboard.press('Space');
        assert.deepEqual(await order(), sorted('render_ms', -1));
        assert.equal(await page.getAttribute('th[data-key="render_ms"]', 'aria-sort'), 'descending');
        assert.equal(await page.evaluate(() => document.activeElement.dataset.sort), 'render_ms');
        await page.click('button[data-sort="primary_mrays"]');
        assert.deepEqual(await order(), sorted('primary_mrays', -1), 'a rate sorts highest first');
        await page.click('button[data-sort="tree"]');
        assert.deepEqual(await order(), TREES.map((t) => t.join(' ')));
        await screenshot(page, 'compare-table');
        assert.deepEqual(errors, []);
    });
});

test('while a job runs the table says which tree is being measured and which wait, and marks a best only once all are in', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // a daemon with Embree, so that its row is asked for
        await page.route('**/api/stats', async (route) => {
            const res = await route.fetch();
            const json = await res.json();
            route.fulfill({ response: res, json: { ...json, daemon: { ...json.daemon, embree: true } } });
        });
        const job = { id: '31', model: 'sphere', state: 'queued', rows: [], total: 9 };
        const seen = await fakeBench(page, job);
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.selectOption('#cmp-peer', 'embree');
        await page.click('#cmp-start');
        await waitProgress(page, /^queued: another benchmark is running/);
        await page.waitForSelector('#cmp-table');
        assert.deepEqual((await table(page)).map((r) => r.state), Array(8).fill('queued'));
        job.state = 'running';
        job.rows = rowsFor('sphere', 3);
        await waitProgress(page, /^running: 3 of 9 trees measured; measuring BVH sah/);
        await page.waitForSelector('#cmp-table tbody tr[data-state="measuring…"]');
        const rows = await table(page);
        assert.deepEqual(rows.map((r) => r.state), ['', '', '', 'measuring…', 'waiting', 'waiting', 'waiting', 'waiting']);
        assert.equal(rows[3].tree, 'bvh sah');
        assert.deepEqual(rows.flatMap((r) => Object.values(r.cells)).filter((c) => c.best), [], 'a best marked before all eight were in');
        assert.equal(await page.locator('figure.chart rect.bar.best').count(), 0);
        assert.match(await page.textContent('#cmp-table tfoot'), /Embree\s*its figures come last/);
        await screenshot(page, 'compare-running');
        // a row coming in redraws the table: a keyboard user's sort button keeps the focus
        await page.focus('button[data-sort="build_ms"]');
        job.rows = rowsFor('sphere', 4);
        await page.waitForSelector('#cmp-table tbody tr[data-builder="spatial"][data-accel="kd"][data-state="measuring…"]');
        assert.equal(await page.evaluate(() => document.activeElement.dataset.sort), 'build_ms');
        job.state = 'done';
        job.rows = [...rowsFor('sphere'), { model: 'sphere', accel: 'embree', builder: 'default', build_ms: 1, primary_mrays: 999, diffuse_mrays: 999, shadow_mrays: 999 }];
        await waitProgress(page, /^done: 9 rows/);
        const done = await table(page);
        assert.deepEqual(done.map((r) => r.state), Array(8).fill(''));
        for (const k of METRICS) {
            assert.deepEqual(done.filter((r) => r.cells[k].best).map((r) => r.tree), bestTrees(done, k), `${k}: Embree is beside, not ranked`);
        }
        assert.equal(await page.getAttribute('#cmp-table tfoot td[data-key="primary_mrays"]', 'data-value'), '999');
        assert.equal(seen.posts[0].embree, true);
        assert.deepEqual(errors, []);
    });
});

test("a model chosen mid-run never shows another's figures, and a replaced model's are dropped", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const job = { id: '41', model: 'cornell', state: 'running', rows: rowsFor('cornell', 2) };
        await fakeBench(page, job);
        await page.goto(`${d.base}/?model=cornell&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'cornell');
        await page.click('#cmp-start');
        await page.waitForSelector('#cmp-table tbody tr[data-state="measuring…"]');
        await page.selectOption('#model', 'sphere');
        // the job's figures stay, named as cornell's, and the note says where sphere's are
        assert.equal(await page.textContent('#cmp-model'), 'cornell');
        assert.match(await page.textContent('#cmp-note'), /These are cornell's figures \(its benchmark is running\); sphere, the model chosen, shows when the run ends/);
        assert.equal(await page.isVisible('#cmp-note'), true);
        job.state = 'done';
        job.rows = rowsFor('cornell');
        await waitProgress(page, /^done: 8 rows .*of cornell: choose it to see them\)$/);
        assert.equal(await page.textContent('#cmp-model'), 'sphere');
        assert.equal(await page.isVisible('#cmp-results'), false, "cornell's figures under sphere's heading");
        assert.equal(await page.isVisible('#cmp-note'), false);
        await page.selectOption('#model', 'cornell');
        assert.deepEqual((await table(page)).map((r) => r.cells.build_ms.value), job.rows.map((r) => r.build_ms));

        // a model of the same name uploaded over it is another mesh: the old figures are not its own
        const upload = async (text) => page.setInputFiles('#file-input', { name: 'tri.obj', mimeType: 'text/plain', buffer: Buffer.from(text) });
        await upload('v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n');
        await page.waitForFunction(() => document.getElementById('model').value === 'tri');
        job.id = '42';
        job.model = 'tri';
        job.rows = rowsFor('tri');
        await page.click('#cmp-start');
        await waitProgress(page, /^done: 8 rows/);
        assert.equal(await page.isVisible('#cmp-results'), true);
        await upload('v 0 0 0\nv 2 0 0\nv 0 2 0\nv 2 2 0\nf 1 2 3\nf 2 4 3\n');
        await page.click('#upload-actions button:has-text("Replace")');
        await page.waitForFunction(() => /Uploaded "tri"/.test(document.getElementById('upload-text').textContent));
        assert.equal(await page.isVisible('#cmp-results'), false, 'the replaced model\'s figures are shown for the new one');
        assert.equal(await page.locator('figure.chart').count(), 0);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('errors read plainly: a benchmark over the memory budget, a busy daemon, a job the daemon no longer has', T, async () => {
    await withViewer({ daemon: { extraArgs: ['--max-memory', '40M', '--prebuild', 'none'] } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        const failed = () => page.waitForSelector('#cmp-error:not([hidden])');
        await page.click('#cmp-start');
        await failed();
        const memory = await page.textContent('#cmp-error');
        // the daemon's words, its byte counts in MiB too
        assert.match(memory, /^The benchmark of sphere failed: the benchmark needs \d+ bytes \([\d.]+ MiB\)/);
        assert.match(memory, /\b41943040(-byte| bytes) \(40\.0 MiB\)/);
        assert.equal(await page.isVisible('#cmp-progress-wrap'), false);
        assert.equal(await page.isDisabled('#cmp-start'), false);
        assert.equal(await page.getAttribute('#cmp-error', 'role'), 'alert');
        await screenshot(page, 'compare-memory');

        await page.route('**/api/bench', (r) => r.fulfill({
            status: 503, headers: { 'Retry-After': '10' },
            json: { error: { code: 'busy', message: '8 bench jobs are queued: try again when one has run' } },
        }));
        await page.click('#cmp-start');
        await page.waitForFunction(() => /busy/.test(document.getElementById('cmp-error').textContent));
        assert.match(await page.textContent('#cmp-error'), /the daemon is busy: 8 bench jobs are queued.*\(503 busy\)\. Try again in 10 seconds\.$/);
        assert.equal(await page.isDisabled('#cmp-start'), false);

        await page.unroute('**/api/bench');
        await page.route('**/api/bench', (r) => r.fulfill({ status: 202, json: { id: '7', state: 'queued' } }));
        await page.route('**/api/jobs/7', (r) => r.fulfill({ status: 404, json: { error: { code: 'not_found', message: 'no job 7' } } }));
        await page.click('#cmp-start');
        await page.waitForFunction(() => /no longer/.test(document.getElementById('cmp-error').textContent));
        assert.equal(await page.textContent('#cmp-error'),
            'The benchmark of sphere is no longer on the daemon, which keeps its jobs only until it restarts.');
        assert.equal(await page.isDisabled('#cmp-start'), false);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('Cancel by keyboard: the focus moves to it and back, it says it is cancelling, and the daemon is asked once', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const job = { id: '51', model: 'cornell', state: 'running', rows: rowsFor('cornell', 2) };
        const seen = await fakeBench(page, job);
        await page.goto(`${d.base}/?model=cornell&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'cornell');
        await page.focus('#cmp-start');
        await page.keyboard.press('Enter');
        await page.waitForFunction(() => document.activeElement && document.activeElement.id === 'cmp-cancel');
        await page.waitForSelector('#cmp-table tbody tr[data-state="measuring…"]');
        await page.keyboard.press('Enter');
        assert.equal(await page.textContent('#cmp-cancel'), 'Cancelling…');
        await waitProgress(page, /^cancelling: the daemon stops the job at its next check/);
        await page.keyboard.press('Enter');
        job.state = 'cancelled';
        job.error = 'benchmark cancelled';
        await page.waitForSelector('#cmp-error:not([hidden])');
        assert.equal(seen.deletes, 1, 'Cancel asked the daemon more than once');
        assert.equal(await page.textContent('#cmp-error'), 'The benchmark of cornell was cancelled.');
        assert.equal(await page.evaluate(() => document.activeElement.id), 'cmp-start');
        // what the job measured stays, the rest said to be unmeasured, and no best of a short run
        const rows = await table(page);
        assert.deepEqual(rows.map((r) => r.state), ['', '', ...Array(6).fill('not measured')]);
        assert.equal(rows.flatMap((r) => Object.values(r.cells)).filter((c) => c.best).length, 0);
        assert.deepEqual(errors, []);
    });
});

test('a reload follows the job running, and shows the finished run again', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const job = { id: '61', model: 'sphere', state: 'running', rows: rowsFor('sphere', 3) };
        await fakeBench(page, job);
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.click('#cmp-start');
        await waitProgress(page, /^running: 3 of 8/);
        await page.reload();
        await waitProgress(page, /^running: 3 of 8 trees measured; measuring BVH sah/);
        assert.equal(await page.isDisabled('#cmp-cancel'), false);
        assert.equal(await page.isDisabled('#cmp-start'), true, 'a second job could be started beside the first');
        job.state = 'done';
        job.rows = rowsFor('sphere');
        await waitProgress(page, /^done: 8 rows/);
        await page.reload();
        await page.waitForSelector('#cmp-table');
        assert.deepEqual((await table(page)).map((r) => r.cells.render_ms.value), job.rows.map((r) => r.render_ms));
        assert.equal(await page.isDisabled('#cmp-start'), false);
        assert.deepEqual(errors, []);
    });
});

/** The study's figures of a model, per metric, in its column order (STUDY.md's tables 1-4). */
function studyTables(model) {
    const text = fs.readFileSync(path.resolve(repo, process.env.ARBOR_SHARED_MODELS || '../shared/models', '..', 'STUDY.md'), 'utf8');
    const out = {};
    for (const [n, key] of [[1, 'build_ms'], [2, 'mean_leaf_depth'], [3, 'mean_tris_per_leaf'], [4, 'render_ms']]) {
        const after = text.slice(text.indexOf(`**Table ${n}:**`));
        const line = after.split('\n').find((l) => l.startsWith(`${model}\t`));
        out[key] = line.split('\t').slice(2).map((v) => Number(v.replace(/ms|,/g, '')));
    }
    return out;
}

test("the study's figures under ours are STUDY.md's, and only for a model of the study's mesh", T, async () => {
    await withViewer({ daemon: { shared: ['castle.obj'] } }, async (d, { page, errors }) => {
        // a model named as the study's, another mesh
        const put = await fetch(`${d.base}/api/models/galleon`, { method: 'PUT', body: 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' });
        assert.equal(put.status, 201, await put.text());
        const job = { id: '71', model: 'castle', state: 'done', rows: rowsFor('castle') };
        await fakeBench(page, job);
        await page.goto(`${d.base}/?model=castle&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'castle');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        const study = studyTables('castle');
        const rows = await table(page);
        const studied = TREES.filter(([a, b]) => !(a === 'bvh' && b === 'sah'));
        for (const [key, figures] of Object.entries(study)) {
            const shown = studied.map(([a, b]) => rows.find((r) => r.tree === `${a} ${b}`).cells[key].study);
            assert.deepEqual(shown, figures.map((v) => `study ${v.toLocaleString('en-US')}`), key);
            assert.equal(await page.locator(`figure.chart[data-metric="${key}"] rect.bar.study`).count(), 7);
        }
        assert.match(rows.find((r) => r.tree === 'bvh sah').head, /not in the study/);
        assert.equal(await page.locator('#cmp-table .study-fig').count(), 7 * 4 + 1);

        job.id = '72';
        job.model = 'galleon';
        job.rows = rowsFor('galleon');
        await page.selectOption('#model', 'galleon');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        assert.equal(await page.textContent('#cmp-model'), 'galleon');
        assert.equal(await page.locator('#cmp-table tbody tr').count(), 8);
        assert.equal(await page.locator('#cmp-table .study-fig, figure.chart rect.bar.study, .chart-note').count(), 0,
            "the study's galleon figures beside a one-triangle galleon");
        assert.deepEqual(errors, []);
    });
});

/**
 * A chart as drawn, in CSS pixels: its bars (ours and the study's: figure, left end, width), its axis ticks
 * (figure read from the label, centre) and Embree's line (its x), if any.
 */
function chart(page, key) {
    return page.$eval(`figure.chart[data-metric="${key}"]`, (fig) => {
        const box = (el) => el.getBoundingClientRect();
        return {
            bars: [...fig.querySelectorAll('rect.bar')].map((r) => ({
                what: `${r.classList.contains('study') ? 'study' : 'ours'} ${r.dataset.accel} ${r.dataset.builder}`,
                value: Number(r.dataset.value), left: box(r).left, width: box(r).width,
            })),
            ticks: [...fig.querySelectorAll('text.tick')].map((t) => ({
                text: t.textContent, value: Number(t.textContent.replace(/,/g, '')), x: box(t).left + box(t).width / 2,
            })),
            embree: fig.querySelector('line.embree') ? box(fig.querySelector('line.embree')).left + box(fig.querySelector('line.embree')).width / 2 : null,
            // SVG units are scaled to the figure's width
            unit: box(fig.querySelector('svg')).width / fig.querySelector('svg').viewBox.baseVal.width,
        };
    });
}

/** Asserts a chart is linear from zero: each bar's length (a tiny figure's sliver aside), each tick and Embree's
 *  line (figure e) at its figure times one scale, within 1 px; ticks at a 1-2-5 step from 0. */
function assertLinear(c, key, e = null) {
    const longest = c.bars.reduce((a, b) => (b.width > a.width ? b : a));
    const k = longest.width / longest.value; // px per unit
    const x0 = longest.left;
    for (const b of c.bars) {
        const want = b.value * k;
        // a figure under a couple of SVG units is drawn as a sliver
        if (want < 3 * c.unit) assert.ok(b.width >= 1.5 * c.unit && b.width <= 3 * c.unit + 1, `${key} ${b.what}: ${b.width} px for ${b.value}, not a sliver`);
        else assert.ok(Math.abs(b.width - want) <= 1, `${key} ${b.what}: ${b.width.toFixed(1)} px for ${b.value}, ${want.toFixed(1)} px by the longest bar's scale`);
        assert.ok(Math.abs(b.left - x0) <= 0.5, `${key} ${b.what} does not start at the axis`);
    }
    assert.ok(c.ticks.length >= 2, `${key}: ${c.ticks.length} ticks`);
    assert.equal(c.ticks[0].text, '0', `${key}: the axis does not start at 0`);
    const step = c.ticks[1].value;
    const mantissa = Number((step / 10 ** Math.floor(Math.log10(step))).toPrecision(6));
    assert.ok([1, 2, 5].includes(mantissa), `${key}: a tick step of ${step}, not a round 1-2-5 one`);
    c.ticks.forEach((t, i) => {
        assert.ok(Math.abs(t.value - i * step) <= step * 1e-6, `${key}: tick ${i} says ${t.text}, not ${i * step}`);
        assert.ok(Math.abs(t.x - x0 - t.value * k) <= 1, `${key}: tick ${t.text} at ${(t.x - x0).toFixed(1)} px, ${(t.value * k).toFixed(1)} px by the bars' scale`);
    });
    if (e !== null) assert.ok(Math.abs(c.embree - x0 - e * k) <= 1, `${key}: Embree's line at ${(c.embree - x0).toFixed(1)} px, ${(e * k).toFixed(1)} px by the bars' scale`);
}

test("the charts are linear from zero: a bar's length, a tick's and Embree's line's place are their figures'", T, async () => {
    await withViewer({ daemon: { shared: ['castle.obj'] } }, async (d, { page, errors }) => {
        // times far apart: a log scale drew a 2.4 times longer time about 21 times longer
        const times = { build_ms: [0.5, 1.2, 0.8, 3.1, 2.4, 12, 7.5, 1], render_ms: [100, 240, 180, 130, 410, 95, 150, 60] };
        const rows = rowsFor('sphere').map((r, i) => ({ ...r, build_ms: times.build_ms[i], render_ms: times.render_ms[i] }));
        const embree = { model: 'sphere', accel: 'embree', builder: 'default', build_ms: 0.3, primary_mrays: 150, diffuse_mrays: 40, shadow_mrays: 90 };
        const job = { id: '91', model: 'sphere', state: 'done', rows: [...rows, embree] };
        await fakeBench(page, job);
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        const keys = await page.$$eval('figure.chart', (fs) => fs.map((f) => f.dataset.metric));
        assert.ok(keys.includes('build_ms') && keys.includes('render_ms'), keys.join());
        for (const key of keys) assertLinear(await chart(page, key), key, embree[key] !== undefined && /mrays/.test(key) ? embree[key] : null);
        assert.doesNotMatch(await page.textContent('#charts'), /log/i);
        await screenshot(page, 'compare-charts');

        // the study's figures beside ours are on the same scale (its build times dwarf ours: slivers)
        job.id = '92';
        job.model = 'castle';
        job.rows = rowsFor('castle').map((r, i) => ({ ...r, render_ms: times.render_ms[i] * 10 }));
        await page.selectOption('#model', 'castle');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        for (const key of ['build_ms', 'render_ms']) {
            const c = await chart(page, key);
            assert.equal(c.bars.filter((b) => b.what.startsWith('study')).length, 7, key);
            assertLinear(c, key);
        }
        await screenshot(page, 'compare-charts-study');
        assert.deepEqual(errors, []);
    });
});

test('figures that read alike at the precision shown are all the best, starred in the table and outlined in the chart', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // BVH builds all shown as 0.02 ms, k-d's 0.026 as 0.03; primary rates 51.004 and 50.996 both shown as 51.00;
        // a whole depth of 2 shown as "2" beside 2.001 and 2.004 shown as "2.00", the same figure
        const build = [0.021, 0.018, 0.024, 0.019, 0.031, 0.05, 0.026, 1.2];
        const primary = [51.004, 50.996, 50.994, 40.5, 30.5, 20.5, 10.5, 45.5];
        const depth = [3.5, 2.001, 2.006, 2.5, 2, 4.5, 2.004, 5.5];
        const rows = rowsFor('sphere').map((r, i) => ({ ...r, build_ms: build[i], primary_mrays: primary[i], mean_leaf_depth: depth[i] }));
        await fakeBench(page, { id: '95', model: 'sphere', state: 'done', rows });
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        const shown = await table(page);
        const want = {
            build_ms: { texts: ['0.02', '0.02', '0.02', '0.02', '0.03', '0.05', '0.03', '1.20'], best: ['bvh mean', 'bvh median', 'bvh sah', 'bvh spatial'] },
            primary_mrays: { texts: ['51.00', '51.00', '50.99', '40.50', '30.50', '20.50', '10.50', '45.50'], best: ['bvh median', 'bvh spatial'] },
            mean_leaf_depth: { texts: ['3.50', '2.00', '2.01', '2.50', '2', '4.50', '2.00', '5.50'], best: ['bvh median', 'kd mean', 'kd spatial'] },
        };
        for (const [k, { texts, best }] of Object.entries(want)) {
            assert.deepEqual(shown.map((r) => r.cells[k].text), texts, `${k}: the figures shown`);
            assert.deepEqual(shown.filter((r) => r.cells[k].best).map((r) => r.tree).sort(), best, `${k}: the trees starred`);
            const stars = await page.$$eval(`#cmp-table tbody td[data-key="${k}"]`, (tds) => tds.filter((td) => td.querySelector('.best-mark')).length);
            assert.equal(stars, best.length, `${k}: the stars`);
            const bars = await page.$$eval(`figure.chart[data-metric="${k}"] rect.bar.ours.best`, (rs) => rs.map((r) => `${r.dataset.accel} ${r.dataset.builder}`).sort());
            assert.deepEqual(bars, best, `${k}: the bars outlined as best`);
            const named = best.map((t) => t.replace(/^bvh/, 'BVH').replace(/^kd/, 'k-d'));
            const key = await page.textContent(`figure.chart[data-metric="${k}"] .best-key`);
            assert.deepEqual(key.replace(/^best: /, '').split(', ').sort(), named.sort(), `${k}: the chart's key`);
        }
        assert.deepEqual(errors, []);
    });
});

test('at phone width the model comes before the figures, and the table scrolls in its card, its trees in view', T, async () => {
    await withViewer({ browser: { viewport: { width: 390, height: 844 }, mobile: true, colorScheme: 'light' } }, async (d, { page, errors }) => {
        const job = { id: '81', model: 'sphere', state: 'done', rows: rowsFor('sphere') };
        await fakeBench(page, job);
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.click('#cmp-start');
        await waitProgress(page, /^done/);
        const layout = await page.evaluate(() => {
            const box = (s) => document.querySelector(s).getBoundingClientRect();
            const wrap = document.querySelector('.cmp-table-wrap');
            const th = () => document.querySelector('#cmp-table tbody th').getBoundingClientRect().left;
            const before = th();
            wrap.scrollLeft = 300;
            return {
                page: document.documentElement.scrollWidth,
                model: box('#model').bottom, section: box('#compare-section').top,
                scrolls: wrap.scrollWidth > wrap.clientWidth && wrap.scrollLeft > 0,
                stays: Math.abs(th() - before) < 1,
            };
        });
        await screenshot(page, 'compare-phone');
        // a phone widens its layout to what sticks out (innerWidth too): the page must stay the screen's 390 px
        assert.ok(layout.page <= 390, `the page is ${layout.page} px wide on a 390 px screen`);
        assert.ok(layout.model < layout.section, 'the model is chosen below the figures');
        assert.ok(layout.scrolls, 'the table does not scroll inside its card');
        assert.ok(layout.stays, "the trees' names scroll out of view");
        assert.deepEqual(errors, []);
    });
});
