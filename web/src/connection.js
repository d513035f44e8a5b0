// WebSocket link to oceand: JSON control messages + binary frames, with
// automatic reconnect (exponential backoff). Knows nothing about rendering.
import { SUBPROTOCOL, FrameJoiner } from '../../proto/js/oc_decode.js';

const BACKOFF_MIN_MS = 500;
const BACKOFF_MAX_MS = 10000;

// Server address: ?server=ws://... overrides; otherwise the page's own host.
export function serverUrl(loc = window.location) {
  const q = new URLSearchParams(loc.search).get('server');
  if (q) return q;
  const scheme = loc.protocol === 'https:' ? 'wss:' : 'ws:';
  return `${scheme}//${loc.host || '127.0.0.1:8080'}/`;
}

// The same server, for a session that carries control messages only (no frames: PROTOCOL.md §1.2).
export function controlUrl(url) {
  try {
    const u = new URL(url);
    u.searchParams.set('frames', '0');
    return u.toString();
  } catch { return url; } // a bad address: the frame connection reports it
}

export class Connection {
  // handlers: { onState(state, detail), onMessage(obj), onFrame(arrayBuffer) }
  constructor(url, handlers) {
    this.url = url;
    this.h = handlers;
    this.ws = null;
    this.state = 'idle';        // connecting | open | retrying | closed
    this.backoff = BACKOFF_MIN_MS;
    this.nextId = 1;
    this.retryTimer = null;
    this.refusal = null;        // last error text from the server, shown on close
  }

  start() { this.open(); }

  setState(state, detail) {
    this.state = state;
    this.h.onState?.(state, detail);
  }

  open() {
    clearTimeout(this.retryTimer);
    this.setState('connecting', `connecting to ${this.url}`);
    let ws;
    try {
      ws = new WebSocket(this.url, SUBPROTOCOL);
    } catch (e) { // bad URL: retrying will not help
      this.setState('closed', `bad server address ${this.url}: ${e.message}`);
      return;
    }
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    let opened = false;
    const joiner = new FrameJoiner(); // a tick's frame may come in parts, with replies between them
    this.joiner = joiner;
    ws.onopen = () => {
      opened = true;
      if (ws.protocol !== SUBPROTOCOL) {
        this.refusal = `server does not speak ${SUBPROTOCOL} (got "${ws.protocol}")`;
        ws.close(1002);
        return;
      }
      this.setState('open', `connected to ${this.url}`);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        let msg;
        try { msg = JSON.parse(ev.data); } catch { return; }
        if (msg.type === 'hello') this.backoff = BACKOFF_MIN_MS; // a real session: reset backoff
        if (msg.type === 'error' && msg.id === undefined) this.refusal = `${msg.code}: ${msg.message}`;
        this.h.onMessage?.(msg);
      } else {
        let frame;
        try { frame = joiner.push(ev.data); } catch { frame = ev.data; } // the decoder reports what is wrong
        if (frame) this.h.onFrame?.(frame);
      }
    };
    ws.onclose = (ev) => {
      if (this.ws !== ws) return;
      this.ws = null;
      const delay = this.backoff;
      this.backoff = Math.min(this.backoff * 2, BACKOFF_MAX_MS);
      const retry = ` — retrying in ${(delay / 1000).toFixed(1)} s`;
      this.retryTimer = setTimeout(() => this.open(), delay);
      if (opened) {
        const why = this.refusal ? `server refused: ${this.refusal}`
          : `connection lost (code ${ev.code}${ev.reason ? ', ' + ev.reason : ''})`;
        this.refusal = null;
        this.setState('retrying', why + retry);
        return;
      }
      // The upgrade failed: tell "nothing there" from "there, but said no".
      this.setState('retrying', `server unreachable at ${this.url}${retry}`);
      this.probe().then((up) => {
        if (up && this.state === 'retrying' && !this.ws) {
          this.setState('retrying', `server at ${this.url} is up but refused the WebSocket (full, or origin not allowed)${retry}`);
        }
      });
    };
  }

  // Drop this connection and open a new one at once (catchup.js: a page that fell behind; the
  // frames the browser still holds for the old socket are discarded, not read). The states
  // are those of a first connect: 'connecting', then 'open'.
  reopen() {
    const ws = this.ws;
    if (!ws) return;
    this.ws = null; // its onclose sees another socket and does nothing
    ws.onmessage = null;
    try { ws.close(1000, 'catching up'); } catch { /* already closing */ }
    this.open();
  }

  // Does the daemon answer HTTP at the same address? (/healthz; same origin only.)
  async probe() {
    try {
      const http = new URL(this.url.replace(/^ws/, 'http'));
      if (http.origin !== window.location.origin) return false;
      const ctl = new AbortController();
      const t = setTimeout(() => ctl.abort(), 2000);
      const r = await fetch(new URL('/healthz', http), { cache: 'no-store', signal: ctl.signal });
      clearTimeout(t);
      return r.ok;
    } catch { return false; }
  }

  // Send a control message; returns its id (or null when not connected).
  send(obj) {
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) return null;
    const id = this.nextId++;
    this.ws.send(JSON.stringify({ ...obj, id }));
    return id;
  }
}
