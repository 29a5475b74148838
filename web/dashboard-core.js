// The dashboard's shared pieces: who is logged in (and the CSRF token, kept in memory only),
// the selected study, calling the API, showing every action's result, small formatters.

import { api, el } from './common.js';

export { el };

/** Everything the views share. Nothing else is kept between requests. */
export const S = {
  csrf: null,
  user: null,
  studyId: null,
  study: null,
  studies: [],
  /** [{subject, tests_complete, tests}] of the selected study. */
  subjects: [],
  /** Paired stations of the selected study. */
  stations: [],
  /** {connected, pid, rig} from GET /api/controller and `controller` live messages. */
  controller: { connected: null, pid: null, rig: null },
  /** Each site's controller from GET /api/controller: [{site, connected, estop_latched, …}]. */
  sites: [],
  loggedIn: false,
};

// ---- events between the views -------------------------------------------------------------

const bus = new EventTarget();

/** Events: study (selected study changed), subjects (list reloaded), trial (a trial changed),
 *  stations (list reloaded), controller (link state), action (an action finished). */
export function emit(name, detail) {
  bus.dispatchEvent(new CustomEvent(name, { detail }));
}

export function on(name, fn) {
  bus.addEventListener(name, (e) => fn(e.detail));
}

// ---- calling the API ----------------------------------------------------------------------

let unauthorized = () => {};

/** Called when any request answers 401 (the session expired or was logged out elsewhere). */
export function onUnauthorized(fn) {
  unauthorized = fn;
}

/** GET: returns {ok, status, data}. */
export async function get(path) {
  const r = await api('GET', path);
  if (r.status === 401 && S.loggedIn) unauthorized();
  return r;
}

/** A state-changing request, with the CSRF token. */
export async function send(method, path, body) {
  const r = await api(method, path, body, { csrf: S.csrf });
  if (r.status === 401 && S.loggedIn) unauthorized();
  return r;
}

export function post(path, body) {
  return send('POST', path, body);
}

/** The error of a failed response, as one readable line. */
export function errText(r) {
  const d = r.data;
  let m = (d && typeof d === 'object' && d.error) || (typeof d === 'string' ? d : '') || 'no answer';
  if (d && Array.isArray(d.fields) && d.fields.length) {
    m += ': ' + d.fields.map((f) => `${f.field}: ${f.message}`).join('; ');
  }
  return r.status ? `${m} (HTTP ${r.status})` : m;
}

// ---- showing results ----------------------------------------------------------------------

/** Sets a status line: kind = ok | err | busy | info. */
export function setStatus(node, kind, text) {
  if (!node) return;
  node.classList.remove('ok', 'err', 'busy', 'info');
  node.classList.add('status', kind);
  node.textContent = text;
  node.hidden = !text;
}

/**
 * Runs one experimenter action: shows "label…" in `out` while it runs, then its result there
 * (with the time) and in the activity log. `fn` returns an api() result. `okText(data)` may
 * describe a success. Returns the api() result.
 */
export async function act(label, out, fn, okText) {
  setStatus(out, 'busy', `${label}…`);
  const r = await fn();
  const when = clock(Date.now());
  if (r.ok) {
    const text = okText ? okText(r.data) : 'done';
    setStatus(out, 'ok', `${label}: ${text} (${when})`);
    logActivity(true, `${label}: ${text}`);
  } else {
    const text = errText(r);
    setStatus(out, 'err', `${label} failed: ${text} (${when})`);
    logActivity(false, `${label} failed: ${text}`);
  }
  emit('action', { label, ok: r.ok });
  return r;
}

/** Appends to the activity log at the side of the page (newest first, 60 kept). */
export function logActivity(ok, text) {
  const list = document.getElementById('activity');
  if (!list) return;
  list.prepend(
    el('li', { class: ok ? 'ok' : 'err' }, el('time', {}, clock(Date.now())), ' ', text),
  );
  while (list.children.length > 60) list.lastElementChild.remove();
}

// ---- formatting ---------------------------------------------------------------------------

const pad = (n) => String(n).padStart(2, '0');

