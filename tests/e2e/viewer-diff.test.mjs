// viewer-diff.test.mjs - split view's difference of the two trees' work:
// each pixel's colour is the second tree's node steps + triangle tests minus
// the first's, as POST /api/ray counts them for that pixel's ray in each
// tree; the means are the daemon's own heat_mean of each tree; the figure
// follows the view once it rests, the URL keeps it, and it goes with split
// view, and a refusal is quoted without asking again.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, screenshot, recordRequests, waitFullFrame, postJSON } from './lib.mjs';

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
