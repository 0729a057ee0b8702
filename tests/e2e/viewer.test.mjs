// viewer.test.mjs - the viewer (web/) in Debian's chromium against a real
// arbord serve: frames, orbit, stats and legend, the box overlay against the
// rendered model, the ray inspector against heat mode, compare, URL state,
// upload errors, the phone layout and a clean console.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import {
    withViewer, screenshot, recordRequests, waitFullFrame, framePixels, overlayBox, postJSON,
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
        await page.waitForFunction((c0) => {
            const c = document.querySelector('canvas.image[data-pane="0"]');
            return c.dataset.frame === 'full' && c.dataset.camera !== c0;
        }, JSON.stringify(cam0), { timeout: 30000 });
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
        assert.equal(ticks.length, 6);
        assert.equal(ticks[0], '0');
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
            await page.waitForFunction(() => /box/.test(document.getElementById('boxes-info').textContent) ||
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
        // deeper levels draw more boxes
        await page.fill('#depth', '3');
        await page.dispatchEvent('#depth', 'input');
        await page.waitForFunction(() => /at depth 3/.test(document.getElementById('boxes-info').textContent), null, { timeout: 30000 });
        const n = await page.textContent('#boxes-info');
        assert.match(n, /(\d+) boxes at depth 3/);
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
        for (const [choice, sent, name] of [['embree', true, 'Embree'], ['robust', 'robust', 'Embree, robust']]) {
            const k = bodies.length;
            await page.selectOption('#cmp-peer', choice);
            await page.click('#cmp-start');
            await page.waitForFunction(() => !/^done/.test(document.getElementById('cmp-progress-text').textContent));
            await page.waitForFunction(() => /^done/.test(document.getElementById('cmp-progress-text').textContent) ||
                !document.getElementById('cmp-error').hidden, null, { timeout: 170000 });
            assert.equal(bodies.length, k + 1);
            assert.equal(bodies[k].embree, sent);
            const err = await page.$eval('#cmp-error', (e) => (e.hidden ? '' : e.textContent));
            if (err) {
                assert.match(err, /built without Embree; run `make bench-embree`/);
                return;
            }
            const job = await fetch(`${d.base}/api/jobs/${jobs[k]}`).then((r) => r.json());
            const peer = job.rows.find((r) => r.accel === 'embree');
            assert.equal(peer.builder, sent === 'robust' ? 'robust' : 'default');
            const charts = await page.$$eval('figure.chart', (fs) => fs.map((f) => ({
                metric: f.dataset.metric,
                line: f.querySelectorAll('line.embree').length,
                label: f.querySelector('text.embree-label')?.textContent || '',
            })));
            await screenshot(page, `compare-beside-${choice}`);
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

test("a broken OBJ upload shows the daemon's error", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell`);
        await waitFullFrame(page);
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
        await page.waitForFunction((c0) => {
            const c = document.querySelector('canvas.image[data-pane="0"]');
            return c.dataset.frame === 'full' && c.dataset.camera !== c0;
        }, JSON.stringify(cam0), { timeout: 30000 });
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
