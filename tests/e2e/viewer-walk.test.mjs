// viewer-walk.test.mjs - moving the eye through a model: W A S D Q E carry
// the eye and its target together by a fiftieth of the bounds' diagonal (Shift
// four times, Alt a quarter), a right-drag pans, and the fly camera turns the
// view about its eye.
// Each camera the daemon rendered is checked against positions worked out here
// from the model's bounds and the orbit convention (camera.c), not by the
// page's own camera code.

import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { withViewer, screenshot, waitFullFrame, waitFrameMovedFrom, repo, afterPaint } from './lib.mjs';

const T = { timeout: 180000 };
const STEP = 0.02; // diagonals a key press moves
const TOL = 1e-4;  // requests round eye and target to 1e-6

const add = (a, b) => a.map((x, i) => x + b[i]);
const sub = (a, b) => a.map((x, i) => x - b[i]);
const mul = (a, s) => a.map((x) => x * s);
const dot = (a, b) => a.reduce((s, x, i) => s + x * b[i], 0);
const len = (a) => Math.sqrt(dot(a, a));
const norm = (a) => mul(a, 1 / len(a));
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const rad = (deg) => (deg * Math.PI) / 180;
const diagOf = (bounds) => len(sub(bounds.max, bounds.min));
/** The orbit convention's unit vector from the target to the eye. */
const orbitDir = (yaw, pitch) => [Math.cos(rad(pitch)) * Math.sin(rad(yaw)), Math.sin(rad(pitch)), Math.cos(rad(pitch)) * Math.cos(rad(yaw))];

/** Eye and target of a request camera: look-at as it is, orbit about the bounds' centre (arbor_camera_orbit). */
function eyeTarget(cam, bounds) {
    if (cam.eye) return { eye: cam.eye, target: cam.target };
    const centre = mul(add(bounds.min, bounds.max), 0.5);
    return { eye: add(centre, mul(orbitDir(cam.yaw, cam.pitch), cam.distance * diagOf(bounds))), target: centre };
}

/** Yaw and pitch (degrees) of the orbit convention whose eye looks from eye to target. */
function yawPitch(eye, target) {
    const d = norm(sub(eye, target));
    return { yaw: Math.atan2(d[0], d[2]) * 180 / Math.PI, pitch: Math.asin(d[1]) * 180 / Math.PI };
}

const near = (a, b, tol = TOL) => a.every((x, i) => Math.abs(x - b[i]) <= tol);

/** The triangles of an OBJ file (faces fanned), as [[a, b, c], ...] of points. */
function objTriangles(file) {
    const v = [], tris = [];
    for (const line of fs.readFileSync(file, 'utf8').split('\n')) {
        const w = line.trim().split(/\s+/);
        if (w[0] === 'v') v.push(w.slice(1, 4).map(Number));
        if (w[0] === 'f') {
            const idx = w.slice(1).map((f) => Number(f.split('/')[0]) - 1);
            for (let i = 2; i < idx.length; i++) tris.push([v[idx[0]], v[idx[i - 1]], v[idx[i]]]);
        }
    }
    return tris;
}

/** The nearest t > 0 at which o + t d meets a triangle (Moller-Trumbore in double, every triangle), or null. */
function bruteNearest(tris, o, d) {
    let best = null;
    for (const [a, b, c] of tris) {
        const e1 = sub(b, a), e2 = sub(c, a), p = cross(d, e2), det = dot(e1, p);
        if (Math.abs(det) < 1e-12) continue;
        const s = sub(o, a), u = dot(s, p) / det, q = cross(s, e1), v = dot(d, q) / det, t = dot(e2, q) / det;
        if (u >= 0 && v >= 0 && u + v <= 1 && t > 0 && (best === null || t < best)) best = t;
    }
    return best;
}

/** Waits until pane 0 shows a full frame rendered from eye and target (within TOL); returns that camera. */
async function waitCamera(page, want) {
    try {
        await page.waitForFunction((w) => {
            const c = document.querySelector('canvas.image[data-pane="0"]');
            if (!c || c.dataset.frame !== 'full' || window.arbor.moving) return false;
            const cam = JSON.parse(c.dataset.camera);
            const close = (a, b) => a && a.every((x, i) => Math.abs(x - b[i]) <= w.tol);
            return close(cam.eye, w.eye) && close(cam.target, w.target);
        }, { ...want, tol: TOL }, { timeout: 30000 });
    } catch (e) {
        const shown = await page.$eval('canvas.image[data-pane="0"]', (c) => c.dataset.camera).catch(() => '?');
        throw new Error(`no full frame from ${JSON.stringify(want)}; pane 0 shows ${shown}`);
    }
    return waitFullFrame(page);
}

