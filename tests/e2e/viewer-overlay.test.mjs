// viewer-overlay.test.mjs - the lines drawn over the frame, as a person who
// orbits a model and looks at a tree's boxes and a ray's path sees them: the
// boxes where the renderer's camera puts them, a colour per depth that the
// key under the frame names, standing out from the frame's background in
// either colour scheme, cased over a heat frame; a ray's path in colours apart from every depth's,
// the ray a line once the view turns; a sharp overlay with a ring of one size
// at two device pixels per CSS pixel; no boxes stretched over the strips of a
// new resolution; a key that follows what is drawn; and Save PNG with what
// the overlay draws.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, screenshot, waitFullFrame, overlayBox, savePNG, afterPaint } from './lib.mjs';

const T = { timeout: 180000 };

/** Waits for pane 0's boxes of `depth`, and a full frame under them, drawn. */
async function boxesShown(page, depth) {
    await waitFullFrame(page, 0, 60000);
    await page.waitForFunction((d) => window.arbor.panes[0].boxes?.data?.depth === d, depth, { timeout: 60000 });
    await afterPaint(page);
}

/** The key's entries: [{depth | part, colour: [r, g, b]}], as the page shows them. */
function keyEntries(page, row) {
    return page.$$eval(`#overlay-key:not([hidden]) #${row} .key-item`, (items) => items.map((e) => {
        const c = getComputedStyle(e.querySelector('.key-swatch')).borderTopColor.match(/\d+/g).slice(0, 3).map(Number);
        return e.dataset.depth !== undefined ? { depth: Number(e.dataset.depth), colour: c } : { part: e.dataset.part, colour: c };
    }));
}

/**
 * Counts of pane `index`'s overlay pixels at least `minAlpha` opaque: in all,
 * and near each of `colours` (within tol in every channel).
 */
function overlayColours(page, colours, { index = 0, minAlpha = 160, tol = 14 } = {}) {
    return page.evaluate(({ index, colours, minAlpha, tol }) => {
        const o = document.querySelectorAll('canvas.overlay')[index];
        const d = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
        const near = colours.map(() => 0);
        let all = 0, matched = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (d[i + 3] < minAlpha) continue;
            all++;
            const k = colours.findIndex((c) => Math.abs(c[0] - d[i]) <= tol && Math.abs(c[1] - d[i + 1]) <= tol && Math.abs(c[2] - d[i + 2]) <= tol);
            if (k >= 0) { near[k]++; matched++; }
        }
        return { all, matched, near };
    }, { index, colours, minAlpha, tol });
}

/**
 * The edges of pane 0's boxes, projected by camera.js with the frame's camera,
 * that have no drawn overlay pixel near their middle (those on the canvas).
 */
function undrawnEdges(page) {
    return page.evaluate(async () => {
        const { boxCorners, projectSegment, BOX_EDGES } = await import('/js/camera.js');
        const p = window.arbor.panes[0], cam = p.shown.cam, o = p.overlay;
        const sx = o.width / cam.width, sy = o.height / cam.height;
        const d = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
        const drawnNear = (x, y) => {
            for (let j = -2; j <= 2; j++) {
                for (let i = -2; i <= 2; i++) {
                    const px = Math.round(x) + i, py = Math.round(y) + j;
                    if (px >= 0 && py >= 0 && px < o.width && py < o.height && d[(py * o.width + px) * 4 + 3] > 0) return true;
                }
            }
            return false;
        };
        let edges = 0, undrawn = 0;
        for (const b of p.boxes.data.boxes) {
            const k = boxCorners(b);
            for (const [a, c] of BOX_EDGES) {
                const s = projectSegment(cam, k[a], k[c]);
                if (!s) continue;
                const x = ((s[0][0] + s[1][0]) / 2) * sx, y = ((s[0][1] + s[1][1]) / 2) * sy;
                if (x < 3 || y < 3 || x > o.width - 3 || y > o.height - 3) continue;
                edges++;
                if (!drawnNear(x, y)) undrawn++;
            }
        }
        return { edges, undrawn };
    });
}

