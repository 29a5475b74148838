// The monitor's live feed: the /api/live WebSocket (reconnecting with a growing delay), the
// live samples it brings kept per trial for the strip charts and the running estimates,
// and the E-stop latch (read from GET /api/controller when the feed connects, then from its
// `estop` messages: Start stays disabled while it is latched). Apart because it is the one
// source of live news; the monitor says what to do with it (`listen`), so this module
// knows nothing of the panels.

import { wsUrl } from './common.js';
import { emit, get } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

/** Seconds of samples kept per trial: a little more than the charts' 10 s window. */
const KEEP_S = 12;

/** Live samples per trial id: {samples, n, sumE2, sumA2, lastT, seenAt}. */
export const live = new Map();

let wanted = false;
let socket = null;
let socketRetry = null;
let socketDelay = 1000;
/** The E-stop latch: from GET /api/controller when the feed connects, then its `estop` messages. */
export let estopLatched = false;
/** What the monitor does on the feed's news: {connected(), trialChanged(trialId), latchChanged()}. */
let listener = null;

/** Set once, before the feed is opened. */
export function listen(l) {
  listener = l;
}

export function open() {
  wanted = true;
  connect();
}

export function close() {
  wanted = false;
  clearTimeout(socketRetry);
  if (socket) {
    socket.onclose = null;
    socket.close();
    socket = null;
  }
  showLive('unknown', 'Live feed: off');
}

function showLive(kind, text) {
  const pill = $('live-state');
  pill.classList.remove('ok', 'bad', 'unknown');
  pill.classList.add(kind);
  pill.textContent = text;
}

function connect() {
  if (!wanted || socket) return;
  showLive('unknown', 'Live feed: connecting…');
  let ws;
  try {
    ws = new WebSocket(wsUrl('/api/live'));
  } catch (e) {
    showLive('bad', `Live feed: ${e.message}`);
    return;
  }
  socket = ws;
  ws.onopen = () => {
    socketDelay = 1000;
    showLive('ok', 'Live feed: connected');
    readLatch();
    listener.connected();
  };
  ws.onmessage = (ev) => {
    let m;
    try {
      m = JSON.parse(ev.data);
    } catch {
      return;
    }
    if (m.type === 'live' && m.sample) addSample(m.sample);
    else if (m.type === 'trial') listener.trialChanged(m.trial_id);
    else if (m.type === 'controller') {
      emit('live-controller', !!m.connected);
      readLatch();
    } else if (m.type === 'estop') {
      setLatch(!!m.latched);
      emit('live-estop', !!m.latched);
    }
  };
  ws.onclose = () => {
    socket = null;
    if (!wanted) return;
    const s = Math.round(socketDelay / 1000);
    showLive('bad', `Live feed: disconnected — retrying in ${s} s`);
    socketRetry = setTimeout(connect, socketDelay);
    socketDelay = Math.min(socketDelay * 2, 15000);
  };
}

/** The latch as the server holds it now (missed while the feed was down). */
async function readLatch() {
  const r = await get('/api/controller');
  if (r.ok && r.data) setLatch(!!r.data.estop_latched);
}

function setLatch(latched) {
  if (latched === estopLatched) return;
  estopLatched = latched;
  listener.latchChanged();
}

function addSample(s) {
  let b = live.get(s.trial_id);
  if (!b) {
    b = { samples: [], n: 0, sumE2: 0, sumA2: 0, lastT: 0, seenAt: 0 };
    live.set(s.trial_id, b);
    // Forget old trials.
    for (const [id, o] of live) {
      if (performance.now() - o.seenAt > 300000 && id !== s.trial_id) live.delete(id);
    }
  }
  const e = s.target_mm - s.cylinder_mm;
  b.n += 1;
  b.sumE2 += e * e;
  b.sumA2 += s.cab_accel_mm_s2 * s.cab_accel_mm_s2;
  b.lastT = Math.max(b.lastT, s.t);
  b.seenAt = performance.now();
  b.samples.push(s);
  if (b.samples.length > 4000 || b.samples[0].t < b.lastT - KEEP_S - 2) {
    const cut = b.lastT - KEEP_S;
    let i = 0;
    while (i < b.samples.length && b.samples[i].t < cut) i++;
    b.samples.splice(0, i);
  }
  b.dirty = true;
}
