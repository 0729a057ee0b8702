// viewer.test.mjs - the viewer (web/) in Debian's chromium against a real
// arbord serve: frames, orbit, stats and legend, the box overlay against the
// rendered model, the field of view, the ray inspector against heat mode,
// compare, URL state, upload errors, the phone layout, a daemon with
// --token-file, layouts that fit their cards, and a clean console.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import {
    withViewer, screenshot, recordRequests, waitFullFrame, waitFrameMovedFrom, framePixels, overlayBox, postJSON, afterPaint,
} from './lib.mjs';

const T = { timeout: 180000 };

async function frameBox(page, index = 0) {
    return page.locator('.frame').nth(index).boundingBox();
}

test('the canvas shows a non-blank frame', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell`);
        await waitFullFrame(page);
        const px = await framePixels(page);
        await screenshot(page, 'frame');
        assert.equal(px.w, 640);
        assert.equal(px.h, 480);
        assert.ok(px.colours > 50, `only ${px.colours} colours in the frame`);
        assert.ok(px.fg > 0.1 * px.w * px.h, `only ${px.fg} pixels differ from the background`);
        assert.deepEqual(errors, []);
    });
});

test('a mouse drag changes the frame and sends a render request with a new camera', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=cornell&spp=1`);
        const cam0 = await waitFullFrame(page);
        const before = await framePixels(page);
        const n0 = rec.renders.length;
        const box = await frameBox(page);
        const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
        await page.mouse.move(cx, cy);
        await page.mouse.down();
        for (let i = 1; i <= 20; i++) {
            await page.mouse.move(cx + i * 8, cy + i * 2);
            await page.waitForTimeout(15);
        }
        await page.mouse.up();
        await waitFrameMovedFrom(page, cam0);
        const after = await framePixels(page);
        await screenshot(page, 'after-drag');
        const sent = rec.renders.slice(n0);
        assert.ok(sent.length >= 1, 'no render request after the drag');
        const moved = sent.filter((r) => r.camera && r.camera.yaw !== cam0.yaw);
        assert.ok(moved.length >= 1, `no request with a new camera: ${JSON.stringify(sent.map((r) => r.camera))}`);
        assert.ok(moved.some((r) => r.camera.yaw < cam0.yaw), 'dragging right should orbit the camera to smaller yaw');
        assert.ok(sent.some((r) => r.spp === 1 && r.width < 640), 'no quick low-resolution frame while dragging');
        const last = sent[sent.length - 1];
        assert.equal(last.width, 640);
        // full frames come as strips (region) with the pane's stream key plus /strip
        assert.equal(new Set(rec.renders.map((r) => r.stream.split('/')[0])).size, 1, 'one stream key for the pane');
        const strips = [0, 120, 240, 360].map((y) => ({ x: 0, y, w: 640, h: 120 }));
        assert.ok(rec.maxInflight() <= strips.length, `${rec.maxInflight()} requests were in flight at once (one frame: ${strips.length})`);
        const lastFull = sent.filter((r) => r.width === 640);
        const rows = lastFull.slice(-strips.length).map((r) => r.region).sort((a, b) => a.y - b.y);
        assert.deepEqual(rows, strips, 'the last full frame was not asked as its strips');
        assert.notEqual(after.hash, before.hash, 'the frame did not change');
        assert.deepEqual(errors, []);
    });
});

