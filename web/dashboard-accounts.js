// Accounts (admins only; the server refuses everyone else): create an account with a role,
// change a role, disable or enable an account. Also what each role may see: the dashboard
// hides what the logged-in role may not do (the server enforces it either way).

import { S, act, el, get, post, setStatus, syncRows, when } from './dashboard-core.js';
import { confirmAction } from './dashboard-confirm.js';

const $ = (id) => document.getElementById(id);

const ROLE_TEXT = {
  admin: 'admin (manages accounts)',
  experimenter: 'experimenter',
  analyst: 'analyst (read-only)',
};

/** Whether the logged-in role may do what `needs` names: `change` or `admin`. */
function allowed(needs) {
  if (needs === 'admin') return S.role === 'admin';
  if (needs === 'change') return S.role === 'admin' || S.role === 'experimenter';
  return true;
}

/** Shows or hides every element marked `data-needs` for the logged-in role. */
export function applyRole(role) {
  S.role = role;
  document.body.dataset.role = role || '';
  for (const node of document.querySelectorAll('[data-needs]')) node.hidden = !allowed(node.dataset.needs);
  if (role === 'admin') refresh();
}

export function mayChange() {
  return allowed('change');
}

export function init() {
  $('account-form').addEventListener('submit', create);
  $('accounts').addEventListener('click', onClick);
}

let accounts = [];

export async function refresh() {
  if (S.role !== 'admin') return;
  const r = await get('/api/accounts');
  if (!r.ok) {
    setStatus($('account-status'), 'err', `Could not load the accounts: ${(r.data && r.data.error) || r.status}`);
    return;
  }
  accounts = r.data;
  render();
}

function render() {
  syncRows($('accounts').tBodies[0], accounts, {
    key: (a) => a.id,
    sig: (a) => JSON.stringify([a, S.user]),
    attrs: (a) => ({ 'data-account-id': a.id, class: a.disabled_at ? 'withdrawn' : '' }),
    cells: (a) => [
      el('td', { class: 'num' }, a.id),
      el('td', {}, a.username, a.username === S.user ? el('span', { class: 'muted' }, ' (you)') : ''),
      el(
        'td',
        {},
        el(
          'select',
          { 'data-role-of': a.id, 'aria-label': `Role of ${a.username}` },
          ...Object.entries(ROLE_TEXT).map(([value, text]) => el('option', { value, selected: a.role === value }, text)),
        ),
        el('button', { type: 'button', class: 'small', 'data-action': 'role', 'data-account-id': a.id }, 'Change role'),
      ),
      el('td', {}, a.disabled_at ? `disabled ${when(Date.parse(a.disabled_at))}` : 'active'),
      el('td', { class: 'nowrap' }, when(Date.parse(a.created_at))),
      el(
        'td',
        { class: 'actions' },
        a.disabled_at
          ? el('button', { type: 'button', class: 'small', 'data-action': 'enable', 'data-account-id': a.id }, 'Enable')
          : el('button', { type: 'button', class: 'small danger-outline', 'data-action': 'disable', 'data-account-id': a.id }, 'Disable…'),
      ),
    ],
    empty: () => el('tr', {}, el('td', { colspan: 6, class: 'muted' }, 'No account.')),
  });
}

async function create(ev) {
  ev.preventDefault();
  const username = $('account-username').value.trim();
  const password = $('account-password').value;
  const role = $('account-role').value;
  const r = await act(`Create account ${username}`, $('account-status'), () => post('/api/accounts', { username, password, role }), (a) =>
    `${a.username} created (${ROLE_TEXT[a.role]})`,
  );
  if (r.ok) {
    $('account-username').value = '';
    $('account-password').value = '';
    await refresh();
  }
}

async function onClick(e) {
  const btn = e.target.closest('button[data-action][data-account-id]');
  if (!btn) return;
  const id = Number(btn.dataset.accountId);
  const a = accounts.find((x) => x.id === id);
  if (!a) return;
  const status = $('account-status');
  if (btn.dataset.action === 'role') {
    const role = $('accounts').querySelector(`select[data-role-of="${id}"]`).value;
    await act(`Role of ${a.username}`, status, () => post(`/api/accounts/${id}/role`, { role }), (x) => `${x.username} is now ${ROLE_TEXT[x.role]}`);
  } else if (btn.dataset.action === 'disable') {
    const yes = await confirmAction({
      title: `Disable the account ${a.username}?`,
      text: `${a.username} is logged out at once and cannot log in until an admin enables the account again. The account stays in the audit log.`,
      ok: `Disable ${a.username}`,
    });
    if (!yes) return;
    await act(`Disable ${a.username}`, status, () => post(`/api/accounts/${id}/disable`), (x) => `${x.username} disabled`);
  } else if (btn.dataset.action === 'enable') {
    await act(`Enable ${a.username}`, status, () => post(`/api/accounts/${id}/enable`), (x) => `${x.username} enabled`);
  }
  await refresh();
}
