// viewer-frames.test.mjs - what a second UX review asked of the frames: a big
// frame previewed, then asked for in strips no more at once than the daemon
// renders and counted in the badge as they come; split view's strips taken
// in turn, and the daemon's render time beside the wall time (a heat frame's
// without its scale's renders); a frame of the
// tree left behind dimmed and labelled as such; Save PNG of both panes, only
// once the current view's frame is complete; the depth slider says which
// tree it walks; a clicked ray is summed up under the frame, in view on a
// laptop and a phone, with a way to the ray inspector; Upload stays on the
// title's line.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, screenshot, recordRequests, waitFullFrame, framePixels, savePNG, pngSize, afterPaint } from './lib.mjs';

const T = { timeout: 240000 };
// a request the test held and let go of, or a frame it gave up on, is logged by the browser
const unprovoked = (errors) => errors.filter((e) => !/Failed to load resource/.test(e));
const THREADS = 2;

/** Holds every frame request (PNG, not format=json) until let go: held[i].continue(). */
async function holdFrames(page) {
    const held = [];
    await page.route('**/api/render', (route) => {
        if (JSON.parse(route.request().postData() || '{}').format === 'json') route.continue();
        else held.push(route);
    });
    return {
        held,
        async waitFor(n) { while (held.length < n) await page.waitForTimeout(20); },
        async release() {
            await page.unroute('**/api/render');
            for (const r of held) await r.continue().catch(() => {});
        },
    };
}

const body = (route) => JSON.parse(route.request().postData());
const badge = (page) => page.textContent('.badge.quality');