/** HH:MM:SS of a time in ms since the epoch. */
export function clock(ms) {
  const d = new Date(ms);
  return `${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
}

/** Date and time, the date left out when it is today. */
export function when(ms) {
  if (ms === null || ms === undefined) return '';
  const d = new Date(ms);
  const today = new Date();
  const sameDay = d.toDateString() === today.toDateString();
  const date = `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}`;
  return sameDay ? clock(ms) : `${date} ${clock(ms)}`;
}

/** A number for a table: 4 significant digits, exponent for large values, '' when missing. */
export function num(v, digits = 4) {
  if (v === null || v === undefined || Number.isNaN(v)) return '';
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(2).replace('e+', 'e');
  return String(Number(v.toPrecision(digits)));
}

/** m:ss of a number of seconds. */
export function mmss(s) {
  if (!Number.isFinite(s)) return '–';
  const neg = s < 0;
  const t = Math.round(Math.abs(s));
  return `${neg ? '−' : ''}${Math.floor(t / 60)}:${pad(t % 60)}`;
}

/** Seats (and a station's role: the seats it serves). */
export const SEAT_NAME = { on: 'ON the machine', off: 'OFF (desk)', both: 'both seats' };

/** Human name of a compensator kind (the real, unblinded one). */
export const COMPENSATOR_NAME = {
  pid: 'PID',
  'pid-notch': 'PID + notch',
  'pid-shaper': 'PID + input shaper',
  lqr: 'LQR',
  'lqr-cabvel': 'LQR + cab velocity',
  'lqr-cabacc': 'LQR + cab acceleration',
  'pid-notch-adaptive': 'PID + adaptive notch',
  'pid-shaper-adaptive': 'PID + adaptive input shaper',
  'lqr-cabvel-scheduled': 'LQR + cab velocity, scheduled on the mode',
};

/** How the test ran: the station's display and input, the controller's timing. */
export function validityText(t) {
  const parse = (j) => {
    try {
      return j ? JSON.parse(j) : null;
    } catch {
      return null;
    }
  };
  const c = parse(t.client_timing_json);
  const k = parse(t.timing_json);
  const parts = [];
  if (c) {
    parts.push(`display ${c.frames} frames, longest gap ${num(c.longest_gap_ms)} ms, hidden ${num(c.hidden_ms)} ms`);
    parts.push(`input ${num(c.input_hz)} Hz, round trip p50 ${num(c.rtt_ms.p50)} / p95 ${num(c.rtt_ms.p95)} / max ${num(c.rtt_ms.max)} ms`);
  } else if (t.started_at) parts.push('no display figures from the station');
  if (k) parts.push(`controller ${k.overruns} overruns, wake p99 ${num(k.wake_latency_us.p99)} µs`);
  return parts.join(' · ');
}

export function compensatorName(kind) {
  return COMPENSATOR_NAME[kind] ? `${COMPENSATOR_NAME[kind]} (${kind})` : kind;
}

// ---- small helpers --------------------------------------------------------------------

/** Calls fn at most once per `ms`, the last call winning. */
export function debounce(fn, ms) {
  let t = null;
  return (...args) => {
    clearTimeout(t);
    t = setTimeout(() => fn(...args), ms);
  };
}

/**
 * Makes `tbody` hold one <tr> per item, in order, keyed by `key(item)`. A row whose
 * signature `sig(item)` is unchanged is left alone (same element, inputs, focus); a changed
 * row gets new attributes (`attrs(item)`) and cells (`cells(item)`), keeping what was typed
 * into its inputs marked `data-keep`. `empty()` gives the row shown when there is no item.
 */
export function syncRows(tbody, items, { key, sig, attrs, cells, empty }) {
  const old = new Map();
  for (const tr of [...tbody.rows]) {
    if (tr.dataset.rowKey !== undefined) old.set(tr.dataset.rowKey, tr);
    else tr.remove();
  }
  if (!items.length) {
    for (const tr of old.values()) tr.remove();
    if (empty) tbody.append(empty());
    return;
  }
  let prev = null;
  for (const it of items) {
    const k = String(key(it));
    const sg = sig(it);
    let tr = old.get(k);
    if (tr) old.delete(k);
    else {
      tr = document.createElement('tr');
      tr.dataset.rowKey = k;
    }
    if (tr.rowSig !== sg) {
      const kept = new Map();
      for (const n of tr.querySelectorAll('[data-keep]')) kept.set(n.dataset.keep, n.value);
      const active = document.activeElement;
      const focusKey = active && tr.contains(active) ? active.dataset.keep : undefined;
      for (const a of [...tr.attributes]) if (a.name !== 'data-row-key') tr.removeAttribute(a.name);
      for (const [n, v] of Object.entries(attrs(it))) {
        if (v !== null && v !== undefined && v !== false) tr.setAttribute(n, v === true ? '' : String(v));
      }
      tr.replaceChildren(...cells(it).filter((c) => c !== null && c !== undefined));
      for (const n of tr.querySelectorAll('[data-keep]')) {
        if (kept.has(n.dataset.keep)) n.value = kept.get(n.dataset.keep);
        if (focusKey !== undefined && n.dataset.keep === focusKey) n.focus();
      }
      tr.rowSig = sg;
    }
    const want = prev ? prev.nextSibling : tbody.firstChild;
    if (want !== tr) tbody.insertBefore(tr, want);
    prev = tr;
  }
  for (const tr of old.values()) tr.remove();
}
