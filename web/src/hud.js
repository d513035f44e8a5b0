// Status overlay: connection, render and stream rates, latency.
// Rates over a sliding one-second window of this page's clock, except the stream's: frames
// reach the page in bursts whenever its thread was busy (a burst of 30 in one window read as
// 90 frames/s), so the stream's rate is counted on the server's clock, from the sequence
// numbers and server times of the frames decoded over the last two seconds.
export class Stats {
  constructor() {
    this.frames = 0; this.bytes = 0; this.renders = 0; this.dropped = 0; this.shownFrames = 0;
    this.window = []; // [t, frames, bytes, renders, shown]
    this.stream = []; // [serverTimeUs, seq] of decoded frames
    this.fps = 0; this.framesPerSec = 0; this.kBps = 0; this.shownPerSec = 0;
    this.latencyMs = null; this.decodeMs = null; this.uploadMs = null;
  }
  // A frame decoded (shown or overtaken): its place on the server's clock.
  decoded(seq, serverTimeUs) {
    if (!Number.isFinite(serverTimeUs)) return;
    const s = this.stream;
    if (s.length && (seq <= s[s.length - 1][1] || serverTimeUs < s[s.length - 1][0])) s.length = 0; // a new session
    s.push([serverTimeUs, seq]);
    while (s.length > 2 && serverTimeUs - s[0][0] > 2e6) s.shift();
    const dt = (serverTimeUs - s[0][0]) / 1e6;
    if (dt > 0.3) this.framesPerSec = (seq - s[0][1]) / dt;
  }
  tick(now) {
    this.window.push([now, this.frames, this.bytes, this.renders, this.shownFrames]);
    while (this.window.length > 2 && now - this.window[0][0] > 1000) this.window.shift();
    const [t0, , b0, r0, s0] = this.window[0];
    const dt = (now - t0) / 1000;
    if (dt > 0.2) {
      this.kBps = (this.bytes - b0) / 1024 / dt;
      this.fps = (this.renders - r0) / dt;
      this.shownPerSec = (this.shownFrames - s0) / dt;
    }
    // No frame for 2 s of this page's clock: the stream has stopped (paused page or server).
    const last = this.stream[this.stream.length - 1];
    if (last && this.lastDecodedAt !== undefined && now - this.lastDecodedAt > 2000) this.framesPerSec = 0;
  }
}

import { serverUrl } from './connection.js';

// A link rate for people: kbit/s, Mbit/s, and no figure past a gigabit (loopback's TCP
// delivery rate reads tens of Gbit/s, which says nothing about a network).
export function formatRate(kbps) {
  if (!(kbps > 0)) return '';
  if (kbps < 1000) return `${Math.round(kbps)} kbit/s`;
  if (kbps < 1e6) return `${(kbps / 1000).toFixed(kbps < 1e4 ? 1 : 0)} Mbit/s`;
  return '> 1 Gbit/s';
}
// Is the server on this machine (loopback)? Then the link is not a network at all.
export function isLocal(url) {
  try { return /^(127\.|localhost$|\[::1\]$)/.test(new URL(url).hostname); } catch { return false; }
}
// The link line (PROTOCOL.md §7.2 `link`): what matters is whether the server serves the
// subscription as asked, and when not, why (its reason) and what the link carries.
export function linkText(link, local) {
  const rtt = link && link.rtt_ms > 0 ? `  rtt ${link.rtt_ms < 10 ? link.rtt_ms.toFixed(1) : Math.round(link.rtt_ms)} ms` : '';
  const reason = link?.reason && link.reason !== 'subscribed' ? `\n         ${link.reason}` : ''; // ("subscribed" says nothing)
  if (local) { // no network: a coarser rung here means this page reads slowly
    return !link || !(link.rung > 0) ? 'local (loopback): the full stream' : `local, coarser: rung ${link.rung} of ${link.rungs - 1} (slow reader)${reason}`;
  }
  if (!link || !(link.rung > 0)) return `the full stream${rtt}${link ? `  ${formatRate(link.link_kbps)}` : ''}`.trimEnd();
  return `coarser for the link: rung ${link.rung} of ${link.rungs - 1}  ${formatRate(link.link_kbps)}${rtt}${reason}`;
}
// The server's `degraded` (PROTOCOL.md §7.2): the reason it gave, for people.
export function degradedText(d) {
  if (!d) return '';
  const what = [d.lod !== undefined && d.subscribed_lod !== undefined && d.lod !== d.subscribed_lod ? `lod ${d.lod} (asked ${d.subscribed_lod})` : null,
    d.codec === 1 ? 'intra codec' : null, d.rate && /lower rate/.test(d.reason || '') ? `${d.rate} frames/s` : null].filter(Boolean).join(', ');
  return `server serves ${what || 'less'}: ${d.reason || 'over its budget'}`;
}

