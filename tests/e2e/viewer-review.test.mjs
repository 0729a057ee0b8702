// viewer-review.test.mjs - what a UX review of the viewer asked for: split
// view's heat panes share one colour scale and its depth slider reaches the
// deeper tree; a dragged depth slider asks for one depth's boxes and drops
// those superseded; the ray panel keeps its focus and scroll across frames,
// and Clear and Escape give the focus back to the frame; the skip link
// reaches the frame; the compare status belongs to its model; Embree is not
// offered once the daemon said it has none; split view keeps its second
// tree; the keyboard hint; round legend ticks, ray vectors at one precision
// and an upload's name conflict in plain words.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, screenshot, recordRequests, waitFullFrame, postJSON, afterPaint } from './lib.mjs';

const T = { timeout: 180000 };
const isBoxes = (url) => new URL(url).pathname.endsWith('/boxes');
const depthOf = (url) => new URL(url).searchParams.get('depth');

/** Moves the depth slider to each of `depths` at once, as a drag does, without waiting between them. */
function slideDepth(page, depths) {
    return page.evaluate((ds) => {
        const el = document.getElementById('depth');
        for (const v of ds) {
            el.value = String(v);
            el.dispatchEvent(new Event('input', { bubbles: true }));
        }
    }, depths);
}

/** Sets a select the way a pick would, leaving the keyboard focus where it is. */
function pickQuietly(page, id, value) {
    return page.evaluate(([i, v]) => {
        const s = document.getElementById(i);
        s.value = v;
        s.dispatchEvent(new Event('change', { bubbles: true }));
    }, [id, value]);
}

test('split heat view colours both panes to one scale, the larger of the two, and the legend says it is shared', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=sphere&accel=bvh&builder=sah&mode=heat&spp=1&split=kd:sah`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        await page.waitForSelector('#legend .legend-row:not([data-heat-scale=""])');
        await afterPaint(page);
        const shown = await page.evaluate(() => window.arbor.panes.map((p) => p.shown.heatScale));
        const last = (accel) => rec.renders.filter((r) => r.accel === accel).at(-1);
        // each tree's own 99th percentile for the same view
        const own = [];
        for (const accel of ['bvh', 'kd']) {
            const r = last(accel);
            const j = await postJSON(d.base, '/api/render', {
                model: 'sphere', accel, builder: 'sah', mode: 'heat', camera: r.camera,
                width: r.width, height: r.height, spp: 1, format: 'json',
            });
            assert.equal(j.status, 200, j.text);
            own.push(j.json.heat_scale);
        }
        assert.notEqual(own[0], own[1], 'the two trees of sphere no longer differ in cost');
        assert.deepEqual(shown, [Math.max(...own), Math.max(...own)], `own scales ${own}`);
        assert.equal(last('bvh').heat_scale, shown[0], 'the BVH frame was not asked for at the shared scale');
        assert.equal(last('kd').heat_scale, shown[0], 'the k-d frame was not asked for at the shared scale');
        const rows = await page.$$eval('#legend .legend-row', (rs) => rs.map((r) => ({ scale: Number(r.dataset.heatScale), text: r.textContent })));
        assert.equal(rows.length, 1, 'one legend bar for the shared scale');
        assert.equal(rows[0].scale, shown[0]);
        assert.match(rows[0].text, /Shared by both panes/);
        await screenshot(page, 'split-heat-shared');
        assert.deepEqual(errors, []);
    });
});

test("split view's depth slider reaches the deeper pane's tree; the shallower shows no boxes there", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=bvh&builder=sah&spp=1&depth=0&split=kd:sah`);
        await page.waitForFunction(() => window.arbor.panes.length === 2 && window.arbor.panes.every((p) => p.stats && p.stats.max_depth >= 0));
        const [bvh, kd] = await page.evaluate(() => window.arbor.panes.map((p) => (p.stats.wide || p.stats).max_depth));
        assert.ok(kd > bvh, `k-d depth ${kd}, BVH wide depth ${bvh}`);
        await afterPaint(page);
        assert.equal(await page.getAttribute('#depth', 'max'), String(kd));
        await slideDepth(page, [kd]);
        await page.waitForFunction((m) => window.arbor.panes.every((p) => p.boxes?.data?.depth === m), kd);
        const counts = await page.evaluate(() => window.arbor.panes.map((p) => p.boxes.data.boxes.length));
        assert.equal(counts[0], 0, 'BVH boxes past its depth');
        assert.ok(counts[1] > 0, 'no k-d boxes at its deepest level');
        assert.deepEqual(errors, []);
    });
});