/** Opens cornell at query; its first full frame's camera, the model's bounds and their diagonal. */
async function openCornell(d, page, query) {
    await page.goto(`${d.base}/?model=cornell&spp=1${query}`);
    const cam0 = await waitFullFrame(page);
    const { models } = await fetch(`${d.base}/api/models`).then((r) => r.json());
    const bounds = models.find((m) => m.name === 'cornell').bounds;
    return { cam0, bounds, diag: diagOf(bounds) };
}

test('W A S D Q E move the eye and its target together, along the view, its right and the world up', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const { cam0, bounds, diag } = await openCornell(d, page, '');
        const { eye, target } = eyeTarget(cam0, bounds);
        const forward = norm(sub(target, eye)), right = norm(cross(forward, [0, 1, 0]));

        await page.locator('.frame').first().focus();
        for (const key of ['KeyW', 'KeyW', 'KeyW', 'KeyD', 'Shift+KeyE', 'Alt+KeyA', 'KeyS', 'KeyQ']) await page.keyboard.press(key);
        // forward 3 - 1 steps, right 1 - 1/4, up 4 - 1
        const by = add(add(mul(forward, 2 * STEP), mul(right, 0.75 * STEP)), mul([0, 1, 0], 3 * STEP));
        const want = { eye: add(eye, mul(by, diag)), target: add(target, mul(by, diag)) };
        const cam = await waitCamera(page, want);
        assert.deepEqual(cam.up, [0, 1, 0]);
        assert.equal(cam.fov, cam0.fov);
        // the orbit camera still orbits, now about the moved target
        assert.match(page.url(), /[?&]target=/);
        assert.doesNotMatch(page.url(), /[?&]cam=/);
        assert.deepEqual(errors, []);
    });
});

test('a right-drag pans: the point the view turned about stays under the pointer, eye and target moved together', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const { cam0, bounds } = await openCornell(d, page, '');
        const start = eyeTarget(cam0, bounds);
        const box = await page.locator('.frame').first().boundingBox();
        const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
        await page.mouse.move(cx, cy);
        await page.mouse.down({ button: 'right' });
        for (let i = 1; i <= 6; i++) await page.mouse.move(cx + 10 * i, cy + 5 * i);
        await page.mouse.up({ button: 'right' });
        const cam = await waitFrameMovedFrom(page, cam0);
        const { eye, target } = eyeTarget(cam, bounds);
        // the old target, projected through the new camera (vertical fov over the frame's height), lies where the pointer let go
        const f = norm(sub(target, eye)), r = norm(cross(f, [0, 1, 0])), u = cross(r, f);
        const rel = sub(start.target, eye), depth = dot(rel, f);
        const pxPerUnit = box.height / 2 / Math.tan(rad(cam.fov) / 2);
        const x = box.width / 2 + (dot(rel, r) / depth) * pxPerUnit, y = box.height / 2 - (dot(rel, u) / depth) * pxPerUnit;
        assert.ok(Math.abs(x - (box.width / 2 + 60)) < 0.05 && Math.abs(y - (box.height / 2 + 30)) < 0.05,
            `the old target is at (${x}, ${y}) in the frame, not (${box.width / 2 + 60}, ${box.height / 2 + 30})`);
        // the view only moved: the eye kept its offset from the target
        assert.ok(near(sub(eye, target), sub(start.eye, start.target)), `eye - target ${sub(eye, target)}, was ${sub(start.eye, start.target)}`);
        assert.match(page.url(), /[?&]target=/);
        assert.deepEqual(errors, []);
    });
});

