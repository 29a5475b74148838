// The experimenter's dashboard: log-in, e-stop and controller link, then the views (study,
// subjects and schedules, stations, live monitor, results, audit log), each in its module.

import { api } from './common.js';
import { S, act, el, emit, get, on, onUnauthorized, post, setStatus, when } from './dashboard-core.js';
import * as study from './dashboard-study.js';
import * as subjects from './dashboard-subjects.js';
import * as stations from './dashboard-stations.js';
import * as monitor from './dashboard-monitor.js';
import * as results from './dashboard-results.js';
import * as workbench from './dashboard-workbench.js';
import * as conditions from './dashboard-conditions.js';
import * as audit from './dashboard-audit.js';
import * as pilot from './dashboard-pilot.js';
import * as plan from './dashboard-plan.js';
import * as calibrate from './dashboard-calibrate.js';
import * as accounts from './dashboard-accounts.js';
import * as backups from './dashboard-backups.js';
import * as configs from './dashboard-configs.js';
import * as bench from './dashboard-bench.js';
import * as protocol from './dashboard-protocol.js';
import * as erasure from './dashboard-erasure.js';

const $ = (id) => document.getElementById(id);

// ---- log-in / log-out ---------------------------------------------------------------------

/** The log-in form; `message` (not an error) says why it shows, e.g. an ended session. */
function showLogin(message) {
  S.loggedIn = false;
  S.csrf = null;
  stopAll();
  $('boot').hidden = true;
  $('app-view').hidden = true;
  $('login-view').hidden = false;
  setStatus($('login-error'), 'err', '');
  setStatus($('login-info'), 'info', message || '');
  $('login-password').value = '';
  $('login-username').focus();
  api('GET', '/api/setup').then((r) => {
    $('login-setup-hint').hidden = !(r.ok && r.data && r.data.needs_setup);
  });
}

let started = false;

async function showApp(me) {
  S.csrf = me.csrf;
  S.user = me.username;
  S.loggedIn = true;
  $('whoami').textContent = `logged in as ${me.username} (${me.role})`;
  if (!started) {
    started = true;
    study.init();
    subjects.init();
    stations.init();
    monitor.init();
    results.init();
    workbench.init();
    conditions.init();
    audit.init();
    pilot.init();
    plan.init();
    calibrate.init();
    accounts.init();
    backups.init();
    bench.init();
    configs.init();
    protocol.init();
    erasure.init();
  }
  accounts.applyRole(me.role);
  erasure.refresh();
  backups.refresh();
  // The page shows once the study list and the form are filled, so that nothing typed
  // into it is overwritten by data still on its way.
  await study.loadStudies();
  $('boot').hidden = true;
  $('login-view').hidden = true;
  $('app-view').hidden = false;
  startAll();
}

async function login(ev) {
  ev.preventDefault();
  const username = $('login-username').value.trim();
  const password = $('login-password').value;
  if (!username || !password) {
    setStatus($('login-error'), 'err', 'Type your username and password.');
    return;
  }
  $('login-submit').disabled = true;
  setStatus($('login-error'), 'err', '');
  setStatus($('login-info'), 'busy', 'Logging in…');
  const r = await api('POST', '/api/login', { username, password });
  $('login-submit').disabled = false;
  setStatus($('login-info'), 'info', '');
  if (!r.ok) {
    const msg =
      r.status === 429
        ? 'Too many failed attempts: wait a minute and try again.'
        : (r.data && r.data.error) || `Log-in failed (HTTP ${r.status})`;
    setStatus($('login-error'), 'err', msg);
    return;
  }
  setStatus($('login-info'), 'busy', 'Loading the dashboard…');
  // The login answer carries {username, csrf}; keep the token in memory only.
  await showApp({ username: r.data.username || username, csrf: r.data.csrf, role: r.data.role });
}

async function logout() {
  const r = await post('/api/logout');
  if (!r.ok && r.status !== 401) {
    setStatus($('estop-status'), 'err', `Log-out failed: ${(r.data && r.data.error) || r.status}`);
    return;
  }
  showLogin('Logged out.');
}

// ---- e-stop and the controller link ------------------------------------------------------

async function estop() {
  // Nothing before the request: the stop must go out at once.
  const r = await act('E-STOP', $('estop-status'), () => post('/api/estop'), () =>
    'sent — the controller latched every valve to zero',
  );
  if (!r.ok) $('estop-status').textContent += ' — USE THE HARDWARE STOP';
  refreshEstopHistory();
}

async function estopReset() {
  await act('E-stop reset', $('estop-status'), () => post('/api/estop/reset'), () => 'latch cleared');
  refreshEstopHistory();
}

/** One site's e-stop or its reset (`?site=`), from the site list's buttons. */
async function siteAction(action, site) {
  const q = `?site=${encodeURIComponent(site)}`;
  if (action === 'stop') {
    const r = await act(`E-STOP ${site}`, $('estop-status'), () => post(`/api/estop${q}`), () =>
      `sent — the controller of ${site} latched every valve to zero`,
    );
    if (!r.ok) $('estop-status').textContent += ' — USE THE HARDWARE STOP';
  } else {
    await act(`E-stop reset ${site}`, $('estop-status'), () => post(`/api/estop/reset${q}`), () => `latch of ${site} cleared`);
  }
  refreshController();
  refreshEstopHistory();
}

