// A stand-in for oceand, used only while build/oceand does not exist yet (and
// by hand for front-end work): serves a static folder over HTTP and speaks the
// control protocol + binary frames (raw float32 tiles, codec 0) on the same port.
// The sea is a sum of periodic travelling waves, so the page has something to show.
//   node tests/web/fake_server.mjs --port 8090 --web-root build/web
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { WebSocketServer } from './webdeps.mjs';

const FIELDS = ['height', 'dx', 'dz', 'slope_x', 'slope_z', 'jacobian'];
const SCHEMA = [
  { name: 'resolution', type: 'int', unit: '', min: 16, max: 1024, default: 256, pow2: true },
  { name: 'patch_size', type: 'float', unit: 'm', min: 1, max: 10000, default: 256 },
  { name: 'wind_speed', type: 'float', unit: 'm/s', min: 0, max: 40, default: 10 },
  { name: 'wind_direction', type: 'float', unit: 'deg', min: -360, max: 360, default: 0 },
  { name: 'amplitude', type: 'float', unit: '', min: 0, max: 10, default: 1 },
  { name: 'spectrum', type: 'enum', choices: ['phillips', 'pierson_moskowitz', 'jonswap', 'tma'], default: 'jonswap' },
  { name: 'choppiness', type: 'float', unit: '', min: 0, max: 4, default: 1 },
  { name: 'paused', type: 'bool', default: false },
];
const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css', '.map': 'application/json' };

function args() {
  const a = { port: 8090, webRoot: 'build/web' };
  for (let i = 2; i < process.argv.length; i++) {
    if (process.argv[i] === '--port') a.port = Number(process.argv[++i]);
    else if (process.argv[i] === '--web-root') a.webRoot = process.argv[++i];
  }
  return a;
}

// Waves: integer wave numbers keep the patch periodic.
function makeWaves(p) {
  const dir = (p.wind_direction * Math.PI) / 180;
  const waves = [];
  let seed = 7;
  const rnd = () => ((seed = (seed * 16807) % 2147483647) / 2147483647);
  for (let w = 0; w < 24; w++) {
    const kmag = 2 + Math.floor(rnd() * 30);
    const ang = dir + (rnd() - 0.5) * 1.6;
    const a = Math.round(Math.cos(ang) * kmag), b = Math.round(Math.sin(ang) * kmag);
    if (!a && !b) continue;
    const k = (2 * Math.PI / p.patch_size) * Math.hypot(a, b);
    const amp = p.amplitude * 0.02 * p.wind_speed * Math.pow(kmag, -1.1) * (0.5 + rnd());
    waves.push({ a, b, k, amp, omega: Math.sqrt(9.81 * k), phase: rnd() * 6.283 });
  }
  return waves;
}

function synth(n, p, waves, t) {
  const f = {}; for (const name of FIELDS) f[name] = new Float32Array(n * n);
  const L = p.patch_size, chop = p.choppiness;
  const cx = new Float64Array(n), sx = new Float64Array(n), cz = new Float64Array(n), sz = new Float64Array(n);
  for (const w of waves) {
    const kx = (2 * Math.PI * w.a) / L, kz = (2 * Math.PI * w.b) / L;
    for (let i = 0; i < n; i++) {
      const ax = kx * (i * L / n) - w.omega * t + w.phase, az = kz * (i * L / n);
      cx[i] = Math.cos(ax); sx[i] = Math.sin(ax); cz[i] = Math.cos(az); sz[i] = Math.sin(az);
    }
    const ux = kx / w.k, uz = kz / w.k, A = w.amp;
    for (let j = 0; j < n; j++) for (let i = 0; i < n; i++) {
      const c = cx[i] * cz[j] - sx[i] * sz[j], s = sx[i] * cz[j] + cx[i] * sz[j], o = j * n + i;
      f.height[o] += A * c;
      f.dx[o] -= chop * A * ux * s; f.dz[o] -= chop * A * uz * s;
      f.slope_x[o] -= A * kx * s; f.slope_z[o] -= A * kz * s;
      f.jacobian[o] -= chop * A * w.k * (ux * ux + uz * uz) * c;
    }
  }
  for (let o = 0; o < n * n; o++) f.jacobian[o] += 1;
  return f;
}

function encodeFrame(seq, simTime, version, n, patch, fields, lod, data) {
  const ts = Math.min(64, n), tiles = n / ts, w = ts >> lod;
  const count = tiles * tiles * fields.length;
  const buf = Buffer.alloc(48 + count * (40 + w * w * 4));
  buf.write('OCNF', 0, 'latin1'); buf.writeUInt16LE(1, 4); buf.writeUInt16LE(48, 6);
  buf.writeBigUInt64LE(BigInt(seq), 8); buf.writeDoubleLE(simTime, 16); buf.writeUInt32LE(version, 24);
  buf.writeUInt16LE(n, 28); buf.writeUInt16LE(ts, 30); buf.writeFloatLE(patch, 32); buf.writeUInt16LE(count, 36);
  buf.writeUInt16LE(0, 38); buf.writeBigUInt64LE(BigInt(Date.now()) * 1000n, 40);
  let o = 48;
  for (const name of fields) for (let tz = 0; tz < tiles; tz++) for (let tx = 0; tx < tiles; tx++) {
    buf.writeUInt8(FIELDS.indexOf(name), o); buf.writeUInt8(lod, o + 1); buf.writeUInt8(0, o + 2);
    buf.writeUInt16LE(tx, o + 4); buf.writeUInt16LE(tz, o + 6); buf.writeUInt16LE(w, o + 8); buf.writeUInt16LE(w, o + 10);
    buf.writeFloatLE(0, o + 12); buf.writeDoubleLE(0, o + 16); buf.writeDoubleLE(1, o + 24); buf.writeUInt32LE(w * w * 4, o + 32);
    o += 40;
    const src = data[name];
    for (let j = 0; j < w; j++) for (let i = 0; i < w; i++, o += 4) {
      buf.writeFloatLE(src[(tz * ts + (j << lod)) * n + tx * ts + (i << lod)], o);
    }
  }
  return buf;
}