test('a big frame: a quick preview first, then its strips no more at once than the daemon renders, each drawn and counted as it comes', T, async () => {
    await withViewer({ daemon: { extraArgs: ['--threads', String(THREADS)] } }, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        const frames = await holdFrames(page);
        await page.goto(`${d.base}/?model=cornell&res=1920x1080&spp=16`);
        await frames.waitFor(1);
        const preview = body(frames.held[0]);
        assert.equal(preview.region, undefined, 'the first request is a strip, not a preview of the whole frame');
        assert.equal(preview.spp, 1);
        assert.ok(preview.width < 1920, `preview ${preview.width}×${preview.height}`);
        await frames.held[0].continue();
        await page.waitForFunction(() => document.querySelector('canvas.image').dataset.frame === 'quick');
        let released = 1;
        let strips = 0;
        for (;;) {
            await frames.waitFor(released + 1);
            const pending = frames.held.length - released;
            assert.ok(pending <= THREADS, `${pending} strips asked for at once of a daemon rendering ${THREADS}`);
            const strip = body(frames.held[released]);
            assert.ok(strip.region && strip.spp === 16, JSON.stringify(strip));
            const before = await framePixels(page);
            await frames.held[released].continue();
            released++;
            strips++;
            await page.waitForFunction((k) => new RegExp(`\\b${k} of \\d+ strips`).test(document.querySelector('.badge.quality').textContent)
                || document.querySelector('canvas.image').dataset.frame === 'full', strips);
            if (await page.$eval('canvas.image', (c) => c.dataset.frame === 'full')) break;
            const total = Number(/of (\d+) strips/.exec(await badge(page))[1]);
            assert.ok(total > 1 && strips < total, await badge(page));
            // drawn over the preview as it came, before the rest
            assert.notEqual((await framePixels(page)).hash, before.hash, `strip ${strips} was not drawn when it came`);
            if (strips === 1) await screenshot(page, 'strips-progress');
        }
        assert.ok(strips >= 8, `${strips} strips`);
        assert.ok(rec.maxInflight() <= THREADS, `${rec.maxInflight()} frame requests at once`);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test("split view takes the panes' strips in turn; the stats show the daemon's render time and the wall time, labelled", T, async () => {
    // both trees ready at start: neither pane's frame waits for a build
    await withViewer({ daemon: { extraArgs: ['--threads', String(THREADS), '--prebuild', 'bvh:sah,kd:sah'] } }, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=cornell&accel=bvh&builder=sah&spp=4&split=kd:sah`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        await afterPaint(page);
        const strips = rec.renders.filter((r) => r.region);
        assert.ok(strips.length >= 6, `${strips.length} strips`);
        const order = strips.map((r) => r.accel);
        // while both have strips waiting, each pane's follows the other's
        const last = Math.min(order.lastIndexOf('bvh'), order.lastIndexOf('kd'));
        for (let i = 1; i <= last; i++) assert.notEqual(order[i], order[i - 1], `strips asked for in the order ${order.join(' ')}`);
        // the daemon's time: the sum of X-Render-Ms over the pane's frame's strips
        for (const [i, accel] of [[0, 'bvh'], [1, 'kd']]) {
            const mine = rec.responses.filter((r) => JSON.parse(r.body).accel === accel && JSON.parse(r.body).region);
            const n = strips.filter((r) => r.accel === accel).length;
            const sum = mine.slice(-n).reduce((a, r) => a + Number(r.headers['x-render-ms']), 0);
            const shown = await page.evaluate((k) => window.arbor.panes[k].shown, i);
            assert.ok(Math.abs(shown.daemonMs - sum) < 1e-6, `pane ${i}: ${shown.daemonMs} ms, its strips' X-Render-Ms add to ${sum}`);
            assert.ok(shown.renderMs > 0, 'no wall time');
        }
        const rows = await page.$$eval('#stats-table tr[data-key]', (rs) => Object.fromEntries(rs.map((r) => [r.dataset.key,
            { label: r.cells[0].textContent, why: r.cells[0].title, cells: [...r.cells].slice(1).map((c) => c.textContent) }])));
        assert.match(rows.render_ms.label, /daemon/i);
        assert.match(rows.render_ms.why, /summed over the frame's requests/);
        assert.match(rows.frame_ms.label, /wall/i);
        assert.match(rows.frame_ms.why, /browser waited/);
        for (const k of ['render_ms', 'frame_ms', 'mrays', 'mrays_wall']) {
            assert.ok(rows[k] && rows[k].cells.length === 2 && rows[k].cells.every((c) => /\d/.test(c)), `${k}: ${JSON.stringify(rows[k])}`);
        }
        await screenshot(page, 'split-times');
        assert.deepEqual(errors, []);
    });
});

test("a split heat frame's wall time leaves out the shared scale's renders before it, and its tooltip says so", T, async () => {
    await withViewer({ daemon: { extraArgs: ['--threads', String(THREADS), '--prebuild', 'bvh:sah,kd:sah'] } }, async (d, { page, errors }) => {
        // the scale's measurements (whole frames at 1 spp, as JSON) held for SCALE_MS: far longer than cornell's frame takes
        const SCALE_MS = 6000;
        let held = 0;
        await page.route('**/api/render', async (route) => {
            const b = JSON.parse(route.request().postData() || '{}');
            if (b.format === 'json' && b.mode === 'heat' && !b.region) {
                held++;
                await new Promise((r) => setTimeout(r, SCALE_MS));
            }
            await route.continue().catch(() => {});
        });
        await page.goto(`${d.base}/?model=cornell&mode=heat&spp=1&split=kd:sah`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        assert.ok(held >= 2, `${held} scale measurements held: the frames did not wait for a shared scale`);
        for (const i of [0, 1]) {
            const shown = await page.evaluate((k) => window.arbor.panes[k].shown, i);
            assert.equal(shown.req.mode, 'heat');
            assert.ok(shown.renderMs > 0 && shown.renderMs < SCALE_MS, `pane ${i}'s wall time ${shown.renderMs} ms counts the scale's ${SCALE_MS} ms`);
        }
        const why = await page.getAttribute('#stats-table tr[data-key="frame_ms"] th', 'title');
        assert.match(why, /heat frame's scale, measured at 1 spp before it, is not counted/);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test("switching trees dims the old frame, says what is coming, and labels the old frame's numbers and legend as its tree's", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=bvh&builder=sah&mode=heat&spp=1`);
        await waitFullFrame(page);
        const frames = await holdFrames(page);
        await page.selectOption('#accel', 'kd');
        await frames.waitFor(1);
        await afterPaint(page);
        assert.match(await page.textContent('.pane-title .tree-name'), /k-d sah/);
        assert.equal(await page.$eval('.frame', (f) => f.classList.contains('stale')), true, 'the old frame is not marked');
        assert.match(await page.textContent('.badge.stale'), /^(building|rendering) k-d sah/);
        assert.equal(await page.isVisible('.badge.stale'), true);
        assert.match(await page.textContent('.pane-title .frame-info'), /BVH sah · heat frame/);
        assert.match(await page.textContent('#stats-table tr[data-key="frame_of"] td'), /^BVH sah · heat \(previous\)$/);
        assert.match(await page.textContent('#legend .legend-row'), /BVH sah: the previous tree's frame/);
        await screenshot(page, 'stale-frame');
        await frames.release();
        await page.waitForFunction(() => window.arbor.panes[0].shown?.req.accel === 'kd' && !window.arbor.panes[0].shown.quick);
        await afterPaint(page);
        assert.equal(await page.$eval('.frame', (f) => f.classList.contains('stale')), false);
        assert.equal(await page.isVisible('.badge.stale'), false);
        assert.equal(await page.$('#stats-table tr[data-key="frame_of"]'), null);
        assert.doesNotMatch(await page.textContent('#legend'), /previous/);
        assert.deepEqual(unprovoked(errors), []);
    });
});

test('Save PNG saves both split panes side by side under their titles, and only a complete frame of the current view', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=bvh&builder=sah&mode=heat&spp=1&split=kd:sah`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        const { file, filename } = await savePNG(page, 'saved-split');
        assert.match(filename, /^sphere-bvh-sah-vs-kd-sah-heat-640x480\.png$/);
        const [w, h] = pngSize(file);
        assert.ok(w >= 2 * 640 && h > 480, `saved ${w}×${h}`);
        // each half holds its pane's frame, under a title
        const match = await page.evaluate(async ({ b64, w, h }) => {
            const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
            const bmp = await createImageBitmap(new Blob([bytes], { type: 'image/png' }));
            const c = new OffscreenCanvas(w, h);
            const ctx = c.getContext('2d');
            ctx.drawImage(bmp, 0, 0);
            const saved = ctx.getImageData(0, 0, w, h).data;
            return window.arbor.panes.map((p, i) => {
                const src = p.canvas.getContext('2d').getImageData(0, 0, p.canvas.width, p.canvas.height).data;
                const x0 = i === 0 ? 0 : w - p.canvas.width, y0 = h - p.canvas.height;
                let differ = 0;
                for (let y = 0; y < p.canvas.height; y += 7) {
                    for (let x = 0; x < p.canvas.width; x += 7) {
                        const a = (y * p.canvas.width + x) * 4, b = ((y + y0) * w + x + x0) * 4;
                        if (Math.abs(src[a] - saved[b]) + Math.abs(src[a + 1] - saved[b + 1]) + Math.abs(src[a + 2] - saved[b + 2]) > 6) differ++;
                    }
                }
                return { differ, titled: y0 > 0 };
            });
        }, { b64: file.toString('base64'), w, h });
        assert.deepEqual(match, [{ differ: 0, titled: true }, { differ: 0, titled: true }]);
        // an orbit: the button waits for the new view's frames
        const frames = await holdFrames(page);
        await page.focus('#frame-0');
        await page.keyboard.press('ArrowLeft');
        await afterPaint(page);
        assert.equal(await page.$eval('#save-png', (b) => b.disabled), true, 'Save PNG offers the frame of the view before the orbit');
        await frames.waitFor(1);
        assert.equal(await page.$eval('#save-png', (b) => b.disabled), true);
        await frames.release();
        await page.waitForSelector('#save-png:not([disabled])', { timeout: 60000 });
        assert.deepEqual(unprovoked(errors), []);
    });
});

test("the depth slider says it walks the traversed tree, and the BVH's binary depth it does not reach", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1&depth=0`);
        await page.waitForFunction(() => window.arbor.panes[0].stats?.wide);
        const st = await page.evaluate(() => window.arbor.panes[0].stats);
        assert.match(await page.textContent('label[for="depth"]'), /Depth \(traversed tree\)/);
        await page.waitForFunction(() => document.getElementById('depth-note').textContent !== '');
        const note = await page.textContent('#depth-note');
        assert.match(note, new RegExp(`BVH sah: its wide tree, depths 0–${st.wide.max_depth} \\(the binary tree .* goes to ${st.max_depth}\\)`));
        assert.equal(await page.getAttribute('#depth', 'aria-describedby'), 'depth-note');
        assert.deepEqual(errors, []);
    });
});

/**
 * Clicks (taps, on a phone) the frame's centre and checks the line under the
 * frame: in view, where the page was, and saying what the daemon's own
 * POST /api/ray answers for that pixel; then its button brings the ray
 * inspector's card into view, its heading focused. Returns the ray's answer
 * and whether the inspector's counts were below the fold before the button.
 */
async function inspectCentre(page, tap) {
    const frame = await page.$eval('#frame-0', (e) => { const r = e.getBoundingClientRect(); return { x: r.x + r.width / 2, y: r.y + r.height / 2 }; });
    const scrolled = await page.evaluate(() => scrollY);
    const answer = page.waitForResponse((r) => r.url().endsWith('/api/ray'));
    if (tap) await page.touchscreen.tap(frame.x, frame.y);
    else await page.mouse.click(frame.x, frame.y);
    const ray = await (await answer).json();
    await page.waitForSelector('#ray-details');
    await afterPaint(page);
    const line = await page.$eval('#ray-summary', (e) => { const r = e.getBoundingClientRect(); return { top: r.top, bottom: r.bottom, text: e.textContent }; });
    const vh = await page.evaluate(() => innerHeight);
    assert.ok(line.top >= 0 && line.bottom <= vh, `the ray's line is out of view: ${line.top}-${line.bottom} of ${vh}`);
    assert.equal(await page.evaluate(() => scrollY), scrolled, 'the page scrolled away from the frame');
    const n = (v) => v.toLocaleString('en-US');
    assert.ok(ray.hit, 'the centre ray of cornell misses');
    assert.ok(line.text.includes(`pixel (${ray.x}, ${ray.y})`), line.text);
    assert.ok(line.text.includes(`hits triangle ${n(ray.hit.triangle)} at t ${ray.hit.t.toFixed(4)}`), line.text);
    assert.ok(line.text.includes(`${n(ray.counts.nodes)} node steps + ${n(ray.counts.tris)} triangle tests`), line.text);
    const countsBelow = await page.$eval('#ray-counts', (e) => e.getBoundingClientRect().top > innerHeight);
    await page.click('#ray-details');
    await page.waitForFunction(() => {
        const r = document.getElementById('ray-panel').closest('.card').getBoundingClientRect();
        return r.top >= -1 && r.top < innerHeight / 2;
    });
    assert.equal(await page.evaluate(() => document.activeElement.id), 'h-ray');
    assert.equal(await page.getAttribute('#ray-counts', 'data-nodes'), String(ray.counts.nodes));
    return { ray, countsBelow };
}

test('a click on the frame says its ray under the frame, in view, and Details brings the ray inspector; Escape clears both', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        assert.ok(await page.$eval('#ray-summary', (e) => e.hidden), 'a ray line before any click');
        const { countsBelow } = await inspectCentre(page, false);
        // at 1280 x 800 the ray inspector's figures are below the fold: the line under the frame is what is seen
        assert.ok(countsBelow, 'the ray inspector is in view without scrolling: this test would not show the line is needed');
        await screenshot(page, 'ray-details');
        await page.focus('#frame-0');
        await page.keyboard.press('Escape');
        await page.waitForFunction(() => document.getElementById('ray-summary').hidden);
        assert.deepEqual(errors, []);
    });
});

test('on a phone a tap on the frame says its ray under the frame, staying there, and Details brings the ray panel; Upload stays on the title line', T, async () => {
    await withViewer({ browser: { viewport: { width: 390, height: 844 }, mobile: true } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        await waitFullFrame(page);
        const box = (sel) => page.$eval(sel, (e) => { const r = e.getBoundingClientRect(); return { top: r.top, bottom: r.bottom }; });
        const title = await box('h1'), upload = await box('#upload-button');
        assert.ok(upload.top < title.bottom && upload.bottom > title.top, `Upload at ${JSON.stringify(upload)}, the title at ${JSON.stringify(title)}`);
        await screenshot(page, 'phone-header');
        await inspectCentre(page, true);
        await screenshot(page, 'phone-ray');
        assert.deepEqual(errors, []);
    });
});