test('switching to kd / sah / heat shows the stats and the legend', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=sphere`);
        await waitFullFrame(page);
        await page.selectOption('#accel', 'kd');
        await page.selectOption('#builder', 'sah');
        await page.selectOption('#mode', 'heat');
        await page.waitForFunction(() => {
            const c = document.querySelector('canvas.image[data-pane="0"]');
            const r = document.querySelector('#legend .legend-row');
            return c.dataset.frame === 'full' && r && r.dataset.heatScale !== '' && !document.getElementById('legend').hidden;
        }, null, { timeout: 60000 });
        await page.waitForFunction(() => {
            const td = document.querySelector('#stats-table tr[data-key="nodes"] td');
            return td && /\d/.test(td.textContent);
        }, null, { timeout: 60000 });
        const stats = await fetch(`${d.base}/api/stats?model=sphere&accel=kd&builder=sah`).then((r) => r.json());
        const st = stats.trees.find((t) => t.accel === 'kd' && t.builder === 'sah' && t.model === 'sphere');
        assert.ok(st, 'the daemon has no kd sah stats for sphere');
        const shown = await page.$$eval('#stats-table tr[data-key] td', (tds) =>
            Object.fromEntries(tds.map((td) => [td.parentElement.dataset.key, td.textContent.trim()])));
        assert.equal(shown.nodes.replace(/,/g, ''), String(st.nodes));
        assert.equal(shown.leaves.replace(/,/g, ''), String(st.leaves));
        assert.equal(shown.max_depth, String(st.max_depth));
        assert.match(shown.frame_ms, /\d/);
        assert.match(shown.mrays, /\d/);
        const heatFrames = rec.responses.filter((r) => r.status === 200 && JSON.parse(r.body).mode === 'heat' && JSON.parse(r.body).accel === 'kd');
        assert.ok(heatFrames.length, 'no kd heat frame');
        const scale = Number(heatFrames[heatFrames.length - 1].headers['x-heat-scale']);
        assert.ok(scale > 0, 'no X-Heat-Scale header');
        const legendScale = Number(await page.$eval('#legend .legend-row', (r) => r.dataset.heatScale));
        assert.equal(legendScale, scale);
        const ticks = await page.$$eval('#legend .legend-ticks span', (s) => s.map((e) => e.textContent));
        assert.ok(ticks.length >= 3, JSON.stringify(ticks));
        assert.equal(ticks[0], '0');
        assert.equal(ticks.at(-1), `${Math.round(scale)}+`);
        await screenshot(page, 'kd-sah-heat');
        assert.deepEqual(errors, []);
    });
});

test('the depth slider draws boxes whose root box, projected, encloses the rendered model', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // cornell is a box: its root box's outline is its silhouette, so the
        // projection must match the rendered model closely, not just enclose it
        const views = [
            '',
            '&yaw=-50&pitch=35&dist=1.6',
            '&yaw=140&pitch=-20&dist=1.2&target=0.3,1.1,-0.2',
        ];
        let k = 0;
        for (const v of views) {
            const rec = recordRequests(page);
            await page.goto(`${d.base}/?model=cornell&mode=normals&spp=1${v}`);
            await waitFullFrame(page);
            if (!(await page.isChecked('#boxes-on'))) await page.check('#boxes-on');
            await page.fill('#depth', '0');
            await page.dispatchEvent('#depth', 'input');
            // "1 box at depth 0", not "loading boxes…"
            await page.waitForFunction(() => /\d box/.test(document.getElementById('boxes-info').textContent) ||
                document.getElementById('boxes-info').classList.contains('error'), null, { timeout: 30000 });
            const info = await page.textContent('#boxes-info');
            assert.doesNotMatch(info, /does not serve|failed/, info);
            const req = rec.renders.filter((r) => r.width === 640).pop();
            const bg = req.background.map((c) => Math.round(c * 255));
            const px = await framePixels(page, 0, bg, 10);
            const ov = await overlayBox(page, 0, px.w, px.h);
            await screenshot(page, `root-box-${k++}`);
            assert.ok(px.bbox, 'the frame shows no model');
            assert.ok(ov, 'no box drawn over the frame');
            const [mx0, my0, mx1, my1] = px.bbox, [bx0, by0, bx1, by1] = ov.bbox;
            const tol = 2.5; // the drawn line's width
            assert.ok(bx0 <= mx0 + tol && by0 <= my0 + tol && bx1 >= mx1 - tol && by1 >= my1 - tol,
                `root box ${ov.bbox.map(Math.round)} does not enclose the model's pixels ${px.bbox}`);
            for (const [a, b] of [[bx0, mx0], [by0, my0], [bx1, mx1], [by1, my1]]) {
                assert.ok(Math.abs(a - b) <= 4, `root box ${ov.bbox.map(Math.round)} is not the box's silhouette ${px.bbox}`);
            }
        }
        // deeper levels draw more boxes: the wide BVH's deepest is 1 (the slider's end)
        await page.fill('#depth', '1');
        await page.dispatchEvent('#depth', 'input');
        await page.waitForFunction(() => /at depth 1/.test(document.getElementById('boxes-info').textContent), null, { timeout: 30000 });
        const n = await page.textContent('#boxes-info');
        assert.ok(Number(/(\d+) boxes at depth 1/.exec(n)?.[1]) > 1, n);
        assert.deepEqual(errors, []);
    });
});

test('clicking a pixel lists a ray path whose counts match the heat mode', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=sphereflake&mode=heat&spp=1`);
        await waitFullFrame(page);
        const box = await frameBox(page);
        await page.mouse.click(box.x + box.width * 0.52, box.y + box.height * 0.48);
        await page.waitForSelector('#ray-counts, #ray-panel .error', { timeout: 30000 });
        await screenshot(page, 'ray-inspector');
        const rayError = await page.$$eval('#ray-panel .error', (e) => e.map((x) => x.textContent).join(' '));
        assert.equal(rayError, '', 'the ray inspector shows an error');
        assert.equal(rec.rays.length, 1, 'one /api/ray request');
        const ray = rec.rays[0];
        for (const k of ['model', 'accel', 'builder', 'camera', 'width', 'height', 'x', 'y']) assert.ok(k in ray, `no ${k} in /api/ray`);
        const shown = await page.$eval('#ray-counts', (t) => ({ nodes: Number(t.dataset.nodes), tris: Number(t.dataset.tris) }));
        const steps = await page.$$eval('#ray-steps tbody tr', (r) => r.length);
        assert.ok(steps >= 1, 'no steps listed');
        assert.ok(shown.nodes > 0, 'a ray through the model visits nodes');
        // the heat mode's cost at that pixel: a one-pixel region of the same heat frame
        const heat = await postJSON(d.base, '/api/render', {
            model: ray.model, accel: ray.accel, builder: ray.builder, mode: 'heat', camera: ray.camera,
            width: ray.width, height: ray.height, spp: 1, format: 'json', region: { x: ray.x, y: ray.y, w: 1, h: 1 },
        });
        assert.equal(heat.status, 200, heat.text);
        assert.equal(shown.nodes, heat.json.mean_nodes, 'node steps differ from heat mode');
        assert.equal(shown.tris, heat.json.mean_tris, 'triangle tests differ from heat mode');
        // the page drew the visited boxes over the frame
        const ov = await overlayBox(page, 0, 640, 480);
        assert.ok(ov && ov.n > 50, 'no visited boxes drawn');
        assert.deepEqual(errors, []);
    });
});

test('the compare view shows a progress bar and then eight bars per chart', T, async () => {
    await withViewer({ daemon: { shared: ['castle.obj'] } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=castle&tab=compare`);
        await page.waitForSelector('#compare-section:not([hidden])');
        await page.waitForFunction(() => document.getElementById('model').value === 'castle');
        await page.click('#cmp-start');
        await page.waitForSelector('#cmp-progress-wrap:not([hidden]) #cmp-progress', { timeout: 10000 });
        await screenshot(page, 'compare-progress');
        await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent) ||
            !document.getElementById('cmp-error').hidden, null, { timeout: 170000 });
        const err = await page.$eval('#cmp-error', (e) => (e.hidden ? '' : e.textContent));
        assert.equal(err, '');
        const charts = await page.$$eval('figure.chart', (fs) => fs.map((f) => ({
            metric: f.dataset.metric,
            ours: [...f.querySelectorAll('rect.bar.ours')].map((r) => r.dataset.value),
            study: f.querySelectorAll('rect.bar.study').length,
        })));
        await screenshot(page, 'compare-done');
        assert.equal(charts.length, 10);
        for (const c of charts) {
            assert.equal(c.ours.length, 8, `${c.metric}: ${c.ours.length} bars`);
            assert.ok(c.ours.every((v) => v !== ''), `${c.metric}: a bar without a value`);
        }
        // every tree's diffuse rays step through a node and test a triangle at least
        for (const m of ['diffuse_nodes_per_ray', 'diffuse_tris_per_ray']) {
            assert.ok(charts.find((c) => c.metric === m).ours.every((v) => Number(v) > 0), `${m}: a bar at 0`);
        }
        // castle is in the study: its seven trees beside ours in tables 1-4
        for (const m of ['build_ms', 'render_ms', 'mean_leaf_depth', 'mean_tris_per_leaf']) {
            assert.equal(charts.find((c) => c.metric === m).study, 7, `${m}: study bars`);
        }
        assert.deepEqual(errors, []);
    });
});

