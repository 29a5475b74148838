// Erasure on request (admins only; the server refuses everyone else): erase a subject of the
// selected study after a confirmation, and the erasures so far with the backups that still
// hold each one's data.

import { S, act, el, emit, get, on, post, setStatus, syncRows, when } from './dashboard-core.js';
import { confirmAction } from './dashboard-confirm.js';

const $ = (id) => document.getElementById(id);

export function init() {
  $('erase-form').addEventListener('submit', erase);
  on('subjects', () => {
    fillSubjects();
    refresh();
  });
  on('study', fillSubjects);
}

/** The selected study's subjects whose data are still there. */
function fillSubjects() {
  const sel = $('erase-subject');
  const before = sel.value;
  const left = S.subjects.map((x) => x.subject).filter((s) => !s.erased_at);
  sel.replaceChildren(
    el('option', { value: '' }, left.length ? 'choose a subject' : 'no subject to erase'),
    ...left.map((s) => el('option', { value: s.id, selected: String(s.id) === before }, `${s.code}${s.withdrawn_at ? ' (withdrawn)' : ''}`)),
  );
}

/** Reloads the erasures (admins only). */
export async function refresh() {
  if (S.role !== 'admin') return;
  const r = await get('/api/erasures');
  if (!r.ok) {
    setStatus($('erase-status'), 'err', `Could not load the erasures: ${(r.data && r.data.error) || r.status}`);
    return;
  }
  render(r.data);
}

function backupsText(e, dir) {
  if (!dir) return el('span', { class: 'muted' }, 'no backup directory set (serve --backup-dir): not checked');
  if (!e.backups_holding_data.length) return el('span', { class: 'muted' }, 'none');
  return e.backups_holding_data.map((b) =>
    el('div', {}, b.backup, ' — ', b.created_at ? `made ${when(Date.parse(b.created_at))}` : `its manifest cannot be read (${b.problem}): it may hold the data`),
  );
}

function render(data) {
  $('erasure-backup-dir').textContent = data.backup_dir
    ? `Backups are looked for in ${data.backup_dir}: each one listed was copied before the erasure and still holds the data until it is deleted.`
    : 'No backup directory is set (serve --backup-dir), so no backup was checked for erased data.';
  syncRows($('erasures').tBodies[0], data.erasures, {
    key: (e) => e.subject_id,
    sig: (e) => JSON.stringify([e, data.backup_dir]),
    attrs: () => ({}),
    cells: (e) => [
      el('td', { class: 'code' }, e.code),
      el('td', { class: 'num' }, e.study_id),
      el('td', { class: 'nowrap' }, when(Date.parse(e.erased_at))),
      el('td', {}, e.by),
      el('td', {}, e.reason),
      el('td', {}, backupsText(e, data.backup_dir)),
    ],
    empty: () => el('tr', {}, el('td', { colspan: 6, class: 'muted' }, 'No subject erased.')),
  });
}

async function erase(ev) {
  ev.preventDefault();
  const id = Number($('erase-subject').value);
  const reason = $('erase-reason').value.trim();
  const status = $('erase-status');
  const subject = S.subjects.map((x) => x.subject).find((s) => s.id === id);
  if (!subject) {
    setStatus(status, 'err', 'Choose the subject whose data are to be erased.');
    return;
  }
  if (!reason) {
    setStatus(status, 'err', 'Type the reason first (it is kept in the audit log; name no person).');
    $('erase-reason').focus();
    return;
  }
  const code = subject.code;
  const yes = await confirmAction({
    title: `Erase all data of ${code}?`,
    text: `Every test, record, survey answer and note of ${code} is deleted, and so are the details of the audit log's entries about ${code}. The audit log keeps only that ${code} was erased, when, by you and why. Exports and results leave ${code} out. Backups made before now still hold the data. This cannot be undone. Reason: “${reason}”.`,
    ok: `Erase ${code}`,
  });
  if (!yes) return;
  $('erase-submit').disabled = true;
  const r = await act(`Erase ${code}`, status, () => post(`/api/subjects/${id}/erase`, { reason }), (d) => {
    const held = d.backups_holding_data.length;
    const backups = !d.backup_dir
      ? 'no backup directory set, backups not checked'
      : d.backups_unchecked
        ? `the backups could not be checked: ${d.backups_unchecked}`
        : `${held} backup${held === 1 ? '' : 's'} copied before it still hold${held === 1 ? 's' : ''} the data`;
    return `erased (${d.removed.trials} test attempts, ${d.removed.surveys} surveys, ${d.removed.notes} notes removed; ${backups})`;
  });
  $('erase-submit').disabled = false;
  if (r.ok) $('erase-reason').value = '';
  await refresh();
  // The subject list, schedules, results and stations drop the subject's data now.
  emit('trial', null);
}
