// The subject's own page (/subject?token=…): their progress, blinded (tests done of how
// many, the labels "Controller k" they saw, never a compensator's name or a metric), their
// consent, and withdrawal with a confirmation step.

import { api, el } from './common.js';

const $ = (id) => document.getElementById(id);

// The token is taken out of the address at once, so it is not left in the browser's
// history or shown to someone looking over a shoulder. It is kept in this tab's session
// storage only, so that reloading the page works; closing the tab forgets it.
const KEY = 'bdft-subject-token';
const fromLink = new URLSearchParams(location.search).get('token');
if (fromLink) {
  sessionStorage.setItem(KEY, fromLink);
  history.replaceState(null, '', location.pathname);
}
const token = sessionStorage.getItem(KEY);

const STATUS = {
  scheduled: 'not yet',
  running: 'running now',
  complete: 'done',
  aborted: 'stopped',
  incomplete: 'not completed',
};
const SEAT = { on: 'on the machine', off: 'at the desk' };
const CONSENT = {
  agreed: 'You agreed to take part.',
  declined: 'You declined to take part.',
};

function show(id) {
  for (const s of document.querySelectorAll('main > section')) s.hidden = s.id !== id;
}

function error(text) {
  $('error').hidden = !text;
  $('error-text').textContent = text || '';
}

function render(p) {
  $('code').textContent = p.code;
  $('consent').textContent = CONSENT[p.consent] || 'You have not yet answered the consent form (the station shows it).';
  $('done').textContent = `${p.tests_complete} of ${p.tests_total} tests done`;
  $('done-bar').max = p.tests_total || 1;
  $('done-bar').value = p.tests_complete;
  $('tests').replaceChildren(
    ...p.tests.map((t) =>
      el('li', { class: t.status }, `${t.label}, ${SEAT[t.station] || t.station}: ${STATUS[t.status] || t.status}`),
    ),
  );
  $('withdraw-box').hidden = p.withdrawn;
  $('withdrawn').hidden = !p.withdrawn;
  show('progress');
}

async function load() {
  const r = await api('GET', '/api/subject', undefined, { bearer: token });
  if (r.ok) {
    error('');
    render(r.data);
  } else if (r.status === 401) {
    show('no-token');
  } else {
    error(`Could not load your progress: ${(r.data && r.data.error) || `HTTP ${r.status}`}. It will be tried again.`);
  }
}

function askToConfirm(open) {
  $('withdraw').hidden = open;
  $('withdraw-confirm').hidden = !open;
  if (open) $('withdraw-reason').focus();
  else $('withdraw').focus();
}

async function withdraw(ev) {
  ev.preventDefault();
  $('withdraw-yes').disabled = true;
  const reason = $('withdraw-reason').value.trim();
  const r = await api('POST', '/api/subject/withdraw', reason ? { reason } : {}, { bearer: token });
  $('withdraw-yes').disabled = false;
  if (r.ok) {
    error('');
    render(r.data);
  } else if (r.status === 409) {
    // Withdrawn already (e.g. by the experimenter): show it.
    await load();
  } else {
    error(`The withdrawal did not go through: ${(r.data && r.data.error) || `HTTP ${r.status}`}. Please try again or tell the experimenter.`);
  }
}

if (!token) {
  show('no-token');
} else {
  $('withdraw').addEventListener('click', () => askToConfirm(true));
  $('withdraw-no').addEventListener('click', () => askToConfirm(false));
  $('withdraw-confirm').addEventListener('submit', withdraw);
  load();
  // Progress changes while the experimenter runs the tests.
  setInterval(load, 5000);
}
