// Accounts (admins only; the server refuses everyone else): create an account with a role
// and, on a server of several sites, the sites whose machines it may drive; change a role or
// the sites, disable or enable an account. Also what each role may see: the dashboard
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

/** The server's site names (GET /api/controller). */
function siteNames() {
  return S.sites.map((x) => x.site);
}

/** A tick box per site, named `name`, ticked for `chosen` (null: none ticked, every site). */
function siteBoxes(name, chosen, label) {
  return siteNames().map((site) =>
    el(
      'label',
      { class: 'nowrap' },
      el('input', { type: 'checkbox', 'data-site-of': name, value: site, checked: !!(chosen && chosen.includes(site)), 'aria-label': `${label}: ${site}` }),
      ` ${site}`,
    ),
  );
}

/** The ticked sites of the boxes named `name` within `root`: null when none (every site). */
function tickedSites(root, name) {
  const ticked = [...root.querySelectorAll(`input[data-site-of="${name}"]:checked`)].map((b) => b.value);
  return ticked.length ? ticked : null;
}

function sitesText(sites) {
  return sites ? sites.join(', ') : 'every site';
}

/** The form's site choice, shown only when the server serves several sites; the table's
 *  site column follows. */
export function showSites() {
  const box = $('account-sites');
  const names = siteNames();
  const have = [...box.querySelectorAll('input')].map((b) => b.value);
  if (have.join() !== names.join()) {
    box.replaceChildren(box.querySelector('legend'), ...siteBoxes('new', null, 'New account may drive'));
    if (S.role === 'admin') render();
  }
  box.hidden = names.length < 2;
}

function render() {
  const several = siteNames().length > 1;
  syncRows($('accounts').tBodies[0], accounts, {
    key: (a) => a.id,
    sig: (a) => JSON.stringify([a, S.user, siteNames()]),
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
      el(
        'td',
        { 'data-sites-of': a.id },
        several
          ? [
              ...siteBoxes(a.id, a.sites, `Sites of ${a.username}`),
              a.sites ? '' : el('span', { class: 'muted small' }, ' (every site)'),
              el('button', { type: 'button', class: 'small', 'data-action': 'sites', 'data-account-id': a.id, title: 'None ticked: every site' }, 'Set sites'),
            ]
          : sitesText(a.sites),
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
    empty: () => el('tr', {}, el('td', { colspan: 7, class: 'muted' }, 'No account.')),
  });
}

async function create(ev) {
  ev.preventDefault();
  const username = $('account-username').value.trim();
  const password = $('account-password').value;
  const role = $('account-role').value;
  const body = { username, password, role };
  if (!$('account-sites').hidden) body.sites = tickedSites($('account-sites'), 'new');
  const r = await act(`Create account ${username}`, $('account-status'), () => post('/api/accounts', body), (a) =>
    `${a.username} created (${ROLE_TEXT[a.role]}; ${sitesText(a.sites)})`,
  );
  if (r.ok) {
    $('account-username').value = '';
    $('account-password').value = '';
    for (const b of $('account-sites').querySelectorAll('input')) b.checked = false;
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
  } else if (btn.dataset.action === 'sites') {
    const sites = tickedSites($('accounts').querySelector(`td[data-sites-of="${id}"]`), id);
    await act(`Sites of ${a.username}`, status, () => post(`/api/accounts/${id}/sites`, { sites }), (x) => `${x.username} may drive: ${sitesText(x.sites)}`);
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
