// The one-time set-up page (/setup?token=…): creates the first experimenter account, which
// also logs in, then opens the dashboard.

import { api } from './common.js';

const $ = (id) => document.getElementById(id);

function say(node, kind, text) {
  node.className = `status ${kind}`;
  node.textContent = text;
  node.hidden = !text;
}

const token = new URLSearchParams(location.search).get('token') || '';

async function check() {
  if (!token) {
    say($('setup-state'), 'err', 'This page needs the set-up link the server printed at its start (…/setup?token=…); a link is valid for an hour, and only the last one printed works.');
  }
  const r = await api('GET', '/api/setup');
  if (r.ok && r.data && r.data.needs_setup === false) {
    say($('setup-state'), 'info', 'Set-up is already done: an experimenter account exists. ');
    const a = document.createElement('a');
    a.href = '/';
    a.textContent = 'Go to the log-in page.';
    $('setup-state').append(a);
  }
}

async function submit(ev) {
  ev.preventDefault();
  const username = $('setup-username').value.trim();
  const password = $('setup-password').value;
  if (!token) {
    say($('setup-error'), 'err', 'The set-up token is missing from the address: open the exact link the server printed.');
    return;
  }
  if (!/^[A-Za-z0-9._-]{3,40}$/.test(username)) {
    say($('setup-error'), 'err', 'Username: 3 to 40 letters, digits, “.”, “_” or “-”.');
    return;
  }
  if ([...password].length < 10) {
    say($('setup-error'), 'err', 'Password: at least 10 characters.');
    return;
  }
  $('setup-submit').disabled = true;
  say($('setup-error'), 'busy', 'Creating the account…');
  const r = await api('POST', '/api/setup', { token, username, password });
  if (r.ok) {
    say($('setup-error'), 'ok', 'Account created. Opening the dashboard…');
    // The answer set the session cookie; the dashboard reads the CSRF token from /api/me.
    location.replace('/');
    return;
  }
  say($('setup-error'), 'err', (r.data && r.data.error) || `Set-up failed (HTTP ${r.status})`);
  if (r.status === 409) {
    // An account exists (made with this link, or another): set-up cannot be done again.
    const a = document.createElement('a');
    a.href = '/';
    a.textContent = ' Go to the log-in page.';
    $('setup-error').append(a);
    return;
  }
  $('setup-submit').disabled = false;
}

$('setup-form').addEventListener('submit', submit);
$('setup-show').addEventListener('change', () => {
  $('setup-password').type = $('setup-show').checked ? 'text' : 'password';
});
check();
