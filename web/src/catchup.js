// A page that falls behind the live sea says so and asks for less (docs/web.md "Falling behind").
//
// The server's quality ladder (PROTOCOL.md §7.2 `link`) sees a slow link, or a reader whose
// socket fills; it does not see frames the browser has already taken off the socket and holds
// for a busy page (a main thread drawing in software GL: megabytes, tens of seconds). So the
// page measures its own lag: the age of each frame when it reaches the page (its header's
// server_time_us against the page's clock, corrected by the clock offset a ping on the control
// connection measures). The freshest frame of the last WINDOW_MS older than BEHIND_MS: the page
// is behind. It then asks for less (the next step of STEPS below: coarser LOD, no finer
// cascades, a lower rate; a `subscribe`, PROTOCOL.md §7.1), chosen from what it manages to
// read against what the stream wants, and opens a fresh connection, which drops whatever the
// browser still holds of the old one (reading it would take as long as the lag). It says so in
// the HUD. Every frame younger than CAUGHT_MS for the hold (8 s, doubled each time a step up
// fell behind again within 30 s, at most 2 min): one step back up.

export const BEHIND_MS = 1000;
export const CAUGHT_MS = 500;
const WINDOW_MS = 3000;
const HOLD_MS = 8000, HOLD_MAX_MS = 120000;
const MIN_GAP_MS = 4000;   // between two steps down: the new session's frames must come in first

// The page's own ladder, finest first. `bytes` is a rough share of step 0's bytes per second
// (a LOD quarters the samples; the finer cascades are about a sixth of the bytes; below the
// tick rate a temporal stream is keyframes, about 3× a predicted frame).
export const STEPS = [
  { lodUp: 0, cascades: true, rate: 0, bytes: 1 },
  { lodUp: 1, cascades: true, rate: 0, bytes: 0.3 },
  { lodUp: 2, cascades: false, rate: 0, bytes: 0.06 },
  { lodUp: 3, cascades: false, rate: 10, bytes: 0.02 },
  { lodUp: 4, cascades: false, rate: 5, bytes: 0.005 },
];