export function startFakeServer({ port, webRoot, resolution }) {
  const params = Object.fromEntries(SCHEMA.map((s) => [s.name, s.default]));
  if (resolution) params.resolution = resolution;
  let version = 1, seq = 0, simTime = 0, clients = 0;
  let waves = makeWaves(params);
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, 'http://x');
    let file = path.join(webRoot, path.normalize(url.pathname === '/' ? '/index.html' : url.pathname));
    if (!file.startsWith(path.resolve(webRoot)) && !file.startsWith(webRoot)) { res.writeHead(403).end(); return; }
    fs.readFile(file, (err, body) => {
      if (err) { res.writeHead(404).end('not found'); return; }
      res.writeHead(200, { 'content-type': TYPES[path.extname(file)] || 'application/octet-stream' }).end(body);
    });
  });
  const wss = new WebSocketServer({ server, handleProtocols: (p) => (p.has('oceand.v1') ? 'oceand.v1' : false) });
  const send = (ws, o) => ws.readyState === 1 && ws.send(JSON.stringify(o));
  wss.on('connection', (ws) => {
    ws.clientId = `c${++clients}`;
    ws.sub = { fields: ['height', 'dx', 'dz'], lod: 0, tiles: 'all', bound: 0.01, max_rate: 30 };
    send(ws, {
      type: 'hello', protocol: 1, server: 'fake-oceand/0', client_id: ws.clientId, role: 'controller',
      params, params_version: version, schema: SCHEMA, fields: FIELDS, lods: [0, 1, 2, 3, 4],
      bounds: [0, 0.001, 0.005, 0.01, 0.05], tick_rate: 30, tile_size: 64, subscription: ws.sub,
    });
    ws.on('message', (data, isBinary) => {
      let m;
      try { m = JSON.parse(data.toString()); } catch { return send(ws, { type: 'error', code: 'bad_json', message: 'bad json' }); }
      if (isBinary) return send(ws, { type: 'error', code: 'bad_message', message: 'binary' });
      if (m.type === 'set') {
        const changed = [];
        for (const [k, v] of Object.entries(m.params || {})) {
          const s = SCHEMA.find((x) => x.name === k);
          if (!s) return send(ws, { type: 'error', code: 'unknown_param', message: `unknown ${k}`, id: m.id, param: k });
          if (params[k] !== v) { params[k] = v; changed.push(k); }
        }
        if (changed.length) { version++; waves = makeWaves(params); }
        for (const c of wss.clients) {
          if (changed.length || c === ws) send(c, { type: 'params', params, params_version: version, changed, by: ws.clientId, ...(ws.name ? { by_name: ws.name } : {}), ...(c === ws ? { id: m.id } : {}) });
        }
      } else if (m.type === 'subscribe') {
        for (const k of ['fields', 'lod', 'bound', 'max_rate']) if (m[k] !== undefined) ws.sub[k] = m[k];
        send(ws, { type: 'subscribed', id: m.id, subscription: ws.sub });
      } else if (m.type === 'name') { // no checks here: the real server's rules are in name.js and control.c
        ws.name = String(m.name || '');
        send(ws, { type: 'named', id: m.id, name: ws.name });
      } else if (m.type === 'ping') {
        send(ws, { type: 'pong', id: m.id, t: m.t, server_time_us: Date.now() * 1000 });
      } else send(ws, { type: 'error', code: 'unknown_type', message: m.type, id: m.id });
    });
  });
  const timer = setInterval(() => {
    if (!wss.clients.size) return;
    if (!params.paused) simTime += 1 / 30;
    seq++;
    const n = params.resolution, data = synth(n, params, waves, simTime);
    for (const c of wss.clients) {
      if (c.readyState !== 1) continue;
      c.send(encodeFrame(seq, simTime, version, n, params.patch_size, c.sub.fields, c.sub.lod, data));
    }
  }, 1000 / 30);
  return new Promise((resolve) => server.listen(port, '127.0.0.1', () => resolve({
    port: server.address().port,
    close: () => new Promise((r) => { clearInterval(timer); for (const c of wss.clients) c.terminate(); wss.close(); server.close(() => r()); }),
  })));
}

if (import.meta.url === `file://${process.argv[1]}`) {
  const a = args();
  startFakeServer(a).then((s) => console.log(`fake oceand on http://127.0.0.1:${s.port}/ serving ${a.webRoot}`));
}
