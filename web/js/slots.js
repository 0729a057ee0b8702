// slots.js - at most n frame requests on their way at once, shared fairly by
// the panes. The daemon renders GET /api/stats' queue.threads frames at a
// time (one per worker) and queues the rest: requests beyond that would only
// wait there, arrive together, and let one pane's strips queue behind the
// other's. Waiting requests are started in turn, one owner after the other
// (round robin), so in split view neither pane is served first.

export class Slots {
    constructor(n) {
        this.n = n;
        this.busy = 0;
        this.waiting = new Map(); // owner -> [{start, signal}]: insertion order is the turn order
        this.dispatchQueued = false;
    }

    /** The daemon's workers: n requests at once from now on. */
    resize(n) {
        this.n = n;
        this.dispatch();
    }

    /**
     * Runs fn() once a slot is free and owner's turn comes; resolves to its
     * result. A request aborted (signal) while it waits is dropped and
     * rejects with an AbortError.
     */
    run(owner, fn, signal) {
        return new Promise((resolve, reject) => {
            if (signal.aborted) { reject(new DOMException('Aborted', 'AbortError')); return; }
            const job = { signal };
            job.start = () => {
                signal.removeEventListener('abort', job.drop);
                this.busy++;
                Promise.resolve().then(fn).then(resolve, reject).finally(() => {
                    this.busy--;
                    this.dispatch();
                });
            };
            job.drop = () => {
                const list = this.waiting.get(owner) || [];
                const i = list.indexOf(job);
                if (i >= 0) list.splice(i, 1);
                if (!list.length) this.waiting.delete(owner);
                reject(new DOMException('Aborted', 'AbortError'));
            };
            signal.addEventListener('abort', job.drop, { once: true });
            if (!this.waiting.has(owner)) this.waiting.set(owner, []);
            this.waiting.get(owner).push(job);
            // started after the current task: panes asking at the same time (pumpAll) all queue before any starts
            if (!this.dispatchQueued) {
                this.dispatchQueued = true;
                queueMicrotask(() => { this.dispatchQueued = false; this.dispatch(); });
            }
        });
    }

    /** Starts waiting requests while slots are free, the owner whose turn it is first. */
    dispatch() {
        while (this.busy < this.n && this.waiting.size) {
            const [owner, list] = this.waiting.entries().next().value;
            const job = list.shift();
            // the owner goes to the back of the turn order, with what it still has waiting
            this.waiting.delete(owner);
            if (list.length) this.waiting.set(owner, list);
            job.start();
        }
    }
}