test('the fly camera turns about the eye: a drag, the arrows; the wheel moves forward; the URL keeps it', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const { cam0, bounds, diag } = await openCornell(d, page, '');
        const { eye } = eyeTarget(cam0, bounds);
        const reach = cam0.distance * diag;

        await page.check('#cam-fly');
        await page.waitForFunction(() => /[?&]cam=fly/.test(location.search), null, { timeout: 5000 });
        assert.equal(await page.textContent('#hint-drag'), 'Drag to look around');

        // a drag of (60, 30) px turns by 60 and 30 times fov / frame height degrees, the scene following the pointer
        const box = await page.locator('.frame').first().boundingBox();
        const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
        await page.mouse.move(cx, cy);
        await page.mouse.down();
        for (let i = 1; i <= 6; i++) await page.mouse.move(cx + 10 * i, cy + 5 * i);
        await page.mouse.up();
        const perPixel = cam0.fov / box.height;
        let yaw = cam0.yaw + 60 * perPixel, pitch = cam0.pitch - 30 * perPixel;
        const lookAt = (y, p) => ({ eye, target: sub(eye, mul(orbitDir(y, p), reach)) });
        let cam = await waitCamera(page, lookAt(yaw, pitch));
        const turned = yawPitch(cam.eye, cam.target);
        assert.ok(Math.abs(turned.yaw - yaw) < 1e-3 && Math.abs(turned.pitch - pitch) < 1e-3, JSON.stringify({ turned, yaw, pitch }));
        // the scene followed the pointer: what was at the centre is now right of it and below
        const sight = norm(sub(cam.target, cam.eye)), r = norm(cross(sight, [0, 1, 0])), u = cross(r, sight);
        const was = sub(eyeTarget(cam0, bounds).target, cam.eye);
        assert.ok(dot(was, r) > 0 && dot(was, u) < 0, `the old centre lies at right ${dot(was, r)}, up ${dot(was, u)}`);

        // the arrows look the way they point: left, then up, 5 degrees each
        await page.keyboard.press('ArrowLeft');
        await page.keyboard.press('ArrowUp');
        yaw += 5;
        pitch -= 5;
        cam = await waitCamera(page, lookAt(yaw, pitch));

        // a wheel notch towards the scene moves eye and target forward, the distance between them kept
        const f = norm(sub(cam.target, cam.eye));
        await page.mouse.move(cx, cy);
        await page.mouse.wheel(0, -100);
        const ahead = 0.1 * 0.15 * diag; // approach(exp(-0.15)): -ln(factor) * 5 steps
        cam = await waitCamera(page, { eye: add(cam.eye, mul(f, ahead)), target: add(cam.target, mul(f, ahead)) });
        assert.ok(Math.abs(len(sub(cam.target, cam.eye)) - reach) < TOL);
        await screenshot(page, 'fly-turned');

        // a reload keeps the fly camera and the view
        await page.goto(page.url());
        await page.waitForFunction(() => document.getElementById('cam-fly').checked, null, { timeout: 10000 });
        await waitCamera(page, { eye: cam.eye, target: cam.target });
        assert.equal(await page.textContent('#hint-drag'), 'Drag to look around');
        assert.deepEqual(errors, []);
    });
});

test('back from Fly to Orbit, the view orbits the surface at its centre: the eye and the picture stay', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const { cam0, bounds, diag } = await openCornell(d, page, '&cam=fly');
        const start = eyeTarget(cam0, bounds);
        const forward = norm(sub(start.target, start.eye)), right = norm(cross(forward, [0, 1, 0]));
        // into the box's open side and a little to the left, so that the frame's centre shows the tall block
        await page.locator('.frame').first().focus();
        for (const key of ['Shift+KeyW', 'Shift+KeyW', 'KeyA', 'KeyA', 'KeyA']) await page.keyboard.press(key);
        const by = mul(add(mul(forward, 2 * 4 * STEP), mul(right, -3 * STEP)), diag);
        const { eye, target } = await waitCamera(page, { eye: add(start.eye, by), target: add(start.target, by) });
        const t = bruteNearest(objTriangles(path.join(repo, 'models', 'cornell.obj')), eye, forward);
        assert.ok(t !== null && t < len(sub(target, eye)), `the line of sight meets the model at ${t}, before the fly target`);

        await page.check('#cam-orbit');
        const cam = await waitCamera(page, { eye, target: add(eye, mul(forward, t)) });
        assert.doesNotMatch(page.url(), /[?&]cam=/);
        const dist = Number(new URL(page.url()).searchParams.get('dist'));
        assert.ok(Math.abs(dist - t / diag) <= 2e-4, `the URL's distance ${dist}, not ${t / diag}`);
        // orbiting now turns about that point: a drag keeps the eye at t from it
        const box = await page.locator('.frame').first().boundingBox();
        await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
        await page.mouse.down();
        for (let i = 1; i <= 5; i++) await page.mouse.move(box.x + box.width / 2 + 8 * i, box.y + box.height / 2);
        await page.mouse.up();
        const orbited = await waitFrameMovedFrom(page, cam);
        assert.ok(near(orbited.target, cam.target), `the orbit moved its target: ${orbited.target} vs ${cam.target}`);
        const r = len(sub(orbited.eye, orbited.target));
        assert.ok(Math.abs(r - t) < 1e-3, `the eye is ${r} from the pivot, not ${t}`);
        assert.ok(!near(orbited.eye, eye), 'the drag did not orbit');
        assert.deepEqual(errors, []);
    });
});