/** Hue of an [r, g, b] colour in degrees. */
function hue([r, g, b]) {
    const max = Math.max(r, g, b), min = Math.min(r, g, b), c = max - min;
    if (c === 0) return 0;
    const h = max === r ? ((g - b) / c) % 6 : max === g ? (b - r) / c + 2 : (r - g) / c + 4;
    return (h * 60 + 360) % 360;
}
const hueApart = (a, b) => Math.min(Math.abs(hue(a) - hue(b)), 360 - Math.abs(hue(a) - hue(b)));

/** WCAG's contrast ratio of two [r, g, b] colours (0..255). */
function contrast(a, b) {
    const lum = (c) => {
        const l = c.map((v) => { v /= 255; return v <= 0.03928 ? v / 12.92 : ((v + 0.055) / 1.055) ** 2.4; });
        return 0.2126 * l[0] + 0.7152 * l[1] + 0.0722 * l[2];
    };
    const [hi, lo] = [lum(a), lum(b)].sort((x, y) => y - x);
    return (hi + 0.05) / (lo + 0.05);
}

/** Clicks the middle of pane 0's frame and waits for the traced ray drawn. */
async function inspectMiddle(page) {
    // a control filled further down the side panel may have scrolled the frame out of the viewport
    await page.locator('#frame-0').scrollIntoViewIfNeeded();
    const box = await page.locator('#frame-0').boundingBox();
    await page.mouse.click(box.x + box.width / 2, box.y + box.height / 2);
    await page.waitForSelector('#ray-counts', { timeout: 30000 });
    await afterPaint(page);
}

test("the tree's boxes are drawn where the renderer's camera puts them, each depth in the key's colour for it", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=3&boxes=all`);
        await boxesShown(page, 3);
        const key = await keyEntries(page, 'key-depths');
        assert.deepEqual(key.map((e) => e.depth), [0, 1, 2, 3]);
        const px = await overlayColours(page, key.map((e) => e.colour));
        await screenshot(page, 'overlay-depth-key');
        key.forEach((e, i) => assert.ok(px.near[i] > 20, `depth ${e.depth}'s colour rgb(${e.colour}) is not drawn: ${JSON.stringify(px)}`));
        // the rest: where lines of two depths cross or lie on each other (a k-d cell's edges are its parent's)
        assert.ok(px.matched >= 0.6 * px.all, `colours drawn that the key does not name: ${JSON.stringify(px)}`);
        const edges = await undrawnEdges(page);
        assert.ok(edges.edges > 50 && edges.undrawn === 0, JSON.stringify(edges));
        // from inside the root box, edges reach behind the eye: those in front are still drawn
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=3&boxes=all&yaw=20&pitch=10&dist=0.2`);
        await boxesShown(page, 3);
        const inside = await undrawnEdges(page);
        assert.ok(inside.edges > 10 && inside.undrawn === 0, JSON.stringify(inside));
        assert.deepEqual(errors, []);
    });
});

test("a ray's path is drawn in warm colours apart from every depth's cool ones, as the key says", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=12&boxes=all`);
        await boxesShown(page, 12);
        await inspectMiddle(page);
        await screenshot(page, 'overlay-ray-key');
        const depths = await keyEntries(page, 'key-depths');
        assert.equal(depths.length, 13);
        const parts = await keyEntries(page, 'key-ray');
        const data = await page.evaluate(() => window.arbor.rayInspect.data);
        const steps = data.steps;
        const want = [steps.some((s) => !s.leaf) && 'inner', steps.some((s) => s.leaf && s.tris > 0) && 'leaf',
            steps.some((s) => s.leaf && !s.tris) && 'empty', 'ray', data.hit ? 'hit' : 'miss'].filter(Boolean);
        assert.deepEqual(parts.map((p) => p.part), want);
        for (const p of parts.filter((e) => ['inner', 'leaf', 'empty'].includes(e.part))) {
            for (const dep of depths) {
                assert.ok(hueApart(p.colour, dep.colour) >= 45,
                    `the ray's ${p.part} rgb(${p.colour}) is near depth ${dep.depth}'s rgb(${dep.colour})`);
            }
        }
        const boxParts = parts.filter((e) => e.part === 'inner' || e.part === 'leaf');
        const px = await overlayColours(page, boxParts.map((p) => p.colour), { minAlpha: 220 });
        boxParts.forEach((p, i) => assert.ok(px.near[i] > 30, `the ray's ${p.part} colour is not drawn: ${JSON.stringify(px)}`));
        assert.deepEqual(errors, []);
    });
});

