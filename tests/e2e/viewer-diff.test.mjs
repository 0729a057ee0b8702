// viewer-diff.test.mjs - split view's difference of the two trees' work:
// each pixel's colour is the second tree's node steps + triangle tests minus
// the first's, as POST /api/ray counts them for that pixel's ray in each
// tree; the means are the daemon's own heat_mean of each tree; the figure
// follows the view once it rests, the URL keeps it, and it goes with split
// view, and a refusal is quoted without asking again. Save PNG puts the
// figure under the two frames, only while it is of the frames saved.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, screenshot, recordRequests, waitFullFrame, postJSON, savePNG, pngSize } from './lib.mjs';

const T = { timeout: 240000 };
// ColorBrewer RdBu's ends and middle, as the page's key says: blue, the second tree does less; red, more
const LESS = [33, 102, 172], SAME = [247, 247, 247], MORE = [178, 24, 43];

/** The colour the key gives difference d on a scale of +-scale (the test's own reading of the key). */
function keyColour(d, scale) {
    const t = Math.max(-1, Math.min(1, d / scale)), end = t < 0 ? LESS : MORE;
    return SAME.map((s, i) => s + Math.abs(t) * (end[i] - s));
}

const figureDone = (page) => page.waitForFunction(() => {
    const el = document.getElementById('diff');
    return !el.hidden && !el.classList.contains('stale') && document.querySelector('#diff-stats tr[data-key="mean_a"]');
}, null, { timeout: 60000 });

const shownNumber = (page, key) => page.$eval(`#diff-stats tr[data-key="${key}"] td`, (td) => Number(td.textContent.replace(/[,×%]/g, '')));

test("each pixel of the difference is the second tree's ray count minus the first's; the means are the daemon's", T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=sphere&accel=bvh&builder=sah&split=kd:median&diff=1&spp=1&res=320x240&mode=normals`);
        await waitFullFrame(page, 0, 60000);
        await figureDone(page);
        await screenshot(page, 'diff');
        assert.equal(await page.isChecked('#diff-on'), true);
        const asked = rec.costs.slice(-2 * 8);
        const cam = asked[asked.length - 1].camera;
        for (const [accel, builder] of [['bvh', 'sah'], ['kd', 'median']]) {
            assert.ok(asked.some((r) => r.accel === accel && r.builder === builder && r.mode === 'heat'), `no costs of ${accel} ${builder}`);
        }
        const frame = { model: 'sphere', camera: cam, width: 320, height: 240 };
        // the means: the daemon's heat_mean of each tree's heat frame at 1 spp, the same pixels' costs
        const mean = async (accel, builder) => (await postJSON(d.base, '/api/render',
            { ...frame, accel, builder, mode: 'heat', spp: 1, format: 'json' })).json.heat_mean;
        const [meanA, meanB] = [await mean('bvh', 'sah'), await mean('kd', 'median')];
        assert.ok(Math.abs((await shownNumber(page, 'mean_a')) - meanA) <= 0.005, `mean of BVH sah: ${meanA}`);
        assert.ok(Math.abs((await shownNumber(page, 'mean_b')) - meanB) <= 0.005, `mean of k-d median: ${meanB}`);
        assert.ok(meanA !== meanB, 'both trees cost the same on average: this view tells nothing');
        const shares = await Promise.all(['less', 'same', 'more'].map((k) => shownNumber(page, k)));
        assert.ok(Math.abs(shares.reduce((a, b) => a + b) - 100) <= 0.2, `shares ${shares} do not add to 100%`);
        // each pixel's colour, from the two rays' own counts (a traversal with a visitor, not the frame's)
        const scale = Number(await page.getAttribute('#diff-canvas', 'data-scale'));
        assert.ok(scale >= 1, `scale ${scale}`);
        const bg = [0.1, 0.1, 0.12].map((c) => Math.round(c * 255)); // the dark scheme's background
        let working = 0, differing = 0;
        for (const [x, y] of [[160, 120], [150, 100], [175, 140], [130, 125], [190, 110], [160, 150], [5, 5], [300, 230], [120, 80], [200, 165]]) {
            const cost = async (accel, builder) => {
                const { json } = await postJSON(d.base, '/api/ray', { ...frame, accel, builder, x, y });
                return json.counts.nodes + json.counts.tris;
            };
            const a = await cost('bvh', 'sah'), b = await cost('kd', 'median');
            const want = a <= 1 && b <= 1 ? bg : keyColour(b - a, scale);
            const got = await page.$eval('#diff-canvas', (c, [x, y]) => [...c.getContext('2d').getImageData(x, y, 1, 1).data].slice(0, 3), [x, y]);
            assert.ok(got.every((v, i) => Math.abs(v - want[i]) <= 1), `pixel (${x}, ${y}): costs ${a} and ${b}, colour ${got}, the key's ${want.map(Math.round)}`);
            if (a > 1 || b > 1) working++;
            if (a !== b) differing++;
        }
        assert.ok(working >= 5 && differing >= 3, `${working} pixels on the model, ${differing} differing: the pixels tell nothing`);
        assert.match(await page.textContent('#diff-title'), /k-d median − BVH sah/);
        assert.match(await page.evaluate(() => location.search), /[?&]diff=1(&|$)/);
        assert.deepEqual(errors, []);
    });
});

