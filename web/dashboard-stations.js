// Operator stations of the selected study: pairing by the code a station shows, and which
// subject each station serves.

import { S, act, el, emit, get, on, post, setStatus, syncRows, SEAT_NAME } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

let lastJson = '';
const rowStatus = new Map();

export function init() {
  $('pair-form').addEventListener('submit', (e) => {
    e.preventDefault();
    pair();
  });
  $('stations').addEventListener('change', (e) => {
    const sel = e.target.closest('select[data-assign-station]');
    if (sel) assign(Number(sel.dataset.assignStation), sel);
  });
  on('study', () => {
    S.stations = [];
    lastJson = '';
    rowStatus.clear();
    setStatus($('pair-status'), 'info', '');
    render();
    refresh();
  });
  on('subjects', () => render());
}

export async function refresh() {
  const id = S.studyId;
  if (!id) {
    render();
    return;
  }
  const r = await get(`/api/studies/${id}/stations`);
  if (id !== S.studyId || !r.ok) return;
  const json = JSON.stringify(r.data);
  if (json === lastJson) return;
  lastJson = json;
  S.stations = r.data;
  render();
  emit('stations', S.stations);
}

async function pair() {
  const id = S.studyId;
  if (!id) {
    setStatus($('pair-status'), 'err', 'Create or select a study first: a station is paired with a study.');
    return;
  }
  const code = $('pair-code').value.trim().toUpperCase();
  const name = $('pair-name').value.trim();
  const role = $('pair-role').value;
  const missing = [];
  if (!code) missing.push('the pairing code the station shows');
  if (!name) missing.push('a name');
  if (missing.length) {
    setStatus($('pair-status'), 'err', `Type ${missing.join(' and ')}.`);
    return;
  }
  // A server with several sites asks where the station is; with one, the server's site.
  const body = { pairing_code: code, name, role };
  if (!$('pair-site-label').hidden && $('pair-site').value) body.site = $('pair-site').value;
  $('pair-submit').disabled = true;
  const r = await act(`Pair station “${name}”`, $('pair-status'), () => post(`/api/studies/${id}/stations`, body), (d) =>
    `paired as station #${d.id} (${SEAT_NAME[d.role] || d.role}${S.sites.length > 1 ? `, site ${d.site}` : ''}); assign a subject to it below`,
  );
  $('pair-submit').disabled = false;
  if (r.ok) {
    // Cleared for the next station, unless something new was typed meanwhile.
    if ($('pair-code').value.trim().toUpperCase() === code) $('pair-code').value = '';
    if ($('pair-name').value.trim() === name) $('pair-name').value = '';
    lastJson = '';
    await refresh();
  }
}

/** The pairing form's site choice: shown only when the server serves several sites. */
export function showSites() {
  const sel = $('pair-site');
  const names = S.sites.map((x) => x.site);
  if ([...sel.options].map((o) => o.value).join() !== names.join()) {
    const kept = sel.value;
    sel.replaceChildren(...names.map((n) => el('option', { value: n }, n)));
    if (names.includes(kept)) sel.value = kept;
  }
  $('pair-site-label').hidden = names.length < 2;
}

async function assign(stationId, sel) {
  const subjectId = sel.value === '' ? null : Number(sel.value);
  const st = S.stations.find((s) => s.id === stationId);
  const subj = S.subjects.find((x) => x.subject.id === subjectId);
  const what = subjectId === null ? 'nobody' : subj ? subj.subject.code : `subject #${subjectId}`;
  sel.disabled = true;
  const out = el('span');
  const r = await act(`Assign ${what} to ${st ? `“${st.name}”` : `station #${stationId}`}`, out, () =>
    post(`/api/stations/${stationId}/assign`, { subject_id: subjectId }),
  );
  rowStatus.set(stationId, [r.ok ? 'ok' : 'err', out.textContent]);
  sel.disabled = false;
  lastJson = '';
  await refresh();
  render();
  emit('assigned', stationId);
}

function render() {
  const tbody = $('stations').tBodies[0];
  const note = (text) => () => el('tr', {}, el('td', { colspan: 5, class: 'muted' }, text));
  if (!S.studyId) {
    syncRows(tbody, [], { empty: note('Select or create a study first.') });
    return;
  }
  syncRows(tbody, S.stations, {
    key: (st) => st.id,
    sig: (st) => JSON.stringify([st, S.subjects.map((x) => [x.subject.id, x.subject.code, x.subject.withdrawn_at, x.subject.erased_at, x.tests_complete, x.tests]), rowStatus.get(st.id)]),
    attrs: (st) => ({ 'data-station-row': st.id }),
    cells: (st) => {
      const sel = el(
        'select',
        { 'data-assign-station': st.id, 'aria-label': `Subject at station ${st.name}` },
        el('option', { value: '' }, '— nobody —'),
        // An erased subject takes no further part (the server refuses the assignment).
        ...S.subjects.filter(({ subject: s }) => !s.erased_at).map(({ subject: s, tests_complete, tests }) =>
          el(
            'option',
            { value: s.id, disabled: !!s.withdrawn_at && s.id !== st.subject_id },
            `${s.code}${s.synthetic ? ' (synthetic)' : ''} — ${tests_complete}/${tests}${s.withdrawn_at ? ' — withdrawn' : ''}`,
          ),
        ),
      );
      // A subject the list does not (yet) have.
      if (st.subject_id !== null && !S.subjects.some((x) => x.subject.id === st.subject_id)) {
        sel.append(el('option', { value: st.subject_id }, `subject #${st.subject_id}`));
      }
      sel.value = st.subject_id === null ? '' : String(st.subject_id);
      const res = rowStatus.get(st.id);
      return [
        el('td', { class: 'num' }, st.id),
        el('td', {}, st.name),
        el('td', {}, SEAT_NAME[st.role] || st.role),
        el('td', {}, sel),
        el('td', {}, res ? el('span', { class: `status ${res[0]}` }, res[1]) : ''),
      ];
    },
    empty: note('No station paired yet: open /station on the station’s computer, then type the code it shows above.'),
  });
}