// The HUD: a text block (full on large screens, two short lines on phones) that the
// user can hide (button or H key; remembered in localStorage), and the banner.
const HUD_KEY = 'oceand.hud';
export class Hud {
  constructor(el, banner, { compact = false } = {}) {
    this.el = el; this.banner = banner; this.lastDraw = 0; this.compact = compact;
    this.local = isLocal(serverUrl());
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
    this.onBanner?.(!!text);
  }
  draw(now, s, st) {
    const c = st.catchup;
    const behind = !!(c && (c.behind || c.step > 0));
    this.button.classList.toggle('warn', behind); // seen with the HUD hidden too
    if (now - this.lastDraw < 250 || !this.visible) return; // 4 Hz is plenty for text
    this.lastDraw = now;
    const cls = st.connected ? 'ok' : (st.connectionState === 'connecting' ? 'warn' : 'bad');
    const f = (v, d = 1) => (v === null || v === undefined ? '–' : v.toFixed(d));
    const esc = (t) => String(t).replace(/[&<>]/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;' })[c]);
    const err = st.lastError ? `\n<span class="bad">${esc(st.lastError.code)}: ${esc(st.lastError.message)}</span>` : '';
    // Behind the live sea (catchup.js): by how much, and what the page asks for meanwhile.
    const sec = (ms) => (ms === null || ms === undefined ? '–' : (ms / 1000).toFixed(1));
    const lag = !c ? '' : behind
      ? `\n<span class="warn oc-wrap" data-ui="behind">${c.behind ? `${sec(c.lagMs)} s behind the live sea` : 'this page is slow for the full stream'}: ${c.step ? `asking for less (${esc(c.asked)})` : 'asking for less'}</span>`
      : c.caughtUp ? '\n<span class="ok" data-ui="behind">caught up: the full stream again</span>' : '';
    // the link's first line as it is, the server's reason under it wrapped to the HUD's width
    const linkLine = (t) => { const [l1, ...why] = t.split('\n'); return esc(l1) + (why.length ? `\n         <span class="oc-wrap">${esc(why.join(' ').trim())}</span>` : ''); };
    const deg = st.degraded ? `\n<span class="warn oc-wrap" data-ui="degraded">${esc(degradedText(st.degraded))}</span>` : '';
    if (this.compact) {
      this.text.innerHTML =
        `<span class="${cls}">●</span> ${esc(st.connected ? st.clientId || '' : st.connectionState)} ${f(s.fps, s.fps < 10 ? 1 : 0)} fps\n` +
        `${f(s.framesPerSec, 0)} frames/s ${f(s.kBps, 0)} kB/s` +
        (behind ? `\n<span class="warn" data-ui="behind">${c.behind ? `${sec(c.lagMs)} s behind` : 'slow page'}: ${c.step ? esc(c.asked.split(',')[0]) : 'less'}</span>` : '') +
        (st.degraded ? `\n<span class="warn" data-ui="degraded">server: ${esc(String(st.degraded.reason || 'degraded').split(':')[0])}</span>` : '') + err;
      return;
    }
    // Only what a user can act on: a decoder that kept falling behind after the start-up
    // grace, so the page gave the temporal codec up (a smaller grid helps), not the frames
    // skipped in passing or a resync while the page was starting.
    const fallback = st.fallback ? `\n<span class="warn">decoder too slow: intra frames now (a smaller grid helps)</span>` : '';
    this.text.innerHTML =
      `<span class="${cls}">● ${esc(st.connectionState)}</span>  ${esc(st.clientId || '')}\n` +
      `render   ${f(s.fps, s.fps < 10 ? 1 : 0)} fps\n` +
      `stream   ${f(s.framesPerSec, 1)} frames/s  shown ${f(s.shownPerSec, 0)}/s\n` +
      `         ${f(s.kBps, 0)} kB/s  latency <span class="${s.latencyMs > 1000 ? 'warn' : ''}">${f(s.latencyMs, 0)} ms</span>\n` +
      `decode   ${f(s.decodeMs, 2)} ms  upload ${f(s.uploadMs, 2)} ms\n` +
      `N ${st.n ?? '–'}  lod ${st.lod ?? '–'}  foam ${st.foamLod === null || st.foamLod === undefined ? 'from folds' : `lod ${st.foamLod}`}` + deg + '\n' +
      `params v${st.paramsVersion ?? '–'}  seq ${st.lastSeq ?? '–'}\n` +
      `<span data-ui="link">link     ${linkLine(linkText(st.link, this.local))}</span>` + fallback + lag + err;
  }
}
