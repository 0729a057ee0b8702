// viewer-state.test.mjs - the viewer keeps what it shows true to what was
// chosen: the compare heading during a run, an upload's error.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import { withViewer, waitFullFrame } from './lib.mjs';

const T = { timeout: 180000 };
// a request the test broke on purpose (route.abort, a 400 it provoked) is logged by the browser
const unprovoked = (errors) => errors.filter((e) => !/Failed to load resource/.test(e));

async function upload(page, name, text) {
    await page.setInputFiles('#file-input', { name, mimeType: 'text/plain', buffer: Buffer.from(text) });
}

const TRIANGLE = 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n';

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
