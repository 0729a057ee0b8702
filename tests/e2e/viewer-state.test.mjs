// viewer-state.test.mjs - the viewer keeps what it shows true to what was
// chosen: a model replaced or switched, a tree left while it builds, a new
// resolution, the daemon's samples budget, a daemon that fails for a while,
// the compare heading during a run, an upload's error, and an overlay of many
// boxes drawn once, in few strokes.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import {
    withViewer, screenshot, recordRequests, waitFullFrame, framePixels, overlayBox, afterPaint,
} from './lib.mjs';

const T = { timeout: 180000 };
// a request the test broke on purpose (route.abort, a 400 it provoked) is logged by the browser
const unprovoked = (errors) => errors.filter((e) => !/Failed to load resource/.test(e));
// API.md: the samples a request costs, against the daemon's --max-pixels
const cost = (r) => (r.region ? r.region.h : r.height) * (r.region ? r.region.w : r.width) * r.spp
    * (r.mode === 'ao' ? r.ao_samples ?? 8 : 1);

/** Holds every frame request the page makes until release() (those it gave up on are let go quietly). */
async function holdFrames(page) {
    const held = [];
    await page.route('**/api/render', (route) => { held.push(route); });
    return {
        held,
        async release() {
            await page.unroute('**/api/render');
            for (const r of held) await r.continue().catch(() => {});
        },
    };
}

/** Waits until pane 0 shows a full frame of the tree and settings `want` has (model, accel, spp...). */
function waitShown(page, want, timeout = 30000) {
    return page.waitForFunction((w) => {
        const s = window.arbor.panes[0].shown;
        return s && !s.quick && Object.entries(w).every(([k, v]) => s.req[k] === v);
    }, want, { timeout });
}

async function upload(page, name, text) {
    await page.setInputFiles('#file-input', { name, mimeType: 'text/plain', buffer: Buffer.from(text) });
}

const TRIANGLE = 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n';
const SLOPE = 'v 0 0 0\nv 3 0 0\nv 3 1 1\nv 0 1 1\nf 1 2 3\nf 1 3 4\n';

