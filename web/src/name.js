// Display names (PROTOCOL.md §7.1 `name`): the server's rules, checked here first so the
// panel can say what is wrong before sending (the server checks again: bad_name).
// At most 32 code points; no controls or invisible characters; no markup < > & " ';
// no space at either end. Returns null when the name is fine, else the reason.
export const NAME_MAX_CHARS = 32;
export const NAME_KEY = 'oceand.name';

function refused(c) {
  return c < 0x20 || (c >= 0x7f && c < 0xa0) || c === 0xad || (c >= 0x200b && c <= 0x200f)
    || (c >= 0x2028 && c <= 0x202e) || (c >= 0x2060 && c <= 0x206f) || c === 0xfeff
    || (c >= 0xe000 && c <= 0xf8ff) || (c >= 0xfff0 && c <= 0xffff) || (c & 0xfffe) === 0xfffe
    || (c >= 0xfdd0 && c <= 0xfdef) || c >= 0xf0000;
}

export function checkName(name) {
  if (typeof name !== 'string') return 'a name is text';
  const cps = [...name];
  if (cps.length > NAME_MAX_CHARS) return `at most ${NAME_MAX_CHARS} characters`;
  for (const ch of cps) {
    const c = ch.codePointAt(0);
    if ('<>&"\''.includes(ch)) return `no ${ch} (no markup: < > & " ')`;
    if (c >= 0xd800 && c <= 0xdfff) return 'not valid text (a lone surrogate)';
    if (refused(c)) return `no U+${c.toString(16).toUpperCase().padStart(4, '0')} (control or invisible character)`;
  }
  if (cps.length && (cps[0] === ' ' || cps[cps.length - 1] === ' ')) return 'no space at either end';
  return null;
}

// What the field's text becomes before checking: spaces at the ends go, runs of
// whitespace become one space.
export const tidyName = (s) => String(s ?? '').replace(/\s+/g, ' ').trim();

export function storedName() {
  try { const n = localStorage.getItem(NAME_KEY) || ''; return checkName(n) ? '' : n; } catch { return ''; }
}
export function storeName(n) {
  try { if (n) localStorage.setItem(NAME_KEY, n); else localStorage.removeItem(NAME_KEY); } catch { /* storage blocked */ }
}
