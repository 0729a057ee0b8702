// token.js - a daemon started with --token-file answers 401 to requests that
// change its state (uploads, benchmarks) without its bearer token. Then the
// user is asked for it here; api.js keeps it in sessionStorage and sends it
// with such requests, and forgets it when the daemon refuses it.

import { saveToken } from './api.js';

const $ = (id) => document.getElementById(id);
let asking = null;

/**
 * Asks for the token in a modal dialog; resolves true once one was entered,
 * false when the user cancels. what: the action that needs it ("Uploading
 * x.obj as "x""); refused: the daemon refused the token it was sent.
 */
export function askToken(what, refused) {
    if (asking) return asking;
    const dialog = $('token-dialog'), input = $('token-input');
    $('token-why').textContent = `${what} needs this daemon's bearer token.`;
    $('token-refused').hidden = !refused;
    input.value = '';
    dialog.returnValue = '';
    asking = new Promise((resolve) => {
        dialog.addEventListener('close', () => {
            asking = null;
            const token = input.value.trim();
            input.value = '';
            const ok = dialog.returnValue === 'ok' && token !== '';
            if (ok) saveToken(token);
            resolve(ok);
        }, { once: true });
    });
    dialog.showModal();
    return asking;
}

/** Runs request() (a state-changing request); while it is refused with 401, asks for the token and runs it again. */
export async function withToken(what, request) {
    for (;;) {
        try {
            return await request();
        } catch (e) {
            if (e.status !== 401 || !(await askToken(what, e.tokenSent))) throw e;
        }
    }
}

$('token-cancel').addEventListener('click', () => $('token-dialog').close(''));