// "Beside" sends the job's embree (true, or "robust" for Embree's robust
// mode); the ray charts then carry Embree's line, named for its mode, at the
// job's own figure; a daemon without Embree says how to get it instead.
test('the compare view draws Embree beside the trees, at its default and in its robust mode', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const bodies = [], jobs = [];
        page.on('response', async (r) => {
            if (new URL(r.url()).pathname !== '/api/bench' || r.request().method() !== 'POST') return;
            bodies.push(JSON.parse(r.request().postData()));
            jobs.push((await r.json()).id);
        });
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForSelector('#compare-section:not([hidden])');
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        // a daemon built without Embree says so, and the page does not offer it (viewer-review.test.mjs)
        const { daemon } = await fetch(`${d.base}/api/stats`).then((r) => r.json());
        if (!daemon.embree) {
            await page.waitForSelector('#cmp-peer option[value="embree"]:disabled', { state: 'attached' });
            return;
        }
        for (const [choice, sent, name] of [['embree', true, 'Embree'], ['robust', 'robust', 'Embree, robust']]) {
            const k = bodies.length;
            await page.selectOption('#cmp-peer', choice);
            await page.click('#cmp-start');
            await page.waitForFunction(() => !/^done/.test(document.getElementById('cmp-progress-text').textContent));
            await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent) ||
                !document.getElementById('cmp-error').hidden, null, { timeout: 170000 });
            assert.equal(bodies.length, k + 1);
            assert.equal(bodies[k].embree, sent);
            assert.equal(await page.$eval('#cmp-error', (e) => (e.hidden ? '' : e.textContent)), '');
            const job = await fetch(`${d.base}/api/jobs/${jobs[k]}`).then((r) => r.json());
            const peer = job.rows.find((r) => r.accel === 'embree');
            assert.equal(peer.builder, sent === 'robust' ? 'robust' : 'default');
            const charts = await page.$$eval('figure.chart', (fs) => fs.map((f) => ({
                metric: f.dataset.metric,
                line: f.querySelectorAll('line.embree').length,
                label: f.querySelector('text.embree-label')?.textContent || '',
            })));
            await screenshot(page, `compare-beside-${choice}`);
            assert.deepEqual(chartClashes(await chartLayout(page)), []);
            for (const c of charts) {
                const rays = /^(primary|diffuse|shadow)_mrays$/.test(c.metric);
                assert.equal(c.line, rays ? 1 : 0, `${c.metric}: Embree lines`);
                if (!rays) continue;
                const m = c.label.match(/^(.*) ([0-9.,]+)$/);
                assert.ok(m && m[1] === name, `${c.metric}: label ${c.label}`);
                const shown = Number(m[2].replace(/,/g, ''));
                assert.ok(Math.abs(shown - peer[c.metric]) <= Math.max(0.006, 0.01 * peer[c.metric]),
                    `${c.metric}: ${shown} shown, ${peer[c.metric]} in the job`);
            }
        }
        assert.deepEqual(errors, []);
    });
});