test('the difference follows the view once it rests, and goes with its checkbox and with split view', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const rec = recordRequests(page);
        await page.goto(`${d.base}/?model=cornell&split=kd:sah&spp=1&res=320x240`);
        await waitFullFrame(page, 1, 60000);
        assert.equal(await page.isVisible('#diff'), false, 'the difference before it was asked for');
        assert.equal(rec.costs.length, 0);
        await page.check('#diff-on');
        await figureDone(page);
        const before = rec.costs[rec.costs.length - 1].camera;
        await page.focus('#frame-0');
        await page.keyboard.press('ArrowLeft');
        await page.waitForFunction((yaw) => {
            const el = document.getElementById('diff');
            return !el.classList.contains('stale') && window.arbor.state.view.yaw !== yaw;
        }, before.yaw, { timeout: 60000 });
        await figureDone(page);
        const after = rec.costs[rec.costs.length - 1].camera;
        assert.notEqual(after.yaw, before.yaw, 'the costs were not measured again for the new view');
        assert.equal(after.yaw, (await waitFullFrame(page, 0)).yaw, "the costs are not of the frame's view");
        await page.uncheck('#diff-on');
        await page.waitForFunction(() => document.getElementById('diff').hidden && !/diff=/.test(location.search));
        await page.check('#diff-on');
        await figureDone(page);
        await page.uncheck('#split-on');
        await page.waitForFunction(() => document.getElementById('diff').hidden && !/diff=/.test(location.search));
        assert.equal(await page.isDisabled('#diff-on'), true);
        assert.deepEqual(errors, []);
    });
});

test('a daemon that refuses the costs is quoted under the figure, and not asked again for the same view', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        let asked = 0;
        // as a daemon from before format=costs answers
        await page.route('**/api/render', (route) => {
            if (JSON.parse(route.request().postData() || '{}').format !== 'costs') return route.continue();
            asked++;
            return route.fulfill({ status: 400, json: { error: { code: 'bad_request', message: "unknown format 'costs' (png, json)" } } });
        });
        await page.goto(`${d.base}/?model=cornell&split=kd:sah&diff=1&spp=1&res=320x240`);
        await page.waitForSelector('#diff-status.error:not([hidden])', { timeout: 60000 });
        assert.match(await page.textContent('#diff-status'), /request was not valid: unknown format 'costs' \(png, json\) \(400 bad_request\)/);
        const once = asked;
        await waitFullFrame(page, 1, 60000);
        await page.waitForTimeout(1000);
        assert.equal(asked, once, 'the refused costs were asked for again for the same view');
        // the browser logs the refused request itself; nothing else went wrong
        assert.deepEqual(errors.filter((e) => !/Failed to load resource/.test(e)), []);
    });
});