export class CatchUp {
  constructor({ enabled = true } = {}) {
    this.enabled = enabled;
    this.step = 0;
    this.samples = [];        // [page ms, age ms, bytes] of frames as they reach the page
    this.offsetMs = 0;        // server clock − page clock (ms), from the best ping
    this.bestRtt = Infinity;
    this.lastChange = -Infinity; this.lastUp = -Infinity; this.calmSince = null;
    this.hold = HOLD_MS;
    this.events = [];         // [{atMs, step, lagMs, why}] for tests and curious users
    this.reconnects = 0;
    this.notBefore = Infinity; // no verdict before the first frame is drawn plus the grace
    this.caughtUpAt = null;
  }
  // A frame reached the page (before the decoder): its age on the server's clock.
  arrived(serverTimeUs, now, bytes) {
    if (!Number.isFinite(serverTimeUs)) return;
    const age = performance.timeOrigin + now - serverTimeUs / 1000 + this.offsetMs;
    this.samples.push([now, age, bytes]);
    while (this.samples.length > 2 && now - this.samples[0][0] > Math.max(WINDOW_MS, 4000)) this.samples.shift();
  }
  // pong (PROTOCOL.md §7.2): the server's clock at about the middle of the round trip.
  pong(msg, now) {
    const sent = Number(msg.t), server = Number(msg.server_time_us);
    if (!Number.isFinite(sent) || !Number.isFinite(server)) return;
    const rtt = now - sent;
    if (rtt < 0 || rtt > this.bestRtt) return;
    this.bestRtt = rtt;
    this.offsetMs = server / 1000 - (performance.timeOrigin + (sent + now) / 2);
  }
  newServer() { this.bestRtt = Infinity; this.offsetMs = 0; }
  // The lag now: the youngest frame of the last window (null: no frame in it).
  lagMs(now) {
    let best = Infinity;
    for (const [t, age] of this.samples) if (now - t <= WINDOW_MS) best = Math.min(best, age);
    return best === Infinity ? null : best;
  }
  // What the subscription asks for at this step, on top of `base` (the lod chosen, the
  // cascades wanted, the tick rate): members for a `subscribe`.
  overrides({ lod = 0, cascades = null, tickRate = 30 } = {}) {
    const s = STEPS[this.step];
    if (!this.step) return {};
    const o = { lod: Math.min(4, lod + s.lodUp) };
    if (!s.cascades && cascades) o.cascades = [];
    if (s.rate) o.max_rate = Math.min(tickRate, s.rate);
    return o;
  }
  // What this step restores when it goes back up (members the lower steps had changed).
  restore({ lod = 0, cascades = null, tickRate = 30 } = {}) {
    const s = STEPS[this.step], o = { lod: Math.min(4, lod + s.lodUp), max_rate: s.rate ? Math.min(tickRate, s.rate) : tickRate };
    if (cascades) o.cascades = s.cascades ? cascades : [];
    return o;
  }
  // Once an animation frame: null, or { down: true } (step down and reconnect) / { up: true }.
  update(now) {
    if (!this.enabled || now < this.notBefore) return null;
    const lag = this.lagMs(now);
    if (lag === null) return null;
    const win = this.samples.filter(([t]) => now - t <= WINDOW_MS);
    const covered = win.length && now - this.samples[0][0] >= WINDOW_MS; // a whole window on this connection
    if (lag > BEHIND_MS && covered && now - this.lastChange >= MIN_GAP_MS && this.step < STEPS.length - 1) {
      // Jump to the first step whose stream fits half of what the page reads (bytes per
      // second on its clock); at least one step, at most two (a stream that skips ticks is
      // keyframes, which overstates what it wants; the next trip goes further if need be).
      const readBps = win.reduce((s, x) => s + x[2], 0) / (WINDOW_MS / 1000);
      const frameBytes = win.reduce((s, x) => s + x[2], 0) / win.length;
      const wantBps = frameBytes * (this.tickRate || 30) / (STEPS[this.step].rate ? (this.tickRate || 30) / STEPS[this.step].rate : 1);
      let k = this.step + 1;
      while (k < Math.min(STEPS.length - 1, this.step + 2) && wantBps * STEPS[k].bytes / STEPS[this.step].bytes > 0.5 * readBps) k++;
      if (now - this.lastUp < 30000) this.hold = Math.min(HOLD_MAX_MS, this.hold * 2); // the step up did not hold
      this.events.push({ atMs: Math.round(now), from: this.step, step: k, lagMs: Math.round(lag), readKBps: Math.round(readBps / 1024), wantKBps: Math.round(wantBps / 1024) });
      this.step = k; this.lastChange = now; this.calmSince = null; this.caughtUpAt = null;
      this.samples.length = 0; this.reconnects++;
      return { down: true };
    }
    // Caught up: every frame of the hold younger than CAUGHT_MS.
    const worst = Math.max(...win.map((x) => x[1]));
    if (worst < CAUGHT_MS) { if (this.calmSince === null) this.calmSince = now; } else this.calmSince = null;
    if (this.calmSince !== null && now - this.lastUp > 60000) this.hold = HOLD_MS;
    if (this.step > 0 && this.calmSince !== null && now - this.calmSince >= this.hold && now - this.lastChange >= this.hold) {
      this.events.push({ atMs: Math.round(now), from: this.step, step: this.step - 1, lagMs: Math.round(lag) });
      this.step--; this.lastChange = now; this.lastUp = now; this.calmSince = null;
      if (this.step === 0) this.caughtUpAt = now;
      return { up: true };
    }
    return null;
  }
  // For the HUD and window.oceand: { lagMs, behind, step, steps, asked (text), hold }.
  status(now, sub) {
    const lag = this.lagMs(now);
    const s = STEPS[this.step];
    const asked = this.step ? [`lod ${sub?.lod ?? '?'}`, s.cascades ? null : 'no finer cascades', s.rate ? `${sub?.max_rate ?? s.rate} frames/s` : null].filter(Boolean).join(', ') : '';
    return {
      lagMs: lag === null ? null : Math.round(lag), behind: lag !== null && lag > BEHIND_MS, step: this.step, steps: STEPS.length - 1,
      asked, holdMs: this.hold, reconnects: this.reconnects, offsetMs: Math.round(this.offsetMs), enabled: this.enabled,
      caughtUp: this.caughtUpAt !== null && now - this.caughtUpAt < 8000, events: this.events.slice(-10),
    };
  }
}