test('the dragged depth slider asks for the boxes of the depth it rests on, and drops those superseded', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=0`);
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.depth === 0);
        const asked = [], dropped = [];
        page.on('request', (r) => { if (isBoxes(r.url())) asked.push(depthOf(r.url())); });
        page.on('requestfailed', (r) => { if (isBoxes(r.url())) dropped.push(depthOf(r.url())); });
        // a drag across eight depths, quicker than any answer: one request, for the last
        await slideDepth(page, [1, 2, 3, 4, 5, 6, 7, 8]);
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.depth === 8);
        assert.deepEqual(asked, ['8']);
        // boxes still on their way when the slider moves on are dropped
        const held = [];
        await page.route((url) => isBoxes(url.href), (route) => { held.push(route); });
        const waitHeld = async (n) => { while (held.length < n) await page.waitForTimeout(20); };
        await slideDepth(page, [3]);
        await waitHeld(1);
        const drop = page.waitForEvent('requestfailed', { predicate: (r) => isBoxes(r.url()), timeout: 10000 });
        await slideDepth(page, [5]);
        await waitHeld(2);
        await drop;
        assert.deepEqual(dropped, ['3']);
        await page.unroute((url) => isBoxes(url.href));
        for (const r of held) await r.continue().catch(() => {});
        await page.waitForFunction(() => window.arbor.panes[0].boxes?.data?.depth === 5);
        await page.waitForFunction(() => /at depth 5/.test(document.getElementById('boxes-info').textContent));
        assert.deepEqual(errors.filter((e) => !/Failed to load resource/.test(e)), []);
    });
});

test('the ray panel keeps its focus and scroll as frames come; Clear and Escape clear the ray and focus the frame', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphereflake&accel=kd&builder=spatial&spp=1`);
        await waitFullFrame(page);
        assert.equal(await page.getAttribute('#ray-panel', 'aria-live'), 'polite');
        await page.focus('.frame');
        await page.keyboard.press('Enter'); // the centre pixel's ray
        await page.waitForSelector('#ray-steps');
        await page.focus('#ray-clear');
        const scrolled = await page.$eval('#ray-panel .steps', (el) => { el.scrollTop = 40; return el.scrollTop; });
        assert.ok(scrolled > 0, 'the steps list does not scroll');
        // a new frame comes while the focus stays on Clear
        await pickQuietly(page, 'spp', '4');
        await page.waitForFunction(() => window.arbor.panes[0].shown?.req.spp === 4 && !window.arbor.panes[0].shown.quick);
        await afterPaint(page);
        assert.equal(await page.evaluate(() => document.activeElement.id), 'ray-clear', 'the focus left Clear');
        assert.equal(await page.$eval('#ray-panel .steps', (el) => el.scrollTop), scrolled, 'the steps list scrolled back');
        await page.keyboard.press('Enter'); // Clear
        await page.waitForFunction(() => !document.getElementById('ray-steps'));
        assert.equal(await page.evaluate(() => document.activeElement.id), 'frame-0', 'Clear left the focus elsewhere than the frame');
        await page.keyboard.press('Enter');
        await page.waitForSelector('#ray-steps');
        await page.keyboard.press('Escape');
        await page.waitForFunction(() => !document.getElementById('ray-steps') && window.arbor.rayInspect === null);
        assert.equal(await page.evaluate(() => document.activeElement.id), 'frame-0');
        assert.deepEqual(errors, []);
    });
});

test('the skip link focuses the frame, whose arrow keys then orbit', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        await page.keyboard.press('Tab');
        assert.equal(await page.evaluate(() => document.activeElement.className), 'skip');
        await page.keyboard.press('Enter');
        await page.waitForFunction(() => location.hash !== '');
        assert.equal(await page.evaluate(() => document.activeElement.id), 'frame-0', 'the skip link focused another element');
        const yaw = await page.evaluate(() => window.arbor.state.view.yaw);
        await page.keyboard.press('ArrowLeft');
        assert.notEqual(await page.evaluate(() => window.arbor.state.view.yaw), yaw, 'the arrow key did not orbit');
        assert.deepEqual(errors, []);
    });
});