test('another model, chosen or standing in for a URL\'s missing one, is framed from the same direction; a distance inside it becomes the protocol\'s', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        const { models } = await fetch(`${d.base}/api/models`).then((r) => r.json());
        const bounds = models.find((m) => m.name === 'sphere').bounds;
        const centre = mul(add(bounds.min, bounds.max), 0.5);
        // a fly camera a tenth of a diagonal from a target off cornell's centre, as a pivot leaves it; zoomed out, 2
        for (const [query, distance] of [['&cam=fly&dist=0.1&target=0.2,0.3,0.1', 1.307], ['&dist=2', 2]]) {
            await openCornell(d, page, `&yaw=30&pitch=10${query}`);
            await page.selectOption('#model', 'sphere');
            await page.waitForFunction(() => {
                const s = window.arbor.panes[0].shown;
                return s && !s.quick && s.req.model === 'sphere' && !window.arbor.moving;
            }, null, { timeout: 30000 });
            const shown = eyeTarget(await waitFullFrame(page), bounds);
            const want = { eye: add(centre, mul(orbitDir(30, 10), distance * diagOf(bounds))), target: centre };
            assert.ok(near(shown.eye, want.eye) && near(shown.target, want.target),
                `sphere shown from ${JSON.stringify(shown)}, not ${JSON.stringify(want)}`);
            // the URL keeps the view a moment after it settles
            await page.waitForFunction((dist) => new URL(location.href).searchParams.get('dist') === String(dist), distance);
        }
        // a URL naming a model the daemon lacks: another is shown, not from the missing model's target and distance
        await page.goto(`${d.base}/?model=nosuch&spp=1&yaw=30&pitch=10&dist=0.1&target=50,50,50`);
        const cornell = models.find((m) => m.name === 'cornell').bounds;
        const shown = eyeTarget(await waitFullFrame(page), cornell);
        const middle = mul(add(cornell.min, cornell.max), 0.5);
        const want = { eye: add(middle, mul(orbitDir(30, 10), 1.307 * diagOf(cornell))), target: middle };
        assert.ok(near(shown.eye, want.eye) && near(shown.target, want.target),
            `cornell shown from ${JSON.stringify(shown)}, not ${JSON.stringify(want)}`);
        assert.deepEqual(errors, []);
    });
});

test('back from Fly to Orbit with nothing at the frame\'s centre: the view stays as it was', T, async () => {
    await withViewer({}, async (d, { page, errors }) => {
        await openCornell(d, page, '&cam=fly&target=0.1,0.2,0.3&dist=0.4');
        const before = await page.evaluate(() => JSON.stringify(window.arbor.state.view));
        // the daemon's answer for the line of sight, made a miss
        await page.route('**/api/ray', async (route) => {
            const res = await route.fetch();
            route.fulfill({ response: res, json: { ...(await res.json()), hit: null } });
        });
        const answered = page.waitForResponse('**/api/ray');
        await page.check('#cam-orbit');
        await answered;
        await afterPaint(page);
        assert.equal(await page.evaluate(() => JSON.stringify(window.arbor.state.view)), before);
        assert.equal(await page.evaluate(() => window.arbor.state.fly), false);
        assert.deepEqual(errors, []);
    });
});
