// controls.js - orbit, zoom and pan like three.js OrbitControls: left-drag
// (one finger) orbits, the wheel (two-finger pinch) zooms, right- or
// shift-drag (two-finger drag) pans, double-click resets; a click without a
// drag inspects the ray under it. Keyboard on a focused frame: arrows orbit,
// shift+arrows pan, + and - zoom. W A S D move the eye and target together
// (Q and E down and up), to go inside a model such as sponza; with the fly
// camera (state.fly) a drag, the arrows, the wheel and + - turn the view
// about its eye and move it forward instead of orbiting and zooming.

import {
    clampPitch, lookFromEye, moveView, shiftView, add, scale,
} from './camera.js';

const CLICK_SLOP = 4;        // px a press may move and still be a click
const CLICK_DELAY = 260;     // ms to wait for a double-click before inspecting
export const MIN_DISTANCE = 0.02, MAX_DISTANCE = 50;
// a key press moves this many of the bounds' diagonals (Shift four times as far, Alt a quarter)
const MOVE_STEP = 0.02;
// what the keys at W A S D Q E on a US layout move along, [forward, right, up]: by position (e.code), so
// that they keep their places on other layouts and with Alt (which turns e.key into other characters on a Mac)
const MOVES = {
    KeyW: [1, 0, 0], KeyS: [-1, 0, 0], KeyA: [0, -1, 0], KeyD: [0, 1, 0], KeyQ: [0, 0, -1], KeyE: [0, 0, 1],
};

const wrapYaw = (y) => ((y + 180) % 360 + 360) % 360 - 180;

