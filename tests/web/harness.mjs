// Shared by the web tests and the web benchmark: a free loopback port, a real
// oceand (or, with --fake, the stand-in server), and headless Debian chromium.
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { chromium } from './webdeps.mjs';

export const CHROMIUM_ARGS = ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--no-sandbox',
  '--disable-background-networking', '--disable-component-update', '--disable-sync', '--no-first-run'];

export function parseArgs(argv, defaults) {
  const a = { ...defaults };
  for (let i = 2; i < argv.length; i++) {
    const k = argv[i].replace(/^--/, '').replace(/-([a-z])/g, (_, c) => c.toUpperCase());
    if (typeof a[k] === 'boolean') a[k] = true; else a[k] = argv[++i];
  }
  return a;
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

export function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => { const { port } = s.address(); s.close(() => resolve(port)); });
  });
}

async function waitHttp(port, ms) {
  const end = Date.now() + ms;
  while (Date.now() < end) {
    try { const r = await fetch(`http://127.0.0.1:${port}/`); if (r.ok) return; } catch { /* not up yet */ }
    await sleep(100);
  }
  throw new Error(`server on port ${port} did not answer within ${ms} ms`);
}

// Start oceand (or the fake) on `port`; returns { port, stop(), log() }.
export async function startServer({ oceand, webRoot, port, fake = false, extra = [] }) {
  if (fake) {
    const { startFakeServer } = await import('./fake_server.mjs');
    const r = extra.indexOf('--resolution');
    const s = await startFakeServer({ port, webRoot, resolution: r >= 0 ? Number(extra[r + 1]) : undefined });
    return { port: s.port, stop: s.close, log: () => '' };
  }
  if (!fs.existsSync(oceand)) throw new Error(`no daemon at ${oceand} (build it: make ${oceand})`);
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'oceand-web-'));
  const proc = spawn(oceand, ['--port', String(port), '--web-root', webRoot,
    '--state-file', path.join(dir, 'state.json'), '--log-level', 'warn', ...extra],
  { stdio: ['ignore', 'pipe', 'pipe'] });
  let out = '';
  proc.stdout.on('data', (d) => { out += d; });
  proc.stderr.on('data', (d) => { out += d; });
  const exited = new Promise((r) => proc.once('exit', r));
  await Promise.race([waitHttp(port, 15000),
    exited.then((code) => { throw new Error(`oceand exited (${code}) at start:\n${out}`); })]);
  return {
    port,
    log: () => out,
    async stop() {
      if (proc.exitCode === null && proc.signalCode === null) {
        proc.kill('SIGTERM');
        const t = setTimeout(() => proc.kill('SIGKILL'), 5000);
        await exited; clearTimeout(t);
      }
      fs.rmSync(dir, { recursive: true, force: true });
    },
  };
}

export function launchBrowser() {
  return chromium.launch({ executablePath: '/usr/bin/chromium', args: CHROMIUM_ARGS });
}

// Poll fn() in the page until truthy; throws with `what` on timeout.
export async function waitFor(page, what, fn, arg, ms = 30000) {
  try {
    await page.waitForFunction(fn, arg, { timeout: ms, polling: 100 });
  } catch (e) {
    throw new Error(`timed out after ${ms} ms waiting for: ${what}`);
  }
}