test('Save PNG beside small frames: the difference\'s key in a wider column, and no line squeezed (a smaller font instead)', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&accel=bvh&builder=median&split=kd:sah&diff=1&spp=1&res=320x240`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        await figureDone(page);
        const { file, drawn } = await saveAndRead(page, 'saved-diff-small');
        const [w, h] = pngSize(file);
        // the second frame's column, at 320 + 8, holds the key at its least width
        assert.equal(w, 328 + 440, `saved ${w}×${h}: not the key's least width beside the 320-pixel frames`);
        const squeezed = drawn.filter((t) => t.maxWidth !== undefined && t.width > t.maxWidth + 0.5);
        assert.deepEqual(squeezed, [], 'lines squeezed into less than their width');
        assert.ok(drawn.some((t) => /99th percentile/.test(t.text)), 'no key drawn');
        assert.deepEqual(errors, []);
    });
});

/**
 * Save PNG, with the lines of text its canvas is given recorded: each line's
 * text, the width it was allowed (fillText's maxWidth) and the width it took.
 */
async function saveAndRead(page, name) {
    await page.evaluate(() => {
        const fillText = CanvasRenderingContext2D.prototype.fillText;
        window.savedText = [];
        CanvasRenderingContext2D.prototype.fillText = function (text, x, y, maxWidth) {
            window.savedText.push({ text: String(text), maxWidth, width: this.measureText(text).width });
            return fillText.call(this, text, x, y, maxWidth);
        };
    });
    const { file } = await savePNG(page, name);
    return { file, drawn: await page.evaluate(() => window.savedText) };
}

/**
 * The saved PNG `file` against the PNG saved without the figure (`plain`)
 * and the page's figure canvas: pixels of plain's area that differ, pixels
 * of the figure's image (at the band's bottom left) that differ from the
 * canvas's and how many of those are blue or red (what the comparison is
 * worth), and the pixels of the band beside the image at the key's ends.
 */
function compareSaved(page, file, plain) {
    return page.evaluate(async ({ file, plain, LESS, MORE }) => {
        const decode = async (b64) => {
            const bmp = await createImageBitmap(new Blob([Uint8Array.from(atob(b64), (ch) => ch.charCodeAt(0))], { type: 'image/png' }));
            const c = new OffscreenCanvas(bmp.width, bmp.height);
            c.getContext('2d').drawImage(bmp, 0, 0);
            return c.getContext('2d').getImageData(0, 0, bmp.width, bmp.height);
        };
        const [saved, old] = [await decode(file), await decode(plain)];
        const px = (img, x, y) => img.data.slice((y * img.width + x) * 4, (y * img.width + x) * 4 + 3);
        const same = (a, b, tol = 0) => [0, 1, 2].every((i) => Math.abs(a[i] - b[i]) <= tol);
        let oldDiffer = 0;
        for (let y = 0; y < old.height; y++) for (let x = 0; x < old.width; x++) if (!same(px(saved, x, y), px(old, x, y))) oldDiffer++;
        const c = document.getElementById('diff-canvas');
        const fig = c.getContext('2d').getImageData(0, 0, c.width, c.height);
        const y0 = saved.height - fig.height;
        let figDiffer = 0, blue = 0, red = 0, compared = 0;
        for (let y = 0; y < fig.height; y += 3) {
            for (let x = 0; x < fig.width; x += 3) {
                const want = px(fig, x, y);
                compared++;
                if (!same(px(saved, x, y0 + y), want)) figDiffer++;
                if (want[2] > want[0] + 40) blue++;
                if (want[0] > want[2] + 40) red++;
            }
        }
        let keyLess = 0, keyMore = 0;
        for (let y = old.height; y < saved.height; y++) {
            for (let x = fig.width; x < saved.width; x++) {
                if (same(px(saved, x, y), LESS, 3)) keyLess++;
                if (same(px(saved, x, y), MORE, 3)) keyMore++;
            }
        }
        return { figure: [fig.width, fig.height], y0, oldDiffer, figDiffer, compared, blue, red, keyLess, keyMore };
    }, { file: file.toString('base64'), plain: plain.toString('base64'), LESS, MORE });
}

