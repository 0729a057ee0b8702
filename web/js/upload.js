// upload.js - drag-and-drop or the file picker: one .obj/.ply/.gz is PUT as
// the body of /api/models/{name}; an .obj with its .mtl files goes as
// multipart/form-data POST. XMLHttpRequest for its upload progress. Every
// error the daemon answers is shown in words, under the upload button over
// the page; a 401 asks for the daemon's token and sends the files again.

import { ApiError, errorFromText, savedToken, tokenRefused } from './api.js';
import { askToken } from './token.js';
import { triangles } from './panels.js';

const $ = (id) => document.getElementById(id);
const MODEL_RE = /\.(obj|ply)(\.gz)?$|\.gz$/i;

/** The model name for a file: its name without .gz and the extension, in [A-Za-z0-9._-]{1,64}. */
export function modelName(filename) {
    let n = filename.replace(/\.gz$/i, '').replace(/\.(obj|ply)$/i, '');
    n = n.replace(/[^A-Za-z0-9._-]+/g, '_').replace(/^[._]+/, '').slice(0, 64);
    return n || 'model';
}

export class Uploader {
    constructor(app) {
        this.app = app;
        this.hideTimer = 0;
        $('upload-button').addEventListener('click', () => $('file-input').click());
        $('file-input').addEventListener('change', (e) => {
            const files = [...e.target.files];
            e.target.value = '';
            if (files.length) this.upload(files);
        });
        let depth = 0;
        const hasFiles = (e) => e.dataTransfer && [...e.dataTransfer.types].includes('Files');
        window.addEventListener('dragenter', (e) => {
            if (!hasFiles(e)) return;
            e.preventDefault();
            depth++;
            $('drop').hidden = false;
        });
        window.addEventListener('dragover', (e) => {
            if (!hasFiles(e)) return;
            e.preventDefault();
            e.dataTransfer.dropEffect = 'copy';
        });
        window.addEventListener('dragleave', (e) => {
            if (!hasFiles(e)) return;
            depth = Math.max(0, depth - 1);
            if (depth === 0) $('drop').hidden = true;
        });
        window.addEventListener('drop', (e) => {
            if (!hasFiles(e)) return;
            e.preventDefault();
            depth = 0;
            $('drop').hidden = true;
            const files = [...e.dataTransfer.files];
            if (files.length) this.upload(files);
        });
    }

    status(text, { progress = null, error = false, actions = [] } = {}) {
        // a later upload's news is not hidden with an earlier success
        clearTimeout(this.hideTimer);
        const box = $('upload-status');
        box.hidden = false;
        box.classList.toggle('error', error);
        box.setAttribute('role', error ? 'alert' : 'status');
        $('upload-text').textContent = text;
        const bar = $('upload-progress');
        bar.hidden = progress === null;
        if (progress !== null) bar.value = progress;
        const act = $('upload-actions');
        act.innerHTML = '';
        for (const [label, fn] of actions) {
            const b = document.createElement('button');
            b.type = 'button';
            b.textContent = label;
            b.addEventListener('click', fn);
            act.append(b);
        }
    }

    hide() {
        $('upload-status').hidden = true;
    }

    upload(files, replace = false) {
        const main = files.filter((f) => MODEL_RE.test(f.name));
        const mtls = files.filter((f) => /\.mtl$/i.test(f.name));
        const other = files.filter((f) => !MODEL_RE.test(f.name) && !/\.mtl$/i.test(f.name));
        const close = ['Dismiss', () => this.hide()];
        if (main.length !== 1) {
            this.status(main.length === 0
                ? `Nothing to upload: choose one .obj (with its .mtl files), .ply or .gz model${other.length ? `, not ${other.map((f) => f.name).join(', ')}` : ''}.`
                : `Upload one model at a time: ${main.map((f) => f.name).join(', ')} are ${main.length} models.`,
            { error: true, actions: [close] });
            return;
        }
        const file = main[0];
        const name = modelName(file.name);
        const url = `/api/models/${encodeURIComponent(name)}${replace ? '?replace=1' : ''}`;
        const xhr = new XMLHttpRequest();
        let body;
        if (mtls.length && /\.obj$/i.test(file.name)) {
            body = new FormData();
            body.append('model', file, file.name);
            for (const m of mtls) body.append('mtl', m, m.name);
            xhr.open('POST', url);
        } else {
            body = file;
            xhr.open('PUT', url);
            xhr.setRequestHeader('Content-Type', 'application/octet-stream');
        }
        const sent = savedToken();
        if (sent) xhr.setRequestHeader('Authorization', `Bearer ${sent}`);
        const what = `Uploading ${file.name}${mtls.length ? ` with ${mtls.map((m) => m.name).join(', ')}` : ''} as "${name}"`;
        const total = file.size + mtls.reduce((a, m) => a + m.size, 0);
        this.status(`${what}: 0 of ${kib(total)}…`, { progress: 0, actions: [['Cancel', () => xhr.abort()]] });
        xhr.upload.onprogress = (e) => {
            const t = e.lengthComputable ? e.total : total;
            this.status(`${what}: ${kib(e.loaded)} of ${kib(t)}…`, { progress: t ? e.loaded / t : 0, actions: [['Cancel', () => xhr.abort()]] });
        };
        xhr.upload.onload = () => {
            this.status(`${what}: sent; the daemon is reading the model…`, { progress: 1 });
        };
        xhr.onload = () => {
            if (xhr.status === 200 || xhr.status === 201) {
                let m;
                try {
                    m = JSON.parse(xhr.responseText);
                } catch (e) {
                    this.status(`${what} failed: the daemon's answer was not JSON (${e.message}).`, { error: true, actions: [close] });
                    return;
                }
                const warn = (m.warnings || []).length ? ` Warnings: ${m.warnings.join('; ')}` : '';
                this.status(`Uploaded "${m.name}": ${triangles(m.triangles)}.${warn}`, { actions: [close] });
                if (!warn) this.hideTimer = setTimeout(() => this.hide(), 5000);
                this.app.addModel(m);
                return;
            }
            const err = errorFromText(what, xhr.status, xhr.responseText);
            if (xhr.status === 401) {
                tokenRefused(sent);
                const ask = () => askToken(what, sent !== '').then((ok) => {
                    if (ok) this.upload(files, replace);
                    else this.status(err.words, { error: true, actions: [['Enter the token…', ask], close] });
                });
                this.status(`${what}: waiting for the daemon's token…`);
                ask();
                return;
            }
            // the name is taken, and the daemon's own remedy (its message names ?replace=1) is the Replace button:
            // said in the viewer's words; another conflict (a .mtl of the folder's) is not one that replacing mends
            if (xhr.status === 409 && /\?replace=1/.test(err.daemonMessage)) {
                this.status(`There is already a model named "${name}" on the daemon.`,
                    { error: true, actions: [[`Replace "${name}"`, () => this.upload(files, true)], close] });
                return;
            }
            this.status(err.words, { error: true, actions: [close] });
        };
        xhr.onerror = () => {
            this.status(new ApiError(what, 0, '', 'the connection failed').words, { error: true, actions: [close] });
        };
        xhr.onabort = () => {
            this.status(`${what}: cancelled.`, { actions: [close] });
        };
        xhr.send(body);
    }
}

function kib(n) {
    return n >= 1048576 ? `${(n / 1048576).toFixed(1)} MiB` : `${Math.max(1, Math.round(n / 1024))} KiB`;
}