test("the tree's boxes stand out from the frame's background in the light and the dark scheme", T, async () => {
    for (const colorScheme of ['light', 'dark']) {
        await withViewer({ browser: { colorScheme } }, async (d, { page, errors }) => {
            await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=6&boxes=all`);
            await boxesShown(page, 6);
            await screenshot(page, `overlay-boxes-${colorScheme}`);
            const ratios = await page.evaluate(() => {
                const bg = window.arbor.background().map((c) => Math.round(c * 255));
                const o = document.querySelector('canvas.overlay');
                const px = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
                const out = [];
                for (let i = 0; i < px.length; i += 4) {
                    const a = px[i + 3] / 255;
                    if (a >= 0.6) out.push([[0, 1, 2].map((k) => px[i + k] * a + bg[k] * (1 - a)), bg]);
                }
                return out;
            }).then((pairs) => pairs.map(([c, bg]) => contrast(c, bg)).sort((a, b) => a - b));
            assert.ok(ratios.length > 1000, `${ratios.length} pixels drawn`);
            const low = ratios[Math.floor(ratios.length * 0.1)];
            assert.ok(low >= 2.5, `${colorScheme}: a tenth of the boxes' pixels contrast ${low.toFixed(2)}:1 or less with the background`);
            assert.deepEqual(errors, []);
        });
    }
});

test("over a heat frame, whose colours are the tree's, the boxes have a dark casing; over other frames they do not", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        // the overlay's near-black pixels: a casing's, as no depth's colour is that dark
        const dark = () => page.evaluate(() => {
            const o = document.querySelector('canvas.overlay');
            const px = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
            let drawn = 0, black = 0;
            for (let i = 0; i < px.length; i += 4) {
                if (px[i + 3] < 150) continue;
                drawn++;
                if (px[i] + px[i + 1] + px[i + 2] < 60) black++;
            }
            return { drawn, black };
        });
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=3&mode=heat`);
        await boxesShown(page, 3);
        await page.waitForFunction(() => window.arbor.panes[0].shown.req.mode === 'heat');
        await afterPaint(page);
        await screenshot(page, 'overlay-boxes-heat');
        // the key's depth swatches are cased as the boxes are
        const swatchesCased = () => page.$$eval('#key-depths .key-swatch', (s) => s.map((e) => getComputedStyle(e).boxShadow !== 'none'));
        const heat = await dark();
        assert.ok(heat.drawn > 1000 && heat.black > heat.drawn / 8, `over the heat frame: ${JSON.stringify(heat)}`);
        const keyHeat = await swatchesCased();
        assert.ok(keyHeat.length >= 1 && keyHeat.every(Boolean), `the key's swatches over heat: cased ${keyHeat}`);
        await page.selectOption('#mode', 'normals');
        await page.waitForFunction(() => window.arbor.panes[0].shown?.req.mode === 'normals' && !window.arbor.panes[0].shown.quick, null, { timeout: 60000 });
        await afterPaint(page);
        const normals = await dark();
        assert.ok(normals.drawn > 1000 && normals.black < normals.drawn / 50, `over the normals frame: ${JSON.stringify(normals)}`);
        const keyNormals = await swatchesCased();
        assert.ok(keyNormals.length >= 1 && !keyNormals.some(Boolean), `the key's swatches over normals: cased ${keyNormals}`);
        assert.deepEqual(errors, []);
    });
});

