// The station's connection to the server: its token and pairing, polling its state, and the
// socket (live samples, changes and the E-stop latch in; operator input and the display's
// health out, sent by station-input.js and station-timing.js). Apart because it is the one
// place that knows whether the station is paired, reachable and still the active page; the
// rest of the page only shows what it hands over.

import { api, wsUrl } from './common.js';
import { describe, setError } from './station-errors.js';
import { show, showSection, state } from './station-phases.js';
import { onSample } from './station-pursuit.js';

const TOKEN_KEY = 'bdft-station-token';
const CODE_KEY = 'bdft-station-code';
const CODE_AT_KEY = 'bdft-station-code-at';
const PAIRED_KEY = 'bdft-station-paired';
/** The server forgets an unused pairing code after an hour; ask for a new one a bit sooner. */
const CODE_LIFETIME_MS = 55 * 60 * 1000;
const POLL_MS = 1000;
/** After a failed registration, ask again this much later (not every poll). */
const REGISTER_RETRY_MS = 10000;
/** Close codes of the station socket (protocol: server_to_browser::station_close). */
const CLOSE_REPLACED = 4001;
const CLOSE_FLOOD = 1008;

const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------------------------------
// One tab per browser.

/** The name of the lock (and channel) a station's tab holds while it is open. */
const TAB_LOCK = 'bdft-station-tab';

/**
 * Runs `start` in the one tab of this browser that is the station. A station is one
 * computer in front of one subject, and every tab of a browser shares its pairing
 * (localStorage): a second tab would feed the same subject's test. So a second tab is
 * refused, saying so, and becomes the station only once the first is closed. The tab holds
 * a Web Lock, which the browser frees when the tab goes; where there are none (a page
 * served over plain HTTP to another computer is not a secure context), the tabs ask each
 * other over a BroadcastChannel.
 */
export function claimTab(start) {
  if (navigator.locks) {
    navigator.locks.request(TAB_LOCK, { ifAvailable: true }, (lock) => {
      if (lock) return holdWhile(start);
      showSection('other-tab');
      // Queued: granted when the other tab closes.
      navigator.locks.request(TAB_LOCK, () => holdWhile(start));
      return null;
    });
    return;
  }
  const channel = new BroadcastChannel(TAB_LOCK);
  let mine = false;
  channel.onmessage = (ev) => {
    if (ev.data === 'who' && mine) channel.postMessage('here');
    else if (ev.data === 'here' && !mine) showSection('other-tab');
  };
  channel.postMessage('who');
  // An open station answers at once; a tab that heard nothing within a second is the one.
  setTimeout(() => {
    if (document.body.dataset.phase === 'other-tab') return;
    mine = true;
    start();
  }, 1000);
}

/** Starts the station and holds the tab's lock for as long as the page lives. */
function holdWhile(start) {
  start();
  return new Promise(() => {});
}

// ---------------------------------------------------------------------------------------
// Token and pairing.

export let token = localStorage.getItem(TOKEN_KEY);
let registering = false;
let registerAgainAt = 0;
/** Waiting to be paired: the state is not polled (it would answer 401 every second). */
let unpaired = false;

async function register() {
  if (registering || Date.now() < registerAgainAt) return;
  registering = true;
  try {
    const res = await api('POST', '/api/station/register', {});
    if (!res.ok || !res.data || !res.data.token) {
      registerAgainAt = Date.now() + REGISTER_RETRY_MS;
      setError('register', `Could not get a pairing code: ${describe(res)}`);
      return;
    }
    setError('register', null);
    token = res.data.token;
    localStorage.setItem(TOKEN_KEY, token);
    localStorage.setItem(CODE_KEY, res.data.pairing_code);
    localStorage.setItem(CODE_AT_KEY, String(Date.now()));
    localStorage.removeItem(PAIRED_KEY);
    showUnpaired();
  } finally {
    registering = false;
  }
}

/** The code the experimenter types to pair this station, as the server last gave it. */
export function showPairingCode() {
  $('pairing-code').textContent = localStorage.getItem(CODE_KEY) || '';
}

function showUnpaired() {
  closeSocket();
  unpaired = true;
  showPairingCode();
  show({ phase: 'unpaired' });
  waitForPairing();
}

let pairingWait = 0;

/**
 * Waits for the experimenter to pair this station: the server answers as soon as it is
 * paired (or "not yet" after 25 s: ask again), 404 when the code expired (register again).
 * A newer wait (a new code) ends the older.
 */