test('the field of view slider: the model scales by the tangents\' ratio about the centre, its root box still its silhouette, the URL and a reset keep it, its note\'s button goes back to 45', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=cornell&mode=normals&spp=1`);
        await waitFullFrame(page);
        assert.equal(await page.inputValue('#fov'), '45');
        assert.equal(await page.isVisible('#fov-default'), false, 'a way back to 45 degrees at 45 degrees');
        const bg = rec.renders.filter((r) => r.width === 640).pop().background.map((c) => Math.round(c * 255));
        const wide = await framePixels(page, 0, bg, 10);
        const [x0, y0, x1, y1] = wide.bbox;
        assert.ok(x0 > 0 && y0 > 0 && x1 < wide.w && y1 < wide.h, `the model is cut by the frame at 45 degrees: ${wide.bbox}`);
        await page.fill('#fov', '90');
        await page.dispatchEvent('#fov', 'input');
        const cam = await page.waitForFunction(() => {
            const c = document.querySelector('canvas.image[data-pane="0"][data-frame="full"]');
            return c && JSON.parse(c.dataset.camera).fov === 90 && JSON.parse(c.dataset.camera);
        }, null, { timeout: 30000 }).then((h) => h.jsonValue());
        assert.equal(await page.textContent('#fov-out'), '90°');
        assert.equal(rec.renders.filter((r) => r.width === 640).pop().camera.fov, 90);
        // the eye stays: every image point moves toward the centre by tan(22.5)/tan(45)
        const k = Math.tan(Math.PI / 8), cx = wide.w / 2, cy = wide.h / 2;
        const px = await framePixels(page, 0, bg, 10);
        const want = [cx + k * (x0 - cx), cy + k * (y0 - cy), cx + k * (x1 - cx), cy + k * (y1 - cy)];
        px.bbox.forEach((v, i) => assert.ok(Math.abs(v - want[i]) <= 2, `the model at 90 degrees spans ${px.bbox}, not ${want.map(Math.round)}`));
        // the overlay projects with the same field of view: cornell's root box is its silhouette
        await page.check('#boxes-on');
        await page.waitForFunction(() => /\d box/.test(document.getElementById('boxes-info').textContent), null, { timeout: 30000 });
        const ov = await overlayBox(page, 0, px.w, px.h);
        assert.ok(ov, 'no box drawn over the frame');
        ov.bbox.forEach((v, i) => assert.ok(Math.abs(v - px.bbox[i]) <= 4, `root box ${ov.bbox.map(Math.round)} is not the model's silhouette ${px.bbox}`));
        await screenshot(page, 'fov-90');
        assert.match(page.url(), /[?&]fov=90(&|$)/);
        await page.reload();
        assert.equal((await waitFullFrame(page)).fov, 90);
        assert.equal(await page.inputValue('#fov'), '90');
        // Reset view (R) resets the orbit, not the field of view
        await page.goto(page.url().replace(/yaw=[^&]*/, 'yaw=77'));
        assert.equal((await waitFullFrame(page)).yaw, 77);
        await page.keyboard.press('r');
        const reset = await page.waitForFunction(() => {
            const c = document.querySelector('canvas.image[data-pane="0"][data-frame="full"]');
            return c && JSON.parse(c.dataset.camera).yaw !== 77 && JSON.parse(c.dataset.camera);
        }, null, { timeout: 30000 }).then((h) => h.jsonValue());
        assert.deepEqual(reset, cam);
        assert.equal(await page.inputValue('#fov'), '90');
        // ... and the note's button goes back to the protocol's 45 degrees, then hides
        await page.click('#fov-default');
        const back = await page.waitForFunction(() => {
            const c = document.querySelector('canvas.image[data-pane="0"][data-frame="full"]');
            return c && JSON.parse(c.dataset.camera).fov === 45 && JSON.parse(c.dataset.camera);
        }, null, { timeout: 30000 }).then((h) => h.jsonValue());
        assert.deepEqual({ ...back, fov: 90 }, cam, 'going back to 45 degrees moved the eye');
        assert.equal(await page.inputValue('#fov'), '45');
        assert.equal(await page.textContent('#fov-out'), '45°');
        assert.equal(await page.isVisible('#fov-default'), false);
        await page.waitForFunction(() => /[?&]fov=45(&|$)/.test(location.search));
        assert.deepEqual(errors, []);
    });
});

test('a link with a view in its URL restores the controls', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        const q = 'model=sphere&accel=kd&builder=mean&mode=normals&spp=1&res=320x240&yaw=40&pitch=-20&dist=2&fov=50&depth=3&boxes=all';
        await page.goto(`${d.base}/?${q}`);
        const cam = await waitFullFrame(page);
        assert.equal(await page.inputValue('#model'), 'sphere');
        assert.equal(await page.inputValue('#accel'), 'kd');
        assert.equal(await page.inputValue('#builder'), 'mean');
        assert.equal(await page.inputValue('#mode'), 'normals');
        assert.equal(await page.inputValue('#spp'), '1');
        assert.equal(await page.inputValue('#res'), '320x240');
        assert.equal(await page.inputValue('#fov'), '50');
        assert.equal(await page.textContent('#fov-out'), '50°');
        assert.equal(await page.isChecked('#boxes-on'), true);
        assert.equal(await page.inputValue('#depth'), '3');
        assert.equal(await page.isChecked('#boxes-all'), true);
        assert.deepEqual(cam, { yaw: 40, pitch: -20, distance: 2, fov: 50 });
        const first = rec.renders[0];
        assert.equal(first.model, 'sphere');
        assert.equal(first.accel, 'kd');
        assert.equal(first.builder, 'mean');
        assert.deepEqual(first.camera, cam);
        const full = rec.renders.filter((r) => r.width === 320);
        assert.ok(full.length, 'no 320x240 frame');
        // the page keeps the view in its URL: reopening it gives the same frame
        const url = page.url();
        for (const part of q.split('&')) assert.ok(url.includes(part), `${part} missing from ${url}`);
        const px1 = await framePixels(page);
        await page.goto(url);
        await waitFullFrame(page);
        const px2 = await framePixels(page);
        assert.equal(px2.hash, px1.hash, 'reopening the link gives another frame');
        await screenshot(page, 'url-restored');
        assert.deepEqual(errors, []);
    });
});