test('once the view turns, the inspected ray is a line from the eye to its hit', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1`);
        await waitFullFrame(page);
        await inspectMiddle(page);
        const before = await page.evaluate(() => window.arbor.panes[0].shown.req.camera.yaw);
        await page.focus('#frame-0');
        for (let i = 0; i < 8; i++) await page.keyboard.press('ArrowLeft');
        await page.waitForFunction((y) => window.arbor.panes[0].shown.req.camera.yaw !== y && !window.arbor.panes[0].shown.quick, before, { timeout: 60000 });
        await afterPaint(page);
        await screenshot(page, 'overlay-ray-turned');
        const line = await page.evaluate(async () => {
            const { projectSegment } = await import('/js/camera.js');
            const p = window.arbor.panes[0], cam = p.shown.cam, o = p.overlay, r = window.arbor.rayInspect.data;
            const s = projectSegment(cam, r.ray.origin, r.hit.point);
            const sx = o.width / cam.width, sy = o.height / cam.height;
            const d = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
            const white = (x, y) => {
                for (let j = -2; j <= 2; j++) {
                    for (let i = -2; i <= 2; i++) {
                        const k = ((Math.round(y) + j) * o.width + Math.round(x) + i) * 4;
                        if (d[k + 3] > 200 && d[k] > 220 && d[k + 1] > 220 && d[k + 2] > 220) return true;
                    }
                }
                return false;
            };
            // every 3 canvas pixels of the line on the canvas, away from the hit's ring (white too)
            const a = [s[0][0] * sx, s[0][1] * sy], b = [s[1][0] * sx, s[1][1] * sy];
            const length = Math.hypot(b[0] - a[0], b[1] - a[1]), samples = [];
            for (let t = 0; t <= length; t += 3) {
                const x = a[0] + ((b[0] - a[0]) * t) / length, y = a[1] + ((b[1] - a[1]) * t) / length;
                if (x >= 3 && y >= 3 && x < o.width - 3 && y < o.height - 3 && Math.hypot(x - b[0], y - b[1]) > 30) samples.push(white(x, y));
            }
            return { samples };
        });
        assert.ok(line.samples.length >= 20, `${line.samples.length} samples of the ray on the frame`);
        assert.ok(line.samples.every(Boolean), `the ray's line is missing at ${line.samples.map((w) => (w ? '+' : '-')).join('')}`);
        assert.deepEqual(errors, []);
    });
});

test("at two device pixels per CSS pixel the overlay has one pixel per device pixel and the hit's ring keeps its size", T, async () => {
    await withViewer({ browser: { dpr: 2 } }, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1`);
        await waitFullFrame(page);
        await inspectMiddle(page);
        const got = await page.evaluate(() => {
            const o = document.querySelector('canvas.overlay');
            const d = o.getContext('2d').getImageData(0, 0, o.width, o.height).data;
            let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
            for (let y = 0; y < o.height; y++) {
                for (let x = 0; x < o.width; x++) {
                    const k = (y * o.width + x) * 4;
                    if (d[k + 3] > 200 && d[k] > 230 && d[k + 1] > 230 && d[k + 2] > 230) {
                        x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y);
                    }
                }
            }
            return { size: [o.width, o.height], css: [o.clientWidth, o.clientHeight], ring: [(x1 - x0 + 1) / 2, (y1 - y0 + 1) / 2] };
        });
        await screenshot(page, 'overlay-dpr2');
        assert.deepEqual(got.size, got.css.map((v) => v * 2), 'the overlay is scaled to its place on the page');
        // the cross-hair reaches twice the ring's radius of 7 CSS pixels each way
        for (const extent of got.ring) assert.ok(extent >= 26 && extent <= 34, `the ring spans ${got.ring} CSS pixels`);
        assert.deepEqual(errors, []);
    });
});

test("a new resolution's strips are not drawn over with the boxes of the old frame's camera", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=0`);
        await boxesShown(page, 0);
        assert.ok(await overlayBox(page, 0, 640, 480), 'no boxes over the frame');
        // the 1280x720 frame's first strip comes, the others wait
        const held = [];
        await page.route('**/api/render', (route) => {
            const body = JSON.parse(route.request().postData() || '{}');
            if (body.width === 1280 && body.region && body.region.y > 0) held.push(route);
            else route.continue();
        });
        await page.selectOption('#res', '1280x720');
        await page.waitForFunction(() => document.querySelector('canvas.image').width === 1280);
        await afterPaint(page);
        await screenshot(page, 'overlay-new-resolution');
        assert.equal(await page.evaluate(() => window.arbor.panes[0].shown.req.width), 640, 'the old frame is no longer the one shown');
        assert.equal(await overlayBox(page, 0, 1280, 720), null, 'the boxes are drawn with the 640x480 frame\'s camera over the 1280x720 strips');
        await page.unroute('**/api/render');
        for (const r of held) await r.continue().catch(() => {});
        await page.waitForFunction(() => window.arbor.panes[0].shown?.req.width === 1280 && !window.arbor.panes[0].shown.quick);
        await afterPaint(page);
        assert.ok(await overlayBox(page, 0, 1280, 720), 'no boxes over the new frame');
        assert.deepEqual(errors, []);
    });
});