async function waitForPairing() {
  const mine = ++pairingWait;
  const asked = token;
  while (mine === pairingWait) {
    const res = await api('POST', '/api/station/pairing', { token: asked });
    if (mine !== pairingWait) return;
    if (res.ok && res.data && res.data.paired) {
      setError('pairing', null);
      pairingWait++;
      unpaired = false;
      refresh();
      return;
    }
    if (res.ok) {
      setError('pairing', null);
      continue;
    }
    if (res.status === 404) {
      pairingWait++;
      register();
      return;
    }
    setError('pairing', `Waiting for the pairing failed: ${describe(res)}`);
    await new Promise((r) => setTimeout(r, REGISTER_RETRY_MS));
  }
}

/** 401 from the state: not paired (yet), or no longer (the station was removed). */
export function onUnauthorized() {
  const code = localStorage.getItem(CODE_KEY);
  const at = Number(localStorage.getItem(CODE_AT_KEY) || 0);
  const revoked = localStorage.getItem(PAIRED_KEY) === '1';
  const stale = at > 0 && Date.now() - at > CODE_LIFETIME_MS;
  if (!token || !code || revoked || stale) {
    register();
    return;
  }
  showUnpaired();
}

/** "Show a new code": forget the token and its code, and register again. */
export function newCode() {
  localStorage.removeItem(CODE_KEY);
  token = null;
  localStorage.removeItem(TOKEN_KEY);
  register();
}

// ---------------------------------------------------------------------------------------
// State polling.

let inflight = false;
let again = false;
let pollTimer = null;

export async function refresh() {
  if (replaced) return;
  if (inflight) {
    again = true;
    return;
  }
  inflight = true;
  clearTimeout(pollTimer);
  try {
    if (!token) {
      await register();
      return;
    }
    if (unpaired) return;
    const res = await api('GET', '/api/station/state', undefined, { bearer: token });
    if (res.status === 401) {
      setError('poll', null);
      onUnauthorized();
      return;
    }
    if (!res.ok) {
      setError('poll', describe(res));
      return;
    }
    setError('poll', null);
    setError('register', null);
    unpaired = false;
    localStorage.setItem(PAIRED_KEY, '1');
    ensureSocket();
    show(res.data);
  } finally {
    inflight = false;
    if (again) {
      again = false;
      refresh();
    } else if (!unpaired && !replaced) {
      pollTimer = setTimeout(refresh, POLL_MS);
    }
  }
}

// ---------------------------------------------------------------------------------------
// The socket: live samples, changes and the E-stop latch in, operator input out.

export let socket = null;
let socketWanted = false;
let reconnectTimer = null;
/** The E-stop latch as the socket last said (it says so when it opens and on changes). */
export let latched = false;
/** Another page of this station took over the socket: this one stays inactive. */
export let replaced = false;

function ensureSocket() {
  socketWanted = true;
  if (socket || reconnectTimer) return;
  const ws = new WebSocket(wsUrl('/api/station/ws?token=' + encodeURIComponent(token)));
  socket = ws;
  ws.addEventListener('open', () => {
    setError('socket', null);
  });
  ws.addEventListener('message', (ev) => {
    let msg;
    try {
      msg = JSON.parse(ev.data);
    } catch {
      return;
    }
    if (msg.type === 'changed') refresh();
    else if (msg.type === 'live' && msg.sample) onSample(msg.sample);
    else if (msg.type === 'estop') onLatch(!!msg.latched);
  });
  ws.addEventListener('close', (ev) => {
    if (socket !== ws) return;
    socket = null;
    if (!socketWanted) return;
    if (ev.code === CLOSE_REPLACED) {
      // Reconnecting would take the station back from the other page, and it would do
      // the same: the two would take turns feeding the test.
      replaced = true;
      socketWanted = false;
      clearTimeout(pollTimer);
      setError('socket', null);
      if (state) show(state);
      return;
    }
    if (state && (state.phase === 'ready' || state.phase === 'running')) {
      setError('socket', 'The connection to the server was interrupted; reconnecting…');
    }
    reconnectTimer = setTimeout(() => {
      reconnectTimer = null;
      if (socketWanted) ensureSocket();
    }, ev.code === CLOSE_FLOOD ? 5 * 1000 : 1000);
  });
}

/** The E-stop was pressed or reset: "Stopped" at once, or back to what the state says. */
function onLatch(now) {
  if (now === latched) return;
  latched = now;
  if (state) show(state);
  if (!now) refresh();
}

function closeSocket() {
  socketWanted = false;
  latched = false;
  clearTimeout(reconnectTimer);
  reconnectTimer = null;
  if (socket) {
    const ws = socket;
    socket = null;
    ws.close();
  }
  setError('socket', null);
}
