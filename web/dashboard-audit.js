// The audit log (GET /api/audit): every change anyone made, newest first.

import { debounce, el, errText, get, on, setStatus, when } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

let rows = [];
let lastJson = '';

export function init() {
  $('audit-refresh').addEventListener('click', () => refresh(true));
  $('audit-limit').addEventListener('change', () => refresh(true));
  $('audit-filter').addEventListener('input', debounce(render, 150));
  $('audit-verify').addEventListener('click', verify);
  on('action', debounce(() => refresh(false), 400));
  on('trial', debounce(() => refresh(false), 1500));
  refresh(true);
  verify();
}

// The chain's and the checkpoints' verdict, in the words `bdft-server audit verify` prints.
async function verify() {
  const out = $('audit-verdict');
  setStatus(out, 'busy', 'Verifying…');
  const r = await get('/api/audit/verify');
  if (!r.ok) {
    setStatus(out, 'err', `Could not verify the audit log: ${errText(r)}`);
    return;
  }
  setStatus(out, r.data.intact ? 'ok' : 'err', r.data.report);
  out.dataset.intact = String(r.data.intact);
}

export async function refresh(announce) {
  const limit = $('audit-limit').value;
  if (announce) setStatus($('audit-status'), 'busy', 'Loading…');
  const r = await get(`/api/audit?limit=${encodeURIComponent(limit)}`);
  if (!r.ok) {
    setStatus($('audit-status'), 'err', `Could not load the audit log: ${errText(r)}`);
    return;
  }
  const json = JSON.stringify(r.data);
  setStatus($('audit-status'), 'info', `${r.data.length} ${r.data.length === 1 ? 'entry' : 'entries'}, read ${when(Date.now())}`);
  if (json === lastJson) return;
  lastJson = json;
  rows = r.data;
  render();
}

function detailText(d) {
  if (d === null || d === undefined) return '';
  if (typeof d !== 'object') return String(d);
  return Object.entries(d)
    .map(([k, v]) => `${k}: ${typeof v === 'object' && v !== null ? JSON.stringify(v) : v}`)
    .join(' · ');
}

function render() {
  const q = $('audit-filter').value.trim().toLowerCase();
  const shown = q
    ? rows.filter((e) => `${e.actor} ${e.action} ${e.target || ''} ${JSON.stringify(e.detail)}`.toLowerCase().includes(q))
    : rows;
  const tbody = $('audit').tBodies[0];
  tbody.replaceChildren(
    ...shown.map((e) => {
      const detail = detailText(e.detail);
      const long = detail.length > 240;
      return el(
        'tr',
        { 'data-audit-id': e.id, class: `audit-${e.action.replace(/[^a-z0-9]+/gi, '-')}` },
        el('td', { class: 'num' }, e.id),
        el('td', { class: 'nowrap', title: e.at }, when(Date.parse(e.at))),
        el('td', { class: 'actor', title: e.actor_id ? `account #${e.actor_id}` : 'not a logged-in account' }, e.actor),
        el('td', { class: 'action' }, e.action),
        el('td', {}, e.target || ''),
        el(
          'td',
          { class: 'detail' },
          long
            ? el('details', {}, el('summary', {}, `${detail.slice(0, 160)}…`), el('pre', {}, JSON.stringify(e.detail, null, 2)))
            : detail,
        ),
      );
    }),
  );
  if (!shown.length) tbody.append(el('tr', {}, el('td', { colspan: 6, class: 'muted' }, q ? 'No entry matches the filter.' : 'No entry.')));
}