test('replacing an uploaded model shows the new model, its statistics and boxes', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1&depth=0`);
        await waitFullFrame(page);
        // the model's statistics, root box (its bounds' x) and a full frame
        const settled = (triangles, x) => page.waitForFunction(([n, x]) => {
            const p = window.arbor.panes[0];
            return window.arbor.state.model === 'shape' && p.stats?.triangles === n && p.boxes?.data?.boxes[0]?.max[0] === x
                && p.shown && !p.shown.quick;
        }, [triangles, x], { timeout: 30000 });
        await upload(page, 'shape.obj', TRIANGLE);
        await settled(1, 1);
        assert.match(await page.textContent('#upload-text'), /: 1 triangle\.$/);
        const before = await framePixels(page);
        const rootBefore = await page.evaluate(() => window.arbor.panes[0].boxes.data.boxes[0]);
        await upload(page, 'shape.obj', SLOPE);
        await page.click('#upload-actions button:text-is("Replace \\"shape\\"")');
        await settled(2, 3);
        await screenshot(page, 'replaced-model');
        const root = await page.evaluate(() => window.arbor.panes[0].boxes.data.boxes[0]);
        assert.deepEqual(root.max, [3, 1, 1], `the boxes are the old model's: ${JSON.stringify(rootBefore)} then ${JSON.stringify(root)}`);
        assert.notEqual((await framePixels(page)).hash, before.hash, 'the frame is the old model\'s');
        assert.equal(await page.$eval('#model option[value="shape"]', (o) => o.textContent), 'shape (2 triangles)');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('switching models clears the old frame: no new boxes over it', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1&depth=0`);
        await waitFullFrame(page);
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data);
        await afterPaint(page);
        assert.ok(await overlayBox(page, 0, 640, 480), 'no boxes over the first frame');
        const frames = await holdFrames(page);
        await page.selectOption('#model', 'sphere');
        // sphere's root box: up to y = 1 (cornell's: 2)
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.boxes[0]?.max[1] < 1.5);
        await afterPaint(page);
        await screenshot(page, 'model-switch-waiting');
        assert.equal((await framePixels(page)).fg, 0, 'the old model\'s frame is still shown');
        assert.equal(await overlayBox(page, 0, 640, 480), null, 'the new model\'s boxes are drawn without its frame');
        await frames.release();
        await waitShown(page, { model: 'sphere' });
        await afterPaint(page);
        assert.ok(await overlayBox(page, 0, 640, 480), 'no boxes over the new frame');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('leaving a tree that is still building: the newest choice is rendered and the badge goes', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // median builds never end in this test: their statistics are held
        const held = [];
        await page.route('**/api/stats?*builder=median*', (route) => { held.push(route); });
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        await page.selectOption('#accel', 'kd');
        await page.selectOption('#builder', 'median');
        await page.waitForFunction(() => /building k-d median/.test(document.querySelector('.badge.building').textContent)
            && !document.querySelector('.badge.building').hidden);
        // through BVH median, another build that does not end
        await page.selectOption('#accel', 'bvh');
        await page.waitForFunction(() => /building BVH median/.test(document.querySelector('.badge.building').textContent));
        await page.selectOption('#builder', 'sah');
        await waitShown(page, { accel: 'bvh', builder: 'sah' }, 15000);
        assert.equal(await page.textContent('.pane-title .tree-name'), 'BVH sah · shaded');
        await page.waitForTimeout(300);
        assert.equal(await page.$eval('.badge.building', (b) => b.hidden), true, 'the badge of the build left behind stays');
        await page.unroute('**/api/stats?*builder=median*');
        for (const r of held) await r.continue().catch(() => {});
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('frames, boxes and statistics that failed while the daemon was away are asked again, unasked', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // the first frame, the first boxes and the first k-d mean statistics find no daemon
        const failFirst = async (pattern) => {
            let failed = false;
            await page.route(pattern, (route) => {
                if (failed) return route.continue();
                failed = true;
                return route.abort('connectionrefused');
            });
        };
        await failFirst('**/api/render');
        await failFirst('**/boxes?*');
        await failFirst('**/api/stats?*accel=kd&builder=mean*');
        await page.goto(`${d.base}/?model=cornell&spp=1&depth=0`);
        await page.waitForFunction(() => /could not be reached/.test(document.querySelector('.badge.error').textContent));
        await waitFullFrame(page);
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data, null, { timeout: 15000 });
        assert.equal(await page.$eval('.badge.error', (b) => b.hidden), true);
        await page.selectOption('#accel', 'kd');
        await page.selectOption('#builder', 'mean');
        await page.waitForFunction(() => window.arbor.panes[0].stats?.error);
        await page.waitForFunction(() => window.arbor.panes[0].stats?.accel === 'kd' && window.arbor.panes[0].stats.builder === 'mean',
            null, { timeout: 15000 });
        await afterPaint(page);
        await screenshot(page, 'recovered');
        assert.match(await page.textContent('#stats-table tr[data-key="nodes"] td'), /\d/);
        assert.equal(await page.locator('.notice.error').count(), 0, 'the failed build\'s notice stays after its statistics came');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('a model list that fails at first: the daemon is named, the URL kept, the list asked again', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        let failures = 2;
        await page.route('**/api/models', (route) => (failures-- > 0 ? route.abort('connectionrefused') : route.continue()));
        await page.goto(`${d.base}/?model=sphere&spp=1`);
        await page.waitForSelector('.notice.error');
        const said = await page.textContent('.notice.error span');
        assert.match(said, /could not be reached/);
        assert.doesNotMatch(said, /There is no model/);
        assert.match(page.url(), /model=sphere/);
        await waitShown(page, { model: 'sphere' });
        assert.match(page.url(), /model=sphere/);
        assert.equal(await page.locator('.notice.error').count(), 0, 'the failure stays said after the list came');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('a new resolution keeps the old frame unstretched until the first frame at it', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        const aspect = () => page.$eval('.frame', (f) => f.style.aspectRatio);
        assert.equal(await aspect(), '640 / 480');
        const frames = await holdFrames(page);
        await page.selectOption('#res', '1280x720');
        while (!frames.held.length) await page.waitForTimeout(50);
        await afterPaint(page);
        assert.equal(await aspect(), '640 / 480', 'the old frame is stretched to the new aspect');
        await frames.release();
        await waitShown(page, { width: 1280, height: 720 });
        assert.equal(await aspect(), '1280 / 720');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('frames over the default samples budget are split within it: ao and heat at 64 spp', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=cornell&mode=ao&spp=64`);
        await waitShown(page, { mode: 'ao', spp: 64 }, 120000);
        await page.selectOption('#mode', 'heat');
        await waitShown(page, { mode: 'heat', spp: 64 }, 120000);
        await screenshot(page, 'heat-64spp');
        assert.equal(await page.$eval('.badge.error', (b) => b.hidden), true);
        assert.deepEqual(rec.responses.filter((r) => r.status !== 200).map((r) => `${r.status} ${r.body}`), []);
        const over = rec.renders.filter((r) => cost(r) > 16777216);
        assert.deepEqual(over, [], 'requests over --max-pixels');
        const heat = rec.renders.filter((r) => r.mode === 'heat' && r.spp === 64);
        assert.ok(heat.length > 1 && heat.every((r) => r.region), 'the heat frame was not split');
        assert.equal(new Set(heat.map((r) => r.heat_scale)).size, 1, 'the strips of the heat frame have different colour scales');
        assert.ok(heat[0].heat_scale > 0);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test("a daemon's smaller --max-pixels: frames split by it, and what even a row exceeds is said and not offered", T, async () => {
    await withViewer({ daemon: { extraArgs: ['--max-pixels', '300000'] } }, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        // the page reads the daemon's limit (GET /api/stats) before its first frame: none is refused
        const refused = [];
        page.on('response', (r) => { if (r.url().includes('/api/render') && r.status() === 400) refused.push(r.url()); });
        await page.goto(`${d.base}/?model=cornell&spp=4`);
        await waitShown(page, { spp: 4 }, 60000);
        assert.equal(await page.$eval('.badge.error', (b) => b.hidden), true);
        const last = rec.renders.slice(-5);
        assert.ok(last.every((r) => r.region && cost(r) <= 300000), JSON.stringify(last.map((r) => r.region)));
        // ao at 64 spp: one row of 640 pixels costs 640 x 64 x 8 = 327,680 samples
        await page.selectOption('#spp', '64');
        await page.selectOption('#mode', 'ao');
        await page.waitForFunction(() => /--max-pixels 300,000/.test(document.querySelector('.badge.error').textContent));
        await screenshot(page, 'over-budget');
        await page.selectOption('#spp', '16');
        await waitShown(page, { mode: 'ao', spp: 16 }, 60000);
        assert.equal(await page.$eval('#spp option[value="64"]', (o) => o.disabled), true, '64 spp is offered');
        assert.equal(await page.$eval('#spp option[value="16"]', (o) => o.disabled), false);
        assert.deepEqual(refused, [], 'frames the daemon refused');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('the frame ms of a frame in strips is its wall time, not the sum of its strips', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // every strip says it rendered for 100 s: summed, four strips would make 400 s
        await page.route('**/api/render', async (route) => {
            const res = await route.fetch();
            await route.fulfill({ response: res, headers: { ...res.headers(), 'x-render-ms': '100000' } });
        });
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitShown(page, { spp: 1, width: 640 });
        const shown = await page.evaluate(() => {
            const s = window.arbor.panes[0].shown;
            return { renderMs: s.renderMs, rays: s.rays, mrays: s.mrays };
        });
        assert.ok(shown.renderMs > 0 && shown.renderMs < 100000, `frame ms ${shown.renderMs}`);
        assert.ok(Math.abs(shown.mrays - shown.rays / shown.renderMs / 1e3) < 1e-9);
        await afterPaint(page);
        const said = Number((await page.textContent('#stats-table tr[data-key="frame_ms"] td')).replace(/,/g, ''));
        assert.ok(said < 100000, `the stats say ${said} ms`);
        assert.deepEqual(errors, []);
    });
});

test("the BVH's depth slider ends at its wide tree's depth, whose boxes it shows", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1&depth=0`);
        await page.waitForFunction(() => window.arbor.panes[0].stats?.wide);
        const st = await page.evaluate(() => window.arbor.panes[0].stats);
        assert.notEqual(st.wide.max_depth, st.max_depth, 'cornell no longer tells the trees apart');
        await page.waitForFunction((m) => document.getElementById('depth').max === String(m), st.wide.max_depth);
        await page.selectOption('#accel', 'kd');
        await page.waitForFunction(() => window.arbor.panes[0].stats?.accel === 'kd');
        const kd = await page.evaluate(() => window.arbor.panes[0].stats.max_depth);
        await page.waitForFunction((m) => document.getElementById('depth').max === String(m), kd);
        assert.deepEqual(errors, []);
    });
});

test('the compare heading names the model whose bars are shown when the model changes mid-run', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rows = [{ model: 'cornell', accel: 'bvh', builder: 'spatial', build_ms: 1, render_ms: 2 }];
        let polls = 0, finish = false;
        await page.route('**/api/bench', (r) => r.fulfill({ status: 202, json: { id: '7', state: 'queued' } }));
        await page.route('**/api/jobs/7', (r) => {
            polls++;
            r.fulfill({ json: { id: '7', model: 'cornell', state: finish ? 'done' : 'running', progress: { done: 1, total: 8 }, elapsed_ms: 10, rows, error: null } });
        });
        await page.goto(`${d.base}/?model=cornell&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'cornell');
        await page.click('#cmp-start');
        await page.waitForFunction(() => document.querySelector('figure.chart rect.bar.ours[data-value="1"]'));
        await page.evaluate(() => window.arbor.setModel('sphere'));
        // two polls of the job after the switch
        for (const p = polls; polls < p + 2;) await page.waitForTimeout(50);
        assert.equal(await page.textContent('#cmp-model'), 'cornell', 'the heading names another model than the bars\'');
        finish = true;
        await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent));
        assert.equal(await page.textContent('#cmp-model'), 'sphere');
        assert.equal(await page.locator('figure.chart').count(), 0, 'cornell\'s bars under sphere\'s heading');
        await page.evaluate(() => window.arbor.setModel('cornell'));
        assert.equal(await page.textContent('#cmp-model'), 'cornell');
        assert.equal(await page.locator('figure.chart').count(), 10);
        assert.deepEqual(errors, []);
    });
});