test('the key follows what is drawn: nothing without boxes or a ray, the depths shown in either pane, the ray until cleared', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1`);
        await waitFullFrame(page);
        await afterPaint(page);
        assert.equal(await page.isVisible('#overlay-key'), false, 'a key with nothing drawn');
        await page.check('#boxes-on');
        await page.fill('#depth', '2');
        await page.dispatchEvent('#depth', 'input');
        await boxesShown(page, 2);
        assert.deepEqual((await keyEntries(page, 'key-depths')).map((e) => e.depth), [2]);
        // split view, leaves up to depth 8: each pane's leaves at their own depths
        await page.check('#split-on');
        await page.check('#boxes-leaves');
        await page.fill('#depth', '8');
        await page.dispatchEvent('#depth', 'input');
        await page.waitForFunction(() => window.arbor.panes.length === 2 && window.arbor.panes.every((p) => p.shown && p.boxes?.data?.depth === 8));
        await afterPaint(page);
        const shown = await page.evaluate(() => [...new Set(window.arbor.panes.flatMap((p) => p.boxes.data.boxes.map((b) => b.depth)))].sort((a, b) => a - b));
        const each = await page.evaluate(() => window.arbor.panes.map((p) => new Set(p.boxes.data.boxes.map((b) => b.depth)).size));
        assert.ok(each.every((n) => n > 0) && shown.length > Math.min(...each), `the panes' leaf depths ${shown} (${each} each)`);
        assert.deepEqual((await keyEntries(page, 'key-depths')).map((e) => e.depth), shown);
        await inspectMiddle(page);
        assert.ok((await keyEntries(page, 'key-ray')).length > 0, 'no key to the ray');
        await page.keyboard.press('Escape');
        await afterPaint(page);
        assert.deepEqual(await keyEntries(page, 'key-ray'), []);
        await page.uncheck('#boxes-on');
        await afterPaint(page);
        assert.equal(await page.isVisible('#overlay-key'), false, 'the key stays without boxes or a ray');
        assert.deepEqual(errors, []);
    });
});

/**
 * Saves the frame (Save PNG) and compares the picture with the frame the
 * daemon sent: its size, how many pixels differ, and how many of those are
 * near each of `colours` ({colour: [r, g, b]}).
 */