test("a broken OBJ upload shows the daemon's error, over the page without moving it", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell`);
        await waitFullFrame(page);
        const before = await frameBox(page);
        const answer = page.waitForResponse((r) => new URL(r.url()).pathname === '/api/models/broken');
        await page.setInputFiles('#file-input', {
            name: 'broken.obj',
            mimeType: 'text/plain',
            buffer: Buffer.from('# a face with vertices that do not exist\nv 0 0 0\nv 1 0 0\nf 1 2 7\n'),
        });
        const res = await answer;
        assert.ok(res.status() >= 400, `the daemon took the broken model (${res.status()})`);
        const body = await res.json();
        assert.ok(body.error && body.error.message, 'the daemon answered without an error message');
        await page.waitForSelector('#upload-status.error', { timeout: 10000 });
        const text = await page.textContent('#upload-text');
        assert.ok(text.includes(body.error.message), `"${text}" does not show "${body.error.message}"`);
        assert.ok(text.includes(String(res.status())), 'the status is not shown');
        await screenshot(page, 'upload-error');
        assert.deepEqual(await frameBox(page), before, 'the upload error moved the frame');
        const shown = await page.$eval('#upload-status', (e) => {
            const r = e.getBoundingClientRect();
            return { left: r.left, right: r.right, width: innerWidth };
        });
        assert.ok(shown.left >= 0 && shown.right <= shown.width, `the upload error sticks out: ${JSON.stringify(shown)}`);
        const names = await page.$$eval('#model option', (o) => o.map((e) => e.value));
        assert.ok(!names.includes('broken'));
        // the browser logs failed loads as console errors; the only one allowed is this upload's
        assert.deepEqual(errors.filter((e) => !/status of 4\d\d/.test(e)), []);
    });
});

test('the phone viewport has no horizontal scroll', T, async () => {
    await withViewer({ browser: { viewport: { width: 375, height: 667 }, mobile: true, colorScheme: 'light' } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell`);
        await waitFullFrame(page);
        const widths = await page.evaluate(() => [document.documentElement.scrollWidth, document.body.scrollWidth, window.innerWidth]);
        await screenshot(page, 'phone');
        assert.ok(widths[0] <= widths[2] && widths[1] <= widths[2], `scroll width ${widths[0]}/${widths[1]} > ${widths[2]}`);
        const frame = await frameBox(page);
        assert.ok(frame.x >= 0 && frame.x + frame.width <= 375, 'the frame sticks out');
        // one-finger touch drag orbits
        const cam0 = await waitFullFrame(page);
        const client = await page.context().newCDPSession(page);
        const cx = frame.x + frame.width / 2, cy = frame.y + frame.height / 2;
        await client.send('Input.dispatchTouchEvent', { type: 'touchStart', touchPoints: [{ x: cx, y: cy }] });
        for (let i = 1; i <= 10; i++) {
            await client.send('Input.dispatchTouchEvent', { type: 'touchMove', touchPoints: [{ x: cx + i * 6, y: cy }] });
        }
        await client.send('Input.dispatchTouchEvent', { type: 'touchEnd', touchPoints: [] });
        await waitFrameMovedFrom(page, cam0);
        await page.click('#tab-compare');
        const w2 = await page.evaluate(() => [document.documentElement.scrollWidth, window.innerWidth]);
        assert.ok(w2[0] <= w2[1], `compare view scroll width ${w2[0]} > ${w2[1]}`);
        assert.deepEqual(errors, []);
    });
});