export function attachControls(app, frameEl, pane) {
    const pointers = new Map(); // id -> {x, y}
    let mode = null;            // 'orbit' | 'pan' | 'pinch'
    let press = null;           // {x, y, moved, button}
    let pinch = null;           // {dist, mid}
    let clickTimer = 0;

    const size = () => frameEl.getBoundingClientRect();

    function orbit(dx, dy) {
        const h = size().height || 1;
        app.updateView((v) => {
            v.yaw = wrapYaw(v.yaw - (360 * dx) / h);
            v.pitch = clampPitch(v.pitch + (360 * dy) / h);
        });
    }

    /** Turns the view about its eye by (yaw, pitch) degrees: positive yaw turns left, positive pitch down. */
    function look(yaw, pitch) {
        const model = app.model();
        if (!model) return;
        app.updateView((v) => Object.assign(v, lookFromEye(model.bounds, v, wrapYaw(v.yaw + yaw), v.pitch + pitch)));
    }

    /**
     * A drag of (dx, dy) px: an orbit, or with the fly camera a look by fov /
     * height degrees a pixel, the scene following the pointer: a drag across
     * the frame's height turns by its field of view (near the centre the
     * scene lags the pointer by 5% at 45 degrees, perspective being steeper).
     */
    function turn(dx, dy) {
        if (!app.state.fly) return orbit(dx, dy);
        const perPixel = app.state.view.fov / (size().height || 1);
        look(dx * perPixel, -dy * perPixel);
    }

    function move(forward, right, up) {
        const model = app.model();
        if (!model) return;
        app.updateView((v) => Object.assign(v, moveView(model.bounds, v, forward, right, up)));
    }

    /**
     * The wheel, pinch and + -: closer by factor < 1. The fly camera moves
     * forward instead, by five key steps per e-fold, so that a wheel notch
     * (factor e^-0.15) goes three quarters of a step and + about as far.
     */
    function approach(factor) {
        if (app.state.fly) move(-Math.log(factor) * MOVE_STEP * 5, 0, 0);
        else zoom(factor);
    }

    function pan(dx, dy) {
        const model = app.model();
        if (!model) return;
        const h = size().height || 1;
        // the image's up, not the world's: the point under the pointer stays under it
        app.updateView((v) => Object.assign(v, shiftView(model.bounds, v, (basis, diagonal) => {
            const perPixel = (2 * v.distance * diagonal * Math.tan((v.fov * Math.PI) / 360)) / h;
            return add(scale(basis.right, -dx * perPixel), scale(basis.up, dy * perPixel));
        })));
    }

    function zoom(factor) {
        app.updateView((v) => {
            v.distance = Math.min(MAX_DISTANCE, Math.max(MIN_DISTANCE, v.distance * factor));
        });
    }

    frameEl.addEventListener('contextmenu', (e) => e.preventDefault());

    frameEl.addEventListener('pointerdown', (e) => {
        frameEl.focus({ preventScroll: true, focusVisible: false });
        frameEl.setPointerCapture(e.pointerId);
        pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
        if (pointers.size === 1) {
            press = { x: e.clientX, y: e.clientY, moved: false, button: e.button };
            mode = e.button === 2 || e.button === 1 || e.shiftKey || e.ctrlKey || e.metaKey ? 'pan' : 'orbit';
        } else if (pointers.size === 2) {
            mode = 'pinch';
            press = null;
            pinch = pinchState();
        }
        e.preventDefault();
    });

    function pinchState() {
        const [a, b] = [...pointers.values()];
        return { dist: Math.hypot(a.x - b.x, a.y - b.y) || 1, mid: { x: (a.x + b.x) / 2, y: (a.y + b.y) / 2 } };
    }

    frameEl.addEventListener('pointermove', (e) => {
        const p = pointers.get(e.pointerId);
        if (!p) return;
        const dx = e.clientX - p.x, dy = e.clientY - p.y;
        p.x = e.clientX;
        p.y = e.clientY;
        if (mode === 'pinch' && pointers.size >= 2) {
            const now = pinchState();
            approach(pinch.dist / now.dist);
            pan(now.mid.x - pinch.mid.x, now.mid.y - pinch.mid.y);
            pinch = now;
            return;
        }
        if (press && !press.moved && Math.hypot(e.clientX - press.x, e.clientY - press.y) <= CLICK_SLOP) return;
        if (press && !press.moved) {
            // first real move: apply the whole offset since the press
            press.moved = true;
            const tx = e.clientX - press.x, ty = e.clientY - press.y;
            if (mode === 'pan') pan(tx, ty); else turn(tx, ty);
            return;
        }
        if (mode === 'pan') pan(dx, dy);
        else if (mode === 'orbit') turn(dx, dy);
    });

    function end(e) {
        if (!pointers.has(e.pointerId)) return;
        pointers.delete(e.pointerId);
        if (e.type === 'pointerup' && press && !press.moved && mode !== 'pinch' && press.button === 0) {
            const { clientX, clientY } = e;
            clearTimeout(clickTimer);
            clickTimer = setTimeout(() => app.inspect(pane, clientX, clientY), CLICK_DELAY);
        }
        if (pointers.size === 1) {
            // pinch became a one-finger orbit
            const [q] = pointers.values();
            press = { x: q.x, y: q.y, moved: true, button: 0 };
            mode = 'orbit';
        } else if (pointers.size === 0) {
            press = null;
            mode = null;
        }
    }
    frameEl.addEventListener('pointerup', end);
    frameEl.addEventListener('pointercancel', end);

    frameEl.addEventListener('dblclick', (e) => {
        e.preventDefault();
        clearTimeout(clickTimer);
        app.resetView();
    });

    frameEl.addEventListener('wheel', (e) => {
        e.preventDefault();
        const unit = e.deltaMode === 1 ? 16 : e.deltaMode === 2 ? 400 : 1;
        const dy = Math.max(-200, Math.min(200, e.deltaY * unit));
        approach(Math.exp(dy * 0.0015));
    }, { passive: false });

    frameEl.addEventListener('keydown', (e) => {
        const step = e.altKey ? 1 : 5;
        const px = (size().height || 400) * (step / 360);
        // the fly camera's arrows turn the way they point: left looks left, up looks up
        const arrow = (x, y) => {
            if (e.shiftKey) pan(x * px * 4, y * px * 4);
            else if (app.state.fly) look(-x * step, y * step);
            else orbit(x * px, y * px);
        };
        const along = MOVES[e.code];
        if (along && !e.ctrlKey && !e.metaKey) {
            const k = MOVE_STEP * (e.shiftKey ? 4 : e.altKey ? 0.25 : 1);
            move(along[0] * k, along[1] * k, along[2] * k);
            e.preventDefault();
            return;
        }
        let handled = true;
        switch (e.key) {
            case 'ArrowLeft': arrow(-1, 0); break;
            case 'ArrowRight': arrow(1, 0); break;
            case 'ArrowUp': arrow(0, -1); break;
            case 'ArrowDown': arrow(0, 1); break;
            case '+': case '=': approach(1 / 1.15); break;
            case '-': case '_': approach(1.15); break;
            case 'Enter': case ' ': {
                const r = size();
                app.inspect(pane, r.left + r.width / 2, r.top + r.height / 2);
                break;
            }
            default: handled = false;
        }
        if (handled) e.preventDefault();
    });
}
