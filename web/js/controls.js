// controls.js - orbit, zoom and pan like three.js OrbitControls: left-drag
// (one finger) orbits, the wheel (two-finger pinch) zooms, right- or
// shift-drag (two-finger drag) pans, double-click resets; a click without a
// drag inspects the ray under it. Keyboard on a focused frame: arrows orbit,
// shift+arrows pan, + and - zoom.

import { boundsFrame, clampPitch, lookAt, viewEyeTarget, add, scale, WORLD_UP } from './camera.js';

const CLICK_SLOP = 4;        // px a press may move and still be a click
const CLICK_DELAY = 260;     // ms to wait for a double-click before inspecting
export const MIN_DISTANCE = 0.02, MAX_DISTANCE = 50;

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
            v.yaw -= (360 * dx) / h;
            v.pitch = clampPitch(v.pitch + (360 * dy) / h);
            v.yaw = ((v.yaw + 180) % 360 + 360) % 360 - 180;
        });
    }

    function pan(dx, dy) {
        const model = app.model();
        if (!model) return;
        const h = size().height || 1;
        app.updateView((v) => {
            const { eye, target } = viewEyeTarget(model.bounds, v);
            const basis = lookAt(eye, target, WORLD_UP, v.fov, 1, 1);
            const { diagonal } = boundsFrame(model.bounds);
            const perPixel = (2 * v.distance * diagonal * Math.tan((v.fov * Math.PI) / 360)) / h;
            const moved = add(scale(basis.right, -dx * perPixel), scale(basis.up, dy * perPixel));
            v.target = add(target, moved);
        });
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
            zoom(pinch.dist / now.dist);
            pan(now.mid.x - pinch.mid.x, now.mid.y - pinch.mid.y);
            pinch = now;
            return;
        }
        if (press && !press.moved && Math.hypot(e.clientX - press.x, e.clientY - press.y) <= CLICK_SLOP) return;
        if (press && !press.moved) {
            // first real move: apply the whole offset since the press
            press.moved = true;
            const tx = e.clientX - press.x, ty = e.clientY - press.y;
            if (mode === 'pan') pan(tx, ty); else orbit(tx, ty);
            return;
        }
        if (mode === 'pan') pan(dx, dy);
        else if (mode === 'orbit') orbit(dx, dy);
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
        zoom(Math.exp(dy * 0.0015));
    }, { passive: false });

    frameEl.addEventListener('keydown', (e) => {
        const step = e.altKey ? 1 : 5;
        const px = (size().height || 400) * (step / 360);
        let handled = true;
        switch (e.key) {
            case 'ArrowLeft': e.shiftKey ? pan(-px * 4, 0) : orbit(-px, 0); break;
            case 'ArrowRight': e.shiftKey ? pan(px * 4, 0) : orbit(px, 0); break;
            case 'ArrowUp': e.shiftKey ? pan(0, -px * 4) : orbit(0, -px); break;
            case 'ArrowDown': e.shiftKey ? pan(0, px * 4) : orbit(0, px); break;
            case '+': case '=': zoom(1 / 1.15); break;
            case '-': case '_': zoom(1.15); break;
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