const TREES = [['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'], ['bvh', 'sah'], ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah']];

test("the compare tab's progress and status belong to the model benchmarked, not the next one chosen", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rows = TREES.map(([accel, builder], i) => ({ model: 'cornell', accel, builder, build_ms: i + 1, render_ms: i + 2 }));
        await page.route('**/api/bench', (r) => r.fulfill({ status: 202, json: { id: '9', state: 'queued' } }));
        await page.route('**/api/jobs/9', (r) => r.fulfill({
            json: { id: '9', model: 'cornell', state: 'done', progress: { done: 8, total: 8 }, elapsed_ms: 10, rows, error: null },
        }));
        await page.goto(`${d.base}/?model=cornell&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'cornell');
        await page.click('#cmp-start');
        await page.waitForFunction(() => /^done: 8 rows/.test(document.getElementById('cmp-progress-text').textContent));
        assert.equal(await page.isVisible('#cmp-progress-wrap'), true);
        await page.selectOption('#model', 'sphere');
        assert.equal(await page.textContent('#cmp-model'), 'sphere');
        assert.equal(await page.isVisible('#cmp-progress-wrap'), false, "cornell's status shown for sphere");
        assert.equal(await page.locator('figure.chart').count(), 0);
        await page.selectOption('#model', 'cornell');
        assert.equal(await page.locator('figure.chart').count(), 10, "cornell's charts are gone");
        assert.deepEqual(errors, []);
    });
});

test('Embree is offered only by a daemon that says it has it (/api/stats daemon.embree)', T, async () => {
    for (const embree of [true, false]) {
        await withViewer({}, async (d, { page, errors }) => {
            await page.route('**/api/stats', async (route) => {
                const res = await route.fetch();
                const json = await res.json();
                route.fulfill({ response: res, json: { ...json, daemon: { ...json.daemon, embree } } });
            });
            await page.goto(`${d.base}/?model=sphere&tab=compare`);
            await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
            const options = () => page.$$eval('#cmp-peer option', (os) => os.map((o) => [o.value, o.disabled]));
            if (embree) {
                assert.deepEqual(await options(), [['', false], ['embree', false], ['robust', false]]);
                assert.equal(await page.isVisible('#cmp-peer-why'), false);
            } else {
                await page.waitForSelector('#cmp-peer-why:not([hidden])');
                assert.deepEqual(await options(), [['', false], ['embree', true], ['robust', true]]);
                assert.equal(await page.inputValue('#cmp-peer'), '');
                assert.match(await page.textContent('#cmp-peer-why'), /built without Embree/);
            }
            assert.deepEqual(errors, []);
        });
    }
});

test('turning split view off and on keeps the second tree chosen', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        await page.check('#split-on');
        await page.selectOption('#accel2', 'bvh');
        await page.selectOption('#builder2', 'median');
        await page.uncheck('#split-on');
        await page.check('#split-on');
        assert.equal(await page.inputValue('#accel2'), 'bvh');
        assert.equal(await page.inputValue('#builder2'), 'median');
        assert.deepEqual(await page.evaluate(() => window.arbor.panes[1].tree()), { accel: 'bvh', builder: 'median' });
        await page.waitForFunction(() => new URLSearchParams(location.search).get('split') === 'bvh:median');
        assert.deepEqual(errors, []);
    });
});

test("the page's hint names every key the frame takes", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        const hint = await page.textContent('#hint');
        const keys = await page.$$eval('#hint kbd', (ks) => ks.map((k) => k.textContent));
        for (const k of ['Shift', 'Alt', 'Enter', 'Space', 'Esc']) assert.ok(keys.includes(k), `${k} is not in the hint: ${hint}`);
        assert.match(hint, /Shift\+arrows pan/);
        assert.match(hint, /Alt\+arrows in fine steps/);
        assert.match(hint, /Enter or Space inspects the centre pixel/);
        assert.match(hint, /Esc clears the ray/);
        assert.deepEqual(errors, []);
    });
});

test('the heat legend ticks at round values, with the scale at its end', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&mode=heat&spp=1`);
        await waitFullFrame(page);
        await page.waitForSelector('#legend .legend-row:not([data-heat-scale=""])');
        const scale = Number(await page.$eval('#legend .legend-row', (r) => r.dataset.heatScale));
        const ticks = await page.$$eval('#legend .legend-ticks span', (s) => s.map((e) => e.textContent));
        assert.equal(ticks.at(-1), `${Math.round(scale)}+`);
        const values = ticks.slice(0, -1).map((t) => Number(t.replace(/,/g, '')));
        assert.ok(values.length >= 3, JSON.stringify(ticks));
        const step = values[1] - values[0];
        assert.match(String(step), /^[125]0*$/, `ticks ${JSON.stringify(ticks)}`);
        values.forEach((v, i) => assert.equal(v, i * step, `ticks ${JSON.stringify(ticks)}`));
        assert.deepEqual(errors, []);
    });
});

test("the ray inspector prints a vector's components at one precision", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        await page.focus('.frame');
        await page.keyboard.press('Enter');
        await page.waitForSelector('#ray-counts');
        const cells = await page.$$eval('#ray-counts tr', (rs) => Object.fromEntries(rs.map((r) => [r.cells[0].textContent, r.cells[1].textContent])));
        // the hit at cornell's centre has a normal with a zero component
        assert.match(cells.Normal, /\b0\.000\b/, cells.Normal);
        for (const k of ['Point', 'Normal']) {
            const decimals = cells[k].replace(/[()]/g, '').split(', ').map((c) => (c.split('.')[1] || '').length);
            assert.equal(new Set(decimals).size, 1, `${k}: ${cells[k]}`);
        }
        assert.deepEqual(errors, []);
    });
});

test('uploading a name already taken says so in plain words, and Replace replaces it', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        const tri = { name: 'tri.obj', mimeType: 'text/plain', buffer: Buffer.from('v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n') };
        await page.setInputFiles('#file-input', tri);
        await page.waitForFunction(() => /^Uploaded "tri"/.test(document.getElementById('upload-text').textContent));
        await page.setInputFiles('#file-input', tri);
        await page.waitForSelector('#upload-status.error');
        const text = await page.textContent('#upload-text');
        assert.equal(text, 'There is already a model named "tri" on the daemon.');
        await page.click('#upload-actions button:has-text("Replace")');
        await page.waitForFunction(() => /^Uploaded "tri"/.test(document.getElementById('upload-text').textContent));
        assert.deepEqual(errors.filter((e) => !/status of 409/.test(e)), []);
    });
});