/** Each site's link and latch with its own stop and reset, when the server serves several. */
function showSites() {
  const list = $('estop-sites');
  list.hidden = S.sites.length < 2;
  const rows = list.hidden ? [] : S.sites;
  const shown = JSON.stringify(rows.map((x) => [x.site, x.connected, x.estop_latched]));
  // Rebuilt only when something changed, so a button is not replaced under the pointer.
  if (list.dataset.shown === shown) return;
  list.dataset.shown = shown;
  list.replaceChildren(
    ...rows.map((x) =>
      el(
        'li',
        { class: x.estop_latched ? 'alarm' : '', dataset: { site: x.site } },
        `${x.site}: ${x.connected ? 'connected' : 'NOT CONNECTED'}${x.estop_latched ? ', LATCHED' : ''}`,
        el('button', { type: 'button', class: 'estop-site', onclick: () => siteAction('stop', x.site) }, `Stop ${x.site}`),
        el('button', { type: 'button', onclick: () => siteAction('reset', x.site) }, `Reset ${x.site}`),
      ),
    ),
  );
}

/** The last e-stop and reset, from the audit log (the API reports no latch state). */
async function refreshEstopHistory() {
  const r = await get('/api/audit?limit=500');
  if (!r.ok || !Array.isArray(r.data)) return;
  const last = r.data.find((e) => e.action === 'estop');
  const reset = r.data.find((e) => e.action === 'estop.reset');
  const box = $('estop-last');
  if (!last) {
    box.textContent = 'No e-stop in the recent audit log.';
    box.classList.remove('alarm');
    return;
  }
  const stopAt = Date.parse(last.at);
  const resetAfter = reset && Date.parse(reset.at) >= stopAt;
  const delivered = last.detail && last.detail.delivered === false ? ' (NOT delivered)' : '';
  box.textContent =
    `Last e-stop ${when(stopAt)} by ${last.actor}${delivered}; ` +
    (resetAfter ? `reset ${when(Date.parse(reset.at))} by ${reset.actor}.` : 'not reset since.');
  box.classList.toggle('alarm', !resetAfter);
}

/** The controller's e-stop latch, as the server last heard it. */
function showLatch(latched) {
  const box = $('estop-latch');
  if (!box) return;
  // With several sites, which ones (as GET /api/controller last said).
  const at = S.sites.length > 1 ? S.sites.filter((x) => x.estop_latched).map((x) => x.site) : [];
  const where = at.length ? ` at ${at.join(', ')}` : '';
  box.textContent = latched ? `E-STOP LATCHED${where}: valves held at zero until reset.` : 'E-stop not latched.';
  box.classList.toggle('alarm', latched);
}

function showController() {
  const c = S.controller;
  const pill = $('controller-state');
  pill.classList.remove('ok', 'bad', 'unknown');
  // With several sites the light is each site's: the ones down are named.
  const several = S.sites.length > 1;
  const down = S.sites.filter((x) => !x.connected).map((x) => x.site);
  if (c.connected === true) {
    pill.classList.add('ok');
    pill.textContent = several
      ? `Controllers: ${S.sites.length} sites connected`
      : `Controller: connected${c.rig ? ` (rig ${c.rig})` : ''}`;
  } else if (c.connected === false) {
    pill.classList.add('bad');
    pill.textContent = several && down.length ? `Controller: NOT CONNECTED at ${down.join(', ')}` : 'Controller: NOT CONNECTED';
  } else {
    pill.classList.add('unknown');
    pill.textContent = 'Controller: unknown';
  }
  pill.title = `Link between the server and the real-time controller${c.pid ? `; controller pid ${c.pid}` : ''}`;
}

async function refreshController() {
  const r = await get('/api/controller');
  if (r.ok) {
    const was = S.controller.connected;
    S.controller = { connected: !!r.data.connected, pid: r.data.pid, rig: r.data.rig };
    S.sites = Array.isArray(r.data.sites) ? r.data.sites : [];
    stations.showSites();
    accounts.showSites();
    showSites();
    showController();
    showLatch(!!r.data.estop_latched);
    if (was !== S.controller.connected) emit('controller', S.controller);
  } else if (r.status !== 401) {
    S.controller = { connected: null, pid: null, rig: null };
    showController();
  }
}

// ---- background refreshing ---------------------------------------------------------------

let timers = [];

function every(ms, fn) {
  timers.push(setInterval(fn, ms));
}

function startAll() {
  stopAll();
  refreshController();
  refreshEstopHistory();
  every(5000, refreshController);
  every(10000, refreshEstopHistory);
  monitor.start();
  every(5000, () => subjects.refresh());
  every(5000, () => stations.refresh());
  every(10000, () => audit.refresh());
  every(15000, () => results.refresh(false));
}

function stopAll() {
  for (const t of timers) clearInterval(t);
  timers = [];
  monitor.stop();
}

// ---- start --------------------------------------------------------------------------------

on('controller', (c) => {
  if (c && typeof c.connected === 'boolean') {
    S.controller.connected = c.connected;
    showController();
  }
});
on('live-estop', (latched) => {
  showLatch(latched);
  refreshEstopHistory();
});
on('live-controller', (connected) => {
  S.controller.connected = connected;
  showController();
  refreshController();
});

async function boot() {
  $('login-form').addEventListener('submit', login);
  $('logout').addEventListener('click', logout);
  $('estop').addEventListener('click', estop);
  $('estop-reset').addEventListener('click', estopReset);
  onUnauthorized(() => showLogin('Your session has ended: log in again.'));
  const r = await api('GET', '/api/me');
  if (r.ok && r.data && r.data.csrf) await showApp(r.data);
  else if (r.status === 401 || r.status === 403) showLogin('');
  else {
    $('boot').textContent = `The server did not answer (${r.status ? `HTTP ${r.status}` : (r.data && r.data.error) || 'no connection'}). Reload to try again.`;
  }
}

boot();