async function savedOverlay(page, colours, name) {
    const { file } = await savePNG(page, name);
    return page.evaluate(async ({ b64, colours }) => {
        const decode = async (blob) => {
            const bmp = await createImageBitmap(blob);
            const c = new OffscreenCanvas(bmp.width, bmp.height);
            c.getContext('2d').drawImage(bmp, 0, 0);
            return c.getContext('2d').getImageData(0, 0, bmp.width, bmp.height);
        };
        const saved = await decode(new Blob([Uint8Array.from(atob(b64), (ch) => ch.charCodeAt(0))], { type: 'image/png' }));
        const frame = await decode(window.arbor.panes[0].lastFull.blob);
        const near = colours.map(() => 0);
        let differ = 0;
        for (let i = 0; i < frame.data.length; i += 4) {
            const s = saved.data.slice(i, i + 3), f = frame.data.slice(i, i + 3);
            if (Math.abs(s[0] - f[0]) + Math.abs(s[1] - f[1]) + Math.abs(s[2] - f[2]) <= 6) continue;
            differ++;
            const k = colours.findIndex((c) => c.colour.every((v, j) => Math.abs(v - s[j]) <= 40));
            if (k >= 0) near[k]++;
        }
        return { size: [saved.width, saved.height], differ, near };
    }, { b64: file.toString('base64'), colours });
}

test('Save PNG saves the boxes and the inspected ray drawn over the frame, in the colours of the key', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=3&boxes=all`);
        await boxesShown(page, 3);
        const depths = await keyEntries(page, 'key-depths');
        const boxes = await savedOverlay(page, depths, 'saved-boxes');
        assert.deepEqual(boxes.size, [640, 480]);
        assert.ok(boxes.differ > 2000, `${boxes.differ} pixels drawn over the saved frame`);
        depths.forEach((c, i) => assert.ok(boxes.near[i] > 20, `depth ${c.depth}'s colour rgb(${c.colour}) is not in the saved picture: ${JSON.stringify(boxes)}`));
        // with a ray inspected, its path is drawn over the (fainter) boxes
        await inspectMiddle(page);
        const parts = (await keyEntries(page, 'key-ray')).filter((c) => c.part === 'inner' || c.part === 'leaf');
        const ray = await savedOverlay(page, parts, 'saved-ray');
        parts.forEach((c, i) => assert.ok(ray.near[i] > 20, `the ray's ${c.part} colour rgb(${c.colour}) is not in the saved picture: ${JSON.stringify(ray)}`));
        // without boxes or a ray, the saved picture is the daemon's frame
        await page.keyboard.press('Escape');
        await page.uncheck('#boxes-on');
        await afterPaint(page);
        assert.equal((await savedOverlay(page, [], 'saved-plain')).differ, 0);
        assert.deepEqual(errors, []);
    });
});

test('Save PNG waits while the frame on screen is not the full frame it would save (a reset before the orbit\'s frames came)', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=sphere&accel=kd&builder=sah&spp=1&depth=3&boxes=all`);
        await boxesShown(page, 3);
        await page.waitForSelector('#save-png:not([disabled])');
        // orbit by drag until quick frames of the moved view are shown
        const box = await page.locator('#frame-0').boundingBox();
        const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
        await page.mouse.move(cx, cy);
        await page.mouse.down();
        for (let i = 1; i <= 10; i++) await page.mouse.move(cx + 12 * i, cy, { steps: 2 });
        await page.mouse.up();
        await page.waitForFunction(() => window.arbor.panes[0].shown.quick, null, { timeout: 30000 });
        // the reset view's frames are held back: the moved view's quick frame stays on screen
        const held = [];
        await page.route('**/api/render*', (route) => held.push(route));
        await page.click('#reset');
        await page.waitForFunction(() => !window.arbor.moving, null, { timeout: 30000 });
        await afterPaint(page);
        const st = await page.evaluate(() => ({ quick: window.arbor.panes[0].shown.quick, full: window.arbor.panes[0].lastFull.key }));
        assert.equal(st.quick, true, 'the moved view\'s quick frame is on screen');
        assert.equal(await page.$eval('#save-png', (b) => b.disabled), true,
            'Save PNG offers the reset view\'s full frame while another view is on screen');
        await page.unroute('**/api/render*');
        for (const r of held) await r.continue().catch(() => {});
        await page.waitForSelector('#save-png:not([disabled])', { timeout: 60000 });
        assert.deepEqual(errors, []);
    });
});