test('no console errors on load', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/`);
        await waitFullFrame(page);
        await page.waitForTimeout(500);
        const title = await page.title();
        assert.match(title, /arbor/);
        // every control has a label
        const unlabelled = await page.$$eval('select, input, button', (els) => els.filter((e) => {
            if (e.type === 'file') return false;
            const id = e.id && document.querySelector(`label[for="${e.id}"]`);
            return !id && !e.getAttribute('aria-label') && !(e.textContent || '').trim();
        }).map((e) => e.id || e.outerHTML.slice(0, 60)));
        assert.deepEqual(unlabelled, []);
        assert.deepEqual(errors, []);
    });
});

/** What sticks out sideways: the page past the window, a card's or a scroll box's content past its box. */
function overflows(page) {
    return page.evaluate(() => {
        const name = (e) => `${e.id || e.className} in ${e.closest('.card')?.querySelector('h2')?.textContent || '?'}`;
        const out = [];
        if (document.documentElement.scrollWidth > innerWidth) out.push(`the page: ${document.documentElement.scrollWidth} > ${innerWidth}`);
        for (const e of document.querySelectorAll('.card, .scroll')) {
            if (e.offsetParent && e.scrollWidth > e.clientWidth) out.push(`${name(e)}: ${e.scrollWidth} > ${e.clientWidth}`);
        }
        for (const t of document.querySelectorAll('table.kv')) {
            const box = t.parentElement.getBoundingClientRect(), r = t.getBoundingClientRect();
            if (t.offsetParent && r.right > box.right + 0.5) out.push(`table ${name(t)} ends at ${r.right}, its box at ${box.right}`);
        }
        return out;
    });
}

/** Pairs of neighbouring labels less than `gap` apart (or overlapping), from their boxes [left, right]. */
function crowded(boxes, gap) {
    const sorted = [...boxes].sort((a, b) => a.left - b.left);
    return sorted.slice(1).map((b, i) => [sorted[i], b]).filter(([a, b]) => b.left - a.right < gap)
        .map(([a, b]) => `"${a.text}" and "${b.text}": ${(b.left - a.right).toFixed(1)} apart`);
}

/** Each compare chart's axis labels and bar value labels ([left, right] in SVG units) and Embree's line (x, or null). */
function chartLayout(page) {
    return page.$$eval('figure.chart', (fs) => fs.map((f) => {
        const box = (t) => {
            const b = t.getBBox();
            return { text: t.textContent, left: b.x, right: b.x + b.width };
        };
        const line = f.querySelector('line.embree');
        return {
            metric: f.dataset.metric,
            ticks: [...f.querySelectorAll('text.tick')].map(box),
            values: [...f.querySelectorAll('text.value:not(.tick)')].map(box),
            line: line ? Number(line.getAttribute('x1')) : null,
        };
    }));
}

/** Axis labels closer than 8 units, and value labels that Embree's line runs through. */
function chartClashes(charts) {
    return charts.flatMap((c) => [
        ...crowded(c.ticks, 8).map((w) => `${c.metric}: axis labels ${w}`),
        ...c.values.filter((v) => c.line !== null && v.left - 1 < c.line && c.line < v.right + 1)
            .map((v) => `${c.metric}: Embree's line at ${c.line.toFixed(1)} crosses "${v.text}"`),
    ]);
}

test('split view, its stats and the ray inspector fit their cards at 1400, 1920 and 420 px wide', T, async () => {
    await withViewer({ daemon: { shared: ['bunny.obj'] }, browser: { viewport: { width: 1400, height: 900 } } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=bunny&accel=kd&builder=median&split=bvh:median&spp=1`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        await page.waitForFunction(() => [...document.querySelectorAll('#stats-table tr[data-key="nodes"] td')]
            .filter((td) => /\d/.test(td.textContent)).length === 2, null, { timeout: 60000 });
        const box = await frameBox(page);
        await page.mouse.click(box.x + box.width * 0.5, box.y + box.height * 0.5);
        await page.waitForSelector('#ray-heat', { timeout: 30000 });
        for (const [width, height] of [[1400, 900], [1920, 1080], [420, 900]]) {
            await page.setViewportSize({ width, height });
            await page.waitForTimeout(300);
            await screenshot(page, `split-ray-${width}`);
            assert.deepEqual(await overflows(page), [], `at ${width} px`);
        }
        // both trees' columns give their binary tree's bytes as built (the BVH's too, though freed once collapsed)
        const bytes = await page.$$eval('#stats-table tr[data-key="bytes"] td', (tds) => tds.map((td) => td.textContent.trim()));
        assert.match(bytes[0], /MiB$/);
        assert.match(bytes[1], /MiB$/);
        // the heat legend's numbers stay apart in the narrow card (one bar: the panes share a scale)
        await page.setViewportSize({ width: 1400, height: 900 });
        await page.selectOption('#mode', 'heat');
        await page.waitForFunction(() => [...document.querySelectorAll('#legend .legend-row')]
            .filter((r) => r.dataset.heatScale !== '' && r.dataset.pane === '0 1').length === 1, null, { timeout: 60000 });
        await screenshot(page, 'split-heat-legend');
        const rows = await page.$$eval('#legend .legend-ticks', (ts) => ts.map((t) => [...t.children].map((s) => {
            const r = s.getBoundingClientRect();
            return { text: s.textContent, left: r.left, right: r.right };
        })));
        for (const ticks of rows) assert.deepEqual(crowded(ticks, 12), [], JSON.stringify(ticks.map((t) => t.text)));
        assert.deepEqual(errors, []);
    });
});

test('the selects of the controls show their choices whole', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&accel=kd&builder=spatial&split=bvh:median`);
        await waitFullFrame(page);
        for (const [width, height] of [[1400, 900], [1280, 800], [420, 900]]) {
            await page.setViewportSize({ width, height });
            // a select as wide as its widest option needs: a copy of it at its own width
            // (not the model's: its names are the daemon's, up to 64 characters)
            const cut = await page.$$eval('.side select:not(#model)', (sels) => sels.map((sel) => {
                const copy = sel.cloneNode(true);
                Object.assign(copy.style, { position: 'absolute', width: 'auto', visibility: 'hidden' });
                sel.parentElement.append(copy);
                const need = copy.getBoundingClientRect().width;
                copy.remove();
                return { id: sel.id, has: sel.getBoundingClientRect().width, need };
            }).filter((s) => s.has < s.need - 0.5));
            assert.deepEqual(cut, [], `at ${width} px`);
        }
        assert.deepEqual(errors, []);
    });
});

