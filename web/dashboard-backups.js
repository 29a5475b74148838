// Backups (admins only; the server refuses everyone else): the backup directory, its
// schedule, the backups it holds with their manifests, and "Back up now".

import { S, act, el, get, post, setStatus, syncRows, when } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

export function init() {
  $('backup-now').addEventListener('click', backUpNow);
  $('backups-refresh').addEventListener('click', refresh);
}

/** A size in bytes as people read it. */
function size(bytes) {
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 * 1024) return `${(bytes / 1024).toFixed(1)} KiB`;
  return `${(bytes / 1024 / 1024).toFixed(1)} MiB`;
}

/** A period in seconds as the server's flag takes it. */
function period(s) {
  for (const [unit, n] of [['d', 86400], ['h', 3600], ['m', 60]]) if (s % n === 0) return `${s / n}${unit}`;
  return `${s}s`;
}

export async function refresh() {
  if (S.role !== 'admin') return;
  const r = await get('/api/backups');
  if (!r.ok) {
    setStatus($('backups-status'), 'err', `Could not load the backups: ${(r.data && r.data.error) || r.status}`);
    return;
  }
  const v = r.data;
  $('backups-policy').textContent = v.dir
    ? `Into ${v.dir}, every ${period(v.every_s)}, the newest ${v.keep} kept` +
      (v.next_at ? `; next ${when(Date.parse(v.next_at))}` : '') +
      (v.running ? ' — a backup is being made now' : '')
    : 'Backups are off: start the server with --backup-dir DIR (or BDFT_BACKUP_DIR).';
  $('backup-now').disabled = !v.dir || v.running;
  syncRows($('backups').tBodies[0], v.backups, {
    key: (m) => m.file,
    sig: (m) => JSON.stringify(m),
    attrs: () => ({}),
    cells: (m) => [
      el('td', { class: 'nowrap' }, when(Date.parse(m.created_at))),
      el('td', {}, m.file),
      el('td', { class: 'num' }, size(m.bytes)),
      el('td', { class: 'num' }, `${m.row_counts.trials ?? 0} / ${m.row_counts.trial_records ?? 0}`),
      el('td', {}, `${String(m.schema_version).padStart(4, '0')} ${m.schema_migration}`, el('br'), el('span', { class: 'muted small' }, `bdft-server ${m.program_version}`)),
      el('td', {}, m.made_by),
      el('td', { class: 'hash small', title: m.sha256 }, m.sha256.slice(0, 16) + '…'),
      el('td', { class: 'num' }, `${m.took_ms} ms`),
      el('td', {}, el('details', {}, el('summary', {}, 'manifest'), el('pre', { class: 'small' }, JSON.stringify(m, null, 2)))),
    ],
    empty: () => el('tr', {}, el('td', { colspan: 9, class: 'muted' }, v.dir ? 'No backup yet.' : 'Backups are off.')),
  });
}

async function backUpNow() {
  $('backup-now').disabled = true;
  await act('Back up now', $('backups-status'), () => post('/api/backups'), (m) => `${m.file}, ${size(m.bytes)}, checked, in ${m.took_ms} ms`);
  await refresh();
}