test('Save PNG puts the difference under the frames (its image pixel for pixel, title, key and figures) only while it is of the frames saved', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await page.goto(`${d.base}/?model=cornell&accel=bvh&builder=median&split=kd:sah&diff=1&spp=1`);
        await waitFullFrame(page, 0, 60000);
        await waitFullFrame(page, 1, 60000);
        await figureDone(page);
        const saved = await saveAndRead(page, 'saved-diff');
        const withFigure = saved.file, drawn = saved.drawn.map((t) => t.text);
        const shown = await page.evaluate(() => ({
            title: document.getElementById('diff-title').textContent,
            ticks: [...document.querySelectorAll('#diff-ticks span')].map((s) => s.textContent),
            note: document.getElementById('diff-note').textContent,
            rows: [...document.querySelectorAll('#diff-stats tr')].map((tr) => [tr.querySelector('th').textContent, tr.querySelector('td').textContent]),
        }));
        // the figure off: the two frames under their titles, as Save PNG saved them before the figure
        await page.uncheck('#diff-on');
        await page.waitForFunction(() => document.getElementById('diff').hidden);
        const plain = (await savePNG(page, 'saved-diff-off')).file;
        assert.deepEqual(pngSize(plain), [2 * 640 + 8, 28 + 480], 'the PNG without the figure is not the two frames under their titles');
        const [w, h] = pngSize(withFigure);
        assert.equal(w, pngSize(plain)[0]);
        assert.ok(h >= pngSize(plain)[1] + 480 + 20 && h <= pngSize(plain)[1] + 480 + 60,
            `saved ${w}×${h}: not the frames and a band of the figure's 480 rows under its title`);
        const cmp = await compareSaved(page, withFigure, plain);
        assert.deepEqual(cmp.figure, [640, 480], 'the figure is not one pixel per frame pixel');
        assert.equal(cmp.oldDiffer, 0, 'the frames and their titles are not as saved without the figure');
        assert.ok(cmp.blue > 100 && cmp.red > 100, `the figure is too plain to tell anything: ${JSON.stringify(cmp)}`);
        assert.equal(cmp.figDiffer, 0, `the saved figure is not the page's: ${JSON.stringify(cmp)}`);
        assert.ok(cmp.keyLess > 20 && cmp.keyMore > 20, `no colour key beside the figure: ${JSON.stringify(cmp)}`);
        // the page's own title, ends and figures, word for word
        assert.match(shown.title, /k-d sah − BVH median/);
        for (const t of [shown.title, ...shown.ticks, ...shown.rows.flat()]) assert.ok(drawn.includes(t), `"${t}" is not in the saved PNG`);
        // the key's note, the 99th percentile its ends stand for included, in lines of the note's words in order
        const note = drawn.slice(drawn.indexOf(shown.ticks[2]) + 1, drawn.indexOf(shown.rows[0][0]));
        assert.equal(note.join(' '), shown.note, 'the saved key does not say what the page says of it');
        assert.match(shown.note, /\(the 99th percentile\)/);
        // a figure of the view before an orbit (the new view's costs refused) is not saved under the new view's frames
        await page.check('#diff-on');
        await figureDone(page);
        await page.route('**/api/render', (route) => {
            if (JSON.parse(route.request().postData() || '{}').format !== 'costs') return route.continue();
            return route.fulfill({ status: 503, json: { error: { code: 'busy', message: 'held back by the test' } } });
        });
        const orbit = async (key) => {
            const before = await page.evaluate(() => JSON.stringify(window.arbor.panes[0].lastFull.req.camera));
            await page.focus('#frame-0');
            await page.keyboard.press(key);
            await page.waitForFunction((cam) => window.arbor.framesComplete() &&
                window.arbor.panes.every((p) => JSON.stringify(p.lastFull.req.camera) !== cam), before, { timeout: 60000 });
        };
        await orbit('ArrowLeft');
        await page.waitForSelector('#diff-status.error:not([hidden])', { timeout: 60000 });
        assert.equal(await page.$eval('#diff', (el) => el.classList.contains('stale')), true, 'the figure is not marked stale');
        assert.deepEqual(pngSize((await savePNG(page, 'saved-diff-stale')).file), pngSize(plain), 'a stale figure was saved');
        // the next view's figure is measured, and saved: a view not seen before, whose figure is new
        await page.unroute('**/api/render');
        await orbit('ArrowUp');
        await figureDone(page);
        assert.deepEqual(pngSize((await savePNG(page, 'saved-diff-orbited')).file), [w, h], "the new view's figure is not saved");
        assert.deepEqual(errors.filter((e) => !/Failed to load resource/.test(e)), []);
    });
});