test('the boxes line says how many of how many boxes it draws when they are capped', T, async () => {
    await withViewer({ daemon: { shared: ['bunny.obj'] } }, async (d, { page, errors }) => {
        const first = page.waitForResponse((r) => /\/boxes\?/.test(r.url()), { timeout: 60000 });
        await page.goto(`${d.base}/?model=bunny&accel=kd&builder=median&spp=1&depth=20&boxes=leaves`);
        await waitFullFrame(page, 0, 60000);
        // the line once the boxes of that depth are in (window.arbor: the page's app) and the panels redrawn
        const info = async (depth) => {
            await page.waitForFunction((dep) => window.arbor.panes[0].boxes?.data?.depth === dep, depth, { timeout: 60000 });
            await afterPaint(page);
            return page.textContent('#boxes-info');
        };
        const num = (v) => v.toLocaleString('en-US');
        const said = await info(20);
        await screenshot(page, 'boxes-capped');
        const real = await (await first).json();
        assert.equal(real.truncated, true, 'bunny kd median has fewer leaves than the cap');
        assert.equal(real.boxes.length, real.max_boxes);
        // the daemon counts every matching node (count) or only those it sends: either reads right
        assert.equal(said, real.count > real.boxes.length
            ? `k-d median: ${num(real.boxes.length)} of ${num(real.count)} leaf boxes up to depth 20 drawn (an even sample: at most ${num(real.max_boxes)})`
            : `k-d median: ${num(real.boxes.length)} leaf boxes up to depth 20 drawn, more left out (an even sample: at most ${num(real.max_boxes)})`);
        for (const [depth, extra, words] of [[21, 0, /^k-d median: 20,000 leaf boxes up to depth 21 drawn, more left out \(an even sample: at most 20,000\)$/],
            [22, 98287, /^k-d median: 20,000 of 118,287 leaf boxes up to depth 22 drawn \(an even sample: at most 20,000\)$/]]) {
            await page.route('**/boxes?*', async (route) => {
                const res = await route.fetch();
                const json = await res.json();
                route.fulfill({ response: res, json: { ...json, count: json.boxes.length + extra } });
            });
            await page.fill('#depth', String(depth));
            await page.dispatchEvent('#depth', 'input');
            assert.match(await info(depth), words);
            await page.unroute('**/boxes?*');
        }
        assert.deepEqual(errors, []);
    });
});

// A re-run cancelled half way leaves the charts of the run that finished.
test('cancelling a re-run of the compare view keeps the last finished charts', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        const bars = () => page.$$eval('figure.chart', (fs) => fs.map((f) => [f.dataset.metric,
            [...f.querySelectorAll('rect.bar.ours')].map((r) => r.dataset.value),
            [...f.querySelectorAll('text.value')].map((t) => t.textContent)]));
        await page.click('#cmp-start');
        await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent), null, { timeout: 170000 });
        const finished = await bars();
        assert.equal(finished.length, 10);
        await page.click('#cmp-start');
        // the re-run's first rows are drawn with placeholders for the rest
        await page.waitForFunction(() => [...document.querySelectorAll('figure.chart text.value')].some((t) => t.textContent === '…'),
            null, { timeout: 60000 });
        await page.click('#cmp-cancel');
        await page.waitForFunction(() => !document.getElementById('cmp-error').hidden, null, { timeout: 30000 });
        await screenshot(page, 'compare-rerun-cancelled');
        assert.equal(await page.textContent('#cmp-error'),
            'The re-run of the benchmark of sphere was cancelled. The charts show the last finished run.');
        assert.deepEqual(await bars(), finished);
        assert.equal(await page.isDisabled('#cmp-start'), false);
        assert.deepEqual(errors, []);
    });
});

// The charts' layout, on rows made to crowd it: a build-time axis to 86,000
// ms with bars of 0.74 ms beside, and bars that end just short of Embree's line.
test("the compare charts keep axis labels apart and bar values off Embree's line", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const trees = [['bvh', 'spatial'], ['bvh', 'median'], ['bvh', 'mean'], ['bvh', 'sah'],
            ['kd', 'spatial'], ['kd', 'median'], ['kd', 'mean'], ['kd', 'sah']];
        const rows = trees.map(([accel, builder], i) => ({
            model: 'sphere', accel, builder,
            build_ms: [0.74, 1.99, 0.79, 1.98, 79.79, 42.48, 32.42, 86000][i],
            render_ms: [1.5, 30, 400, 5000, 6e4, 7e5, 8e6, 120][i],
            mean_leaf_depth: 10 + i, mean_tris_per_leaf: 2 + i, sah_cost: 30 + i,
            primary_mrays: [33.09, 22.1, 34.85, 13.97, 13.38, 8.54, 8.21, 21.9][i],
            diffuse_mrays: [7.3, 5.67, 8.4, 7.04, 1.14, 0.87, 2.19, 4.3][i],
            shadow_mrays: [13.21, 10.46, 14.34, 13.82, 3.53, 3.27, 2.55, 7.7][i],
            diffuse_nodes_per_ray: 9 + i, diffuse_tris_per_ray: 20 + i,
        }));
        rows.push({ model: 'sphere', accel: 'embree', builder: 'robust', primary_mrays: 22.66, diffuse_mrays: 5.84, shadow_mrays: 9.36 });
        const job = { id: '7', model: 'sphere', state: 'done', progress: { done: 9, total: 9 }, elapsed_ms: 1000, rows, error: null };
        await page.route('**/api/bench', (r) => r.fulfill({ status: 202, json: { id: '7', state: 'queued' } }));
        await page.route('**/api/jobs/7', (r) => r.fulfill({ json: job }));
        await page.goto(`${d.base}/?model=sphere&tab=compare`);
        await page.waitForFunction(() => document.getElementById('model').value === 'sphere');
        await page.click('#cmp-start');
        await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent));
        await screenshot(page, 'compare-crowded');
        const charts = await chartLayout(page);
        assert.equal(charts.length, 10);
        assert.ok(charts.find((c) => c.metric === 'build_ms').ticks.length >= 3, 'the build-time axis has fewer than 3 ticks');
        assert.equal(charts.filter((c) => c.line !== null).length, 3);
        assert.deepEqual(chartClashes(charts), []);
        assert.deepEqual(errors, []);
    });
});

