// Status overlay: connection, render and stream rates, latency, drops.
// Rates are computed over a sliding one-second window.
export class Stats {
  constructor() {
    this.frames = 0; this.bytes = 0; this.renders = 0; this.dropped = 0;
    this.window = []; // [t, frames, bytes, renders]
    this.fps = 0; this.framesPerSec = 0; this.kBps = 0;
    this.latencyMs = null; this.decodeMs = null; this.uploadMs = null;
  }
  tick(now) {
    this.window.push([now, this.frames, this.bytes, this.renders]);
    while (this.window.length > 2 && now - this.window[0][0] > 1000) this.window.shift();
    const [t0, f0, b0, r0] = this.window[0];
    const dt = (now - t0) / 1000;
    if (dt > 0.2) {
      this.framesPerSec = (this.frames - f0) / dt;
      this.kBps = (this.bytes - b0) / 1024 / dt;
      this.fps = (this.renders - r0) / dt;
    }
  }
}

// The HUD: a text block (full on large screens, two short lines on phones) that the
// user can hide (button or H key; remembered in localStorage), and the banner.
const HUD_KEY = 'oceand.hud';
export class Hud {
  constructor(el, banner, { compact = false } = {}) {
    this.el = el; this.banner = banner; this.lastDraw = 0; this.compact = compact;
    this.text = document.createElement('div');
    this.text.className = 'oc-hud-text';
    this.button = document.createElement('button');
    this.button.type = 'button';
    this.button.className = 'oc-hud-toggle';
    this.button.dataset.ui = 'hud-toggle';
    this.button.addEventListener('click', () => this.setVisible(!this.visible));
    el.append(this.button, this.text);
    el.classList.toggle('oc-compact', compact);
    let stored = null;
    try { stored = localStorage.getItem(HUD_KEY); } catch { /* storage blocked */ }
    this.onToggle = null;
    this.setVisible(stored !== 'hidden', false);
  }
  setVisible(on, remember = true) {
    this.visible = on;
    this.el.classList.toggle('oc-hidden', !on);
    this.button.textContent = on ? '×' : 'i';
    this.button.title = on ? 'hide the status (H)' : 'show the status (H)';
    this.lastDraw = 0;
    if (remember) { try { localStorage.setItem(HUD_KEY, on ? 'shown' : 'hidden'); } catch { /* storage blocked */ } }
    this.onToggle?.(on);
  }
  message(text) {
    this.banner.hidden = !text;
    this.banner.textContent = text || '';
  }
  draw(now, s, st) {
    if (now - this.lastDraw < 250 || !this.visible) return; // 4 Hz is plenty for text
    this.lastDraw = now;
    const cls = st.connected ? 'ok' : (st.connectionState === 'connecting' ? 'warn' : 'bad');
    const f = (v, d = 1) => (v === null || v === undefined ? '–' : v.toFixed(d));
    const esc = (t) => String(t).replace(/[&<>]/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;' })[c]);
    const err = st.lastError ? `\n<span class="bad">${esc(st.lastError.code)}: ${esc(st.lastError.message)}</span>` : '';
    if (this.compact) {
      this.text.innerHTML =
        `<span class="${cls}">●</span> ${esc(st.connected ? st.clientId || '' : st.connectionState)} ${f(s.fps, s.fps < 10 ? 1 : 0)} fps\n` +
        `${f(s.framesPerSec, 0)} f/s ${f(s.kBps, 0)} kB/s` + err;
      return;
    }
    this.text.innerHTML =
      `<span class="${cls}">● ${esc(st.connectionState)}</span>  ${esc(st.clientId || '')}\n` +
      `render   ${f(s.fps, s.fps < 10 ? 1 : 0)} fps\n` +
      `stream   ${f(s.framesPerSec, 1)} frames/s  ${f(s.kBps, 0)} kB/s\n` +
      `latency  ${f(s.latencyMs, 0)} ms   dropped ${s.dropped}\n` +
      `decode   ${f(s.decodeMs, 2)} ms  upload ${f(s.uploadMs, 2)} ms\n` +
      `N ${st.n ?? '–'}  lod ${st.lod ?? '–'}  foam ${st.foamLod === null || st.foamLod === undefined ? 'from folds' : `lod ${st.foamLod}`}\n` +
      `params v${st.paramsVersion ?? '–'}  seq ${st.lastSeq ?? '–'}\n` +
      `link     rung ${st.link ? `${st.link.rung}/${st.link.rungs - 1}  ${f(st.link.link_kbps / 1000, 1)} Mbit/s` : '0 (as asked)'}` + err;
  }
}