test("an upload's error stays though an earlier upload's success would hide itself", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        await upload(page, 'good.obj', TRIANGLE);
        await page.waitForFunction(() => /^Uploaded/.test(document.getElementById('upload-text').textContent));
        await upload(page, 'bad.obj', 'v 0 0 0\nf 1 2 3\n');
        await page.waitForSelector('#upload-status.error');
        // past the success's 5 s
        await page.waitForTimeout(5500);
        assert.equal(await page.isVisible('#upload-status.error'), true, 'the error was hidden');
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('many boxes: drawn once per change, one stroke per colour, not redrawn for an unchanged camera', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.addInitScript(() => {
            window.overlayCalls = { clears: 0, strokes: 0, drawn: [] };
            const proto = CanvasRenderingContext2D.prototype;
            for (const [name, key] of [['clearRect', 'clears'], ['stroke', 'strokes']]) {
                const real = proto[name];
                proto[name] = function (...args) {
                    if (this.canvas.classList.contains('overlay')) {
                        window.overlayCalls[key]++;
                        // what each redraw was for, to say in a failure: the pane, its camera, canvas and boxes drawn
                        const i = key === 'clears' ? window.arbor.panes.findIndex((p) => p.overlay === this.canvas) : -1;
                        const d = i >= 0 && window.arbor.panes[i].overlayDrawn;
                        if (d) window.overlayCalls.drawn.push(`pane ${i}: ${d.camera} depth ${d.boxes?.data?.depth}`);
                    }
                    return real.apply(this, args);
                };
            }
        });
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=8&boxes=all`);
        await waitFullFrame(page);
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.depth === 8);
        await afterPaint(page);
        const calls = () => page.evaluate(() => ({ ...window.overlayCalls }));
        const reset = () => page.evaluate(() => { window.overlayCalls = { clears: 0, strokes: 0, drawn: [] }; });
        // a new frame of the same camera: the boxes over it are the same
        await reset();
        await page.selectOption('#spp', '4');
        await waitShown(page, { spp: 4 });
        await afterPaint(page);
        const same = await calls();
        assert.deepEqual([same.clears, same.strokes], [0, 0], `redrawn for ${same.drawn.join('; ')}`);
        // new boxes: one redraw, a stroke per depth's colour
        await reset();
        await page.fill('#depth', '7');
        await page.dispatchEvent('#depth', 'input');
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.depth === 7);
        await afterPaint(page);
        await screenshot(page, 'many-boxes');
        const n = await page.evaluate(() => window.arbor.panes[0].boxes.data.boxes.length);
        assert.ok(n > 100, `only ${n} boxes`);
        const c = await calls();
        assert.equal(c.clears, 1, `redrawn for ${c.drawn.join('; ')}`);
        assert.ok(c.strokes >= 1 && c.strokes <= 8, `${c.strokes} strokes for ${n} boxes of 8 depths`);
        assert.deepEqual(errors, []);
    });
});