// --token-file: changes need the token, frames and reads do not. The viewer
// builds trees through the open GET /api/stats, and asks for the token when an
// upload or a benchmark is refused.
test('a daemon with --token-file: no false error, stats shown, and a token typed in lets an upload and a benchmark through', T, async () => {
    const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'arbor-token-'));
    const tokenFile = path.join(dir, 'token');
    fs.writeFileSync(tokenFile, 'e2e-token-0123\n');
    try {
        await withViewer({ daemon: { extraArgs: ['--token-file', tokenFile] } }, async (d, { page, errors }) => {
            const sent = [];
            page.on('request', (r) => {
                if (r.method() !== 'GET') sent.push({ method: r.method(), path: new URL(r.url()).pathname, auth: r.headers().authorization || '' });
            });
            await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah`);
            await waitFullFrame(page, 0, 60000);
            // the tree's stats, or the error the viewer said instead
            await page.waitForFunction(() => /\d/.test(document.querySelector('#stats-table tr[data-key="nodes"] td').textContent) ||
                document.querySelector('.notice.error, #stats .error'), null, { timeout: 60000 });
            assert.deepEqual(await page.$$eval('.notice, #stats .error, .badge.error:not([hidden])', (e) => e.map((x) => x.textContent)), []);
            const st = (await fetch(`${d.base}/api/stats?model=sphere&accel=kd&builder=sah`).then((r) => r.json()))
                .trees.find((t) => t.model === 'sphere' && t.accel === 'kd' && t.builder === 'sah');
            assert.equal(await page.textContent('#stats-table tr[data-key="nodes"] td'), st.nodes.toLocaleString('en-US'));
            assert.deepEqual(sent.filter((r) => r.path.endsWith('/trees')), [], 'the tree was built by a request that needs the token');
            await screenshot(page, 'token-tree');

            // an upload is refused: the token is asked for, a wrong one refused, the right one lets it through
            await page.setInputFiles('#file-input', {
                name: 'tri.obj', mimeType: 'text/plain', buffer: Buffer.from('v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n'),
            });
            await page.waitForSelector('#token-dialog[open], #upload-status.error');
            assert.equal(await page.isVisible('#upload-status.error'), false, await page.textContent('#upload-text'));
            assert.match(await page.textContent('#token-why'), /Uploading tri\.obj as "tri" needs this daemon's bearer token/);
            assert.equal(await page.isVisible('#token-refused'), false);
            await page.fill('#token-input', 'not-the-token');
            await page.click('#token-dialog button[type="submit"]');
            await page.waitForFunction(() => document.getElementById('token-dialog').open &&
                !document.getElementById('token-refused').hidden, null, { timeout: 10000 });
            assert.equal(await page.evaluate(() => sessionStorage.getItem('arbor.token')), null, 'a refused token was kept');
            await screenshot(page, 'token-refused');
            await page.fill('#token-input', 'e2e-token-0123');
            await page.click('#token-dialog button[type="submit"]');
            await page.waitForFunction(() => [...document.querySelectorAll('#model option')].some((o) => o.value === 'tri'), null, { timeout: 10000 });
            assert.match(await page.textContent('#upload-text'), /Uploaded "tri"/);
            const puts = sent.filter((r) => r.path === '/api/models/tri').map((r) => r.auth);
            assert.deepEqual(puts, ['', 'Bearer not-the-token', 'Bearer e2e-token-0123']);
            assert.equal(await page.evaluate(() => sessionStorage.getItem('arbor.token')), 'e2e-token-0123');

            // a benchmark asks for the token as well (of sphere: long enough to cancel)
            await page.evaluate(() => sessionStorage.clear());
            await page.selectOption('#model', 'sphere');
            await page.click('#tab-compare');
            await page.click('#cmp-start');
            await page.waitForSelector('#token-dialog[open], #cmp-error:not([hidden])');
            assert.match(await page.textContent('#token-why'), /^Starting the benchmark of sphere needs/);
            await page.fill('#token-input', 'e2e-token-0123');
            await page.click('#token-dialog button[type="submit"]');
            await page.click('#cmp-cancel', { timeout: 30000 });
            await page.waitForFunction(() => /was cancelled/.test(document.getElementById('cmp-error').textContent), null, { timeout: 30000 });
            assert.deepEqual(sent.filter((r) => r.path === '/api/bench' || r.path.startsWith('/api/jobs/')).map((r) => `${r.method} ${r.auth}`),
                ['POST ', 'POST Bearer e2e-token-0123', 'DELETE Bearer e2e-token-0123']);
            // the refused requests are the browser's only console errors
            assert.deepEqual(errors.filter((e) => !/status of 401/.test(e)), []);
        });
    } finally {
        fs.rmSync(dir, { recursive: true, force: true });
    }
});
