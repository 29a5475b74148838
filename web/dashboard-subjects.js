// Subjects of the selected study (enrol, progress, withdraw) and the schedule of one subject
// with every trial attempt (real controller, blinded label, results, survey) and its actions.

import {
  S, act, COMPENSATOR_NAME, el, emit, get, num, on, post, setStatus, syncRows, validityText, when, SEAT_NAME,
} from './dashboard-core.js';
import { reloadSelected } from './dashboard-study.js';
import { mayChange } from './dashboard-accounts.js';
import { confirmAction } from './dashboard-confirm.js';
import { identificationBlock } from './dashboard-identification.js';

const $ = (id) => document.getElementById(id);

let selectedSubject = null;
let lastListJson = '';
let lastScheduleJson = '';
/** Results of row actions, kept across re-renders: key → [kind, text]. */
const rowStatus = new Map();

export function init() {
  $('enrol').addEventListener('click', () => enrol(false));
  $('enrol-synthetic').addEventListener('click', () => enrol(true));
  $('subjects').addEventListener('click', onSubjectsClick);
  $('subjects').addEventListener('keydown', (e) => {
    const row = e.target.closest('tr[data-subject-id]');
    if (row && e.target === row && (e.key === 'Enter' || e.key === ' ')) {
      e.preventDefault();
      showSchedule(Number(row.dataset.subjectId));
    }
    if (e.key === 'Enter' && e.target.matches('input[data-withdraw-reason]')) {
      e.preventDefault();
      const b = $('subjects').querySelector(`button[data-action="withdraw"][data-subject-id="${e.target.dataset.withdrawReason}"]`);
      if (b && !b.disabled) b.click();
    }
  });
  $('schedule').addEventListener('click', onScheduleClick);
  $('schedule').addEventListener('keydown', (e) => {
    // Enter in a row's text box adds it as a note (the harmless action).
    if (e.key === 'Enter' && e.target.matches('input[data-trial-input]')) {
      e.preventDefault();
      const b = $('schedule').querySelector(`button[data-action="note"][data-trial-id="${e.target.dataset.trialInput}"]`);
      if (b && !b.disabled) b.click();
    }
  });
  on('study', () => {
    selectedSubject = null;
    lastListJson = '';
    lastScheduleJson = '';
    rowStatus.clear();
    S.subjects = [];
    setStatus($('enrol-status'), 'info', '');
    $('schedule').replaceChildren();
    delete $('schedule').dataset.subjectId;
    renderList();
    refresh();
  });
  on('stations', () => renderList());
  on('trial', () => refresh());
}

/** Reloads the subject list and the open schedule. */
export async function refresh() {
  const id = S.studyId;
  if (!id) return;
  const r = await get(`/api/studies/${id}/subjects`);
  if (id !== S.studyId) return;
  if (r.ok) {
    S.subjects = r.data;
    const json = JSON.stringify(r.data);
    if (json !== lastListJson) {
      lastListJson = json;
      renderList();
      emit('subjects', S.subjects);
    }
  }
  if (selectedSubject) await loadSchedule(selectedSubject);
}

async function enrol(synthetic) {
  const id = S.studyId;
  if (!id) {
    setStatus($('enrol-status'), 'err', 'Create or select a study first.');
    return;
  }
  const btn = synthetic ? $('enrol-synthetic') : $('enrol');
  btn.disabled = true;
  const r = await act(
    synthetic ? 'Enrol synthetic subject' : 'Enrol subject',
    $('enrol-status'),
    () => post(`/api/studies/${id}/subjects`, synthetic ? { synthetic: true } : {}),
    (d) => `${d.subject.code} enrolled (${d.subject.synthetic ? 'synthetic' : 'person'}, starts ${SEAT_NAME[d.subject.starting_station] || d.subject.starting_station})`,
  );
  btn.disabled = false;
  if (!r.ok) return;
  const d = r.data;
  const link = `${location.origin}/subject?token=${encodeURIComponent(d.subject_token)}`;
  $('enrol-status').append(
    el('br'),
    'Subject page (shown only now — copy it if the subject follows their own progress): ',
    el('a', { href: link, target: '_blank', rel: 'noopener', class: 'subject-link' }, link),
    el('br'),
    `Protocol hash: ${d.protocol_hash}`,
  );
  await reloadSelected();
  await refresh();
  showSchedule(d.subject.id);
}

// ---- the subject list ---------------------------------------------------------------------

function consentText(s) {
  // An erased subject's consent went with their data: not "pending", which asks for it.
  if (s.erased_at) return `erased ${when(s.erased_at)}`;
  if (!s.consent_decision) return 'pending';
  return `${s.consent_decision} (v${s.consent_version || '?'}, ${when(s.consent_at)})`;
}

/** The row's withdrawal: a reason and the button; an erased subject takes no further
 * part, so there is nothing to do on their row. */
function withdrawCell(s, st) {
  if (s.erased_at) return el('td', { class: 'actions muted', 'data-erased': s.id }, 'erased: no action');
  return el(
    'td',
    { class: 'actions' },
    el('input', {
      'data-keep': `withdraw-${s.id}`,
      'data-withdraw-reason': s.id,
      placeholder: 'reason',
      maxlength: 500,
      disabled: !!s.withdrawn_at,
      'aria-label': `Reason for withdrawing ${s.code}`,
    }),
    el(
      'button',
      { type: 'button', class: 'danger-outline', 'data-action': 'withdraw', 'data-subject-id': s.id, disabled: !!s.withdrawn_at },
      'Withdraw',
    ),
    st ? el('div', { class: `status ${st[0]}` }, st[1]) : null,
  );
}

function renderList() {
  const tbody = $('subjects').tBodies[0];
  const note = (text) => () => el('tr', {}, el('td', { colspan: mayChange() ? 8 : 7, class: 'muted' }, text));
  if (!S.studyId) {
    syncRows(tbody, [], { empty: note('Select or create a study first.') });
    return;
  }
  syncRows(tbody, S.subjects, {
    key: (x) => x.subject.id,
    sig: (x) =>
      JSON.stringify([
        x,
        x.subject.id === selectedSubject,
        mayChange(),
        rowStatus.get(`withdraw-${x.subject.id}`),
        S.stations.filter((st) => st.subject_id === x.subject.id).map((st) => st.name),
      ]),
    attrs: ({ subject: s }) => ({
      'data-subject-id': s.id,
      tabindex: 0,
      class: ['clickable', s.id === selectedSubject ? 'selected' : '', s.withdrawn_at || s.erased_at ? 'withdrawn' : ''].join(' '),
      'aria-selected': s.id === selectedSubject ? 'true' : 'false',
      title: 'Show the schedule',
    }),
    cells: ({ subject: s, tests_complete, tests }) => {
      const stations = S.stations.filter((st) => st.subject_id === s.id).map((st) => st.name);
      const st = rowStatus.get(`withdraw-${s.id}`);
      return [
        el('td', { class: 'code' }, s.code),
        el('td', {}, s.synthetic ? el('span', { class: 'tag synthetic' }, 'synthetic') : 'person'),
        el('td', {}, s.starting_station),
        el('td', { class: s.erased_at ? 'consent-erased' : `consent-${s.consent_decision || 'pending'}` }, consentText(s)),
        el('td', { class: 'progress-cell' }, `${tests_complete} / ${tests}`, el('progress', { max: tests || 1, value: tests_complete })),
        el('td', {}, stations.join(', ') || el('span', { class: 'muted' }, '—')),
        el(
          'td',
          {},
          s.erased_at
            ? `data erased ${when(s.erased_at)}`
            : s.withdrawn_at
              ? `${when(s.withdrawn_at)}: ${s.withdraw_reason || ''}`
              : el('span', { class: 'muted' }, '—'),
        ),
        // An analyst changes nothing: no withdraw column (the server would refuse it).
        mayChange() ? withdrawCell(s, st) : null,
      ];
    },
    empty: note('No subject enrolled yet.'),
  });
}

async function onSubjectsClick(e) {
  const btn = e.target.closest('button[data-action="withdraw"]');
  if (btn) {
    await withdraw(Number(btn.dataset.subjectId), btn);
    return;
  }
  if (e.target.closest('input, button, a, select')) return;
  const row = e.target.closest('tr[data-subject-id]');
  if (row) showSchedule(Number(row.dataset.subjectId));
}

async function withdraw(id, btn) {
  const input = $('subjects').querySelector(`input[data-withdraw-reason="${id}"]`);
  const reason = input ? input.value.trim() : '';
  const code = (S.subjects.find((x) => x.subject.id === id) || { subject: { code: `#${id}` } }).subject.code;
  const key = `withdraw-${id}`;
  if (!reason) {
    rowStatus.set(key, ['err', 'Type the reason for withdrawing first.']);
    renderList();
    const again = $('subjects').querySelector(`input[data-withdraw-reason="${id}"]`);
    if (again) again.focus();
    return;
  }
  const yes = await confirmAction({
    title: `Withdraw ${code} from the study?`,
    text: `A test of ${code} that is running stops at once, no further test is run, and ${code}'s data leave every result and export. This cannot be undone. Reason: “${reason}”.`,
    ok: `Withdraw ${code}`,
  });
  if (!yes) return;
  btn.disabled = true;
  const out = el('span');
  const r = await act(`Withdraw ${code}`, out, () => post(`/api/subjects/${id}/withdraw`, { reason }), () =>
    'withdrawn (left out of every result and export)',
  );
  rowStatus.set(key, [r.ok ? 'ok' : 'err', out.textContent]);
  if (r.ok && input) input.value = '';
  btn.disabled = false;
  if (r.ok && selectedSubject === id) {
    // The withdrawn subject's tests, metrics and surveys leave the screen with them;
    // clicking their row shows the record again.
    selectedSubject = null;
    lastScheduleJson = '';
    delete $('schedule').dataset.subjectId;
    $('schedule').replaceChildren(el('p', { class: 'muted' }, `${code} withdrew: their data are left out of every result and export.`));
  }
  renderList();
  await refresh();
  // Results, stations and the monitor drop the subject's data now, not at their next poll.
  emit('subjects', S.subjects);
  emit('trial', null);
}

// ---- one subject's schedule ---------------------------------------------------------------

export function showSchedule(id) {
  if (selectedSubject !== id) {
    selectedSubject = id;
    lastScheduleJson = '';
    $('schedule').replaceChildren(el('p', { class: 'muted' }, 'Loading the schedule…'));
    delete $('schedule').dataset.subjectId;
  }
  for (const tr of $('subjects').querySelectorAll('tr[data-subject-id]')) {
    const sel = Number(tr.dataset.subjectId) === id;
    tr.classList.toggle('selected', sel);
    tr.setAttribute('aria-selected', sel ? 'true' : 'false');
    tr.rowSig = null;
  }
  loadSchedule(id);
}

async function loadSchedule(id) {
  const r = await get(`/api/subjects/${id}`);
  if (id !== selectedSubject) return;
  if (!r.ok) {
    $('schedule').replaceChildren(el('p', { class: 'status err' }, `Could not load the schedule: ${r.data && r.data.error}`));
    delete $('schedule').dataset.subjectId;
    return;
  }
  const json = JSON.stringify([r.data, [...rowStatus]]);
  if (json === lastScheduleJson && $('schedule').dataset.subjectId === String(id)) return;
  lastScheduleJson = json;
  renderSchedule(r.data);
}

const FINISHED = ['complete', 'aborted', 'incomplete', 'invalid'];

const HEADERS = [
  ['Slot', 'Slot in the schedule (0 = practice), attempt and trial id'],
  ['Seat · block · pos.', 'Seat (on or off the machine), block (1 = starting seat) and position in the block'],
  ['Controller (real) · label (blinded)', 'The real controller, and the label the subject sees'],
  ['Status · reason', ''],
  ['MSE mm²', 'Mean-squared tracking error (mm²)', 'num'],
  ['Cab accel MS', 'Mean-squared cab acceleration ((mm/s²)²)', 'num'],
  ['Survey (acc / spd / smo / ctl)', 'Ratings: accuracy / speed / smoothness / controllability, and the comment'],
  ['Notes · reason or note · actions', ''],
];

/** Where the subject's identification plot goes once it has loaded. */
function identificationSlot(id, trials) {
  const slot = el('div', { class: 'identification-slot' });
  identificationBlock(id, trials).then((node) => slot.replaceChildren(node));
  return slot;
}

/** The subject's vibration exposure (ISO 2631-1, W_d) day by day against the study's budget. */
function exposureBlock(x) {
  if (!x) return '';
  const budget = `budget A(8) ${x.budget_a8_m_s2} m/s², VDV ${x.budget_vdv_m_s175} m/s^1.75 (action values ${x.action_a8_m_s2} and ${x.action_vdv_m_s175}; limit values ${x.limit_a8_m_s2} and ${x.limit_vdv_m_s175})`;
  if (!x.days.length) {
    return el('p', { class: 'muted exposure', 'data-exposure': 'none' }, `Vibration exposure: no test on the machine yet · ${budget}`);
  }
  const over = (d) => d.a8_m_s2 >= x.budget_a8_m_s2 || d.vdv_m_s175 >= x.budget_vdv_m_s175;
  return el(
    'div',
    { class: 'exposure' },
    el('h4', {}, 'Vibration exposure (ISO 2631-1, W_d, per UTC day)'),
    el(
      'table',
      { class: 'grid' },
      el('thead', {}, el('tr', {}, ...['Day (UTC)', 'Tests on the machine', 'A(8) m/s²', 'VDV m/s^1.75'].map((h) => el('th', {}, h)))),
      el(
        'tbody',
        {},
        ...x.days.map((d) =>
          el(
            'tr',
            { 'data-exposure-day': d.date, class: over(d) ? 'st-incomplete' : null },
            el('td', {}, d.date),
            el('td', { class: 'num' }, d.worst_case_tests ? `${d.tests} (${d.worst_case_tests} at the worst case)` : String(d.tests)),
            el('td', { class: 'num' }, d.a8_m_s2.toFixed(3)),
            el('td', { class: 'num' }, d.vdv_m_s175.toFixed(2)),
          ),
        ),
      ),
    ),
    el('p', { class: 'muted' }, budget),
  );
}

/** The schedule's frame (heading, table, notes), made once per subject. */
function frame(subjectId) {
  const box = $('schedule');
  if (box.dataset.subjectId === String(subjectId) && box.querySelector('.schedule-table > tbody')) return box;
  box.replaceChildren(
    el('div', { class: 'schedule-head' }),
    el(
      'div',
      { class: 'table-wrap' },
      el(
        'table',
        { class: 'grid schedule-table' },
        el('thead', {}, el('tr', {}, ...HEADERS.map(([h, title, cls]) => el('th', { title: title || null, class: cls || null }, h)))),
        el('tbody'),
      ),
    ),
    el('div', { class: 'general-notes' }),
  );
  box.dataset.subjectId = String(subjectId);
  return box;
}

function noteLine(n) {
  return el('div', { class: 'note' }, `${n.text} — ${n.author}, ${when(n.created_at)}`);
}

function renderSchedule(d) {
  const s = d.subject;
  const trials = d.trials;
  const latest = new Map();
  for (const { trial: t } of trials) {
    if (!latest.has(t.slot) || latest.get(t.slot).attempt < t.attempt) latest.set(t.slot, t);
  }
  // The server's queue decides (a failed practice holds it); never guessed here.
  const next = trials.map((x) => x.trial).find((t) => t.id === d.next_trial_id);
  const held = d.held;
  const tests = [...latest.values()].filter((t) => t.phase === 'test');
  const done = tests.filter((t) => t.status === 'complete').length;
  const notesOf = (tid) => d.notes.filter((n) => n.trial_id === tid);
  const generalNotes = d.notes.filter((n) => n.trial_id === null || n.trial_id === undefined);

  const box = frame(s.id);
  box.querySelector('.schedule-head').replaceChildren(
    el('h3', {}, `Schedule of ${s.code}`),
    el(
      'p',
      {},
      `${s.synthetic ? 'Synthetic subject (the synthetic operator drives the tests)' : 'Person'} · starts ${SEAT_NAME[s.starting_station] || s.starting_station} · consent ${consentText(s)} · ${done} of ${tests.length} tests complete` +
        (next ? ` · next: slot ${next.slot} (${next.phase === 'test' ? next.blinded_label : next.phase}, ${SEAT_NAME[next.station]})` : held ? ' · held' : ' · nothing left to run'),
    ),
    held
      ? el(
          'p',
          { class: 'status warn', 'data-held': held.trial_id },
          held.phase === 'practice'
            ? `Held: the practice failed ${held.attempts} time${held.attempts === 1 ? '' : 's'} and no scored test runs until you redo it (Redo, trial ${held.trial_id}) or accept it as incomplete with a reason.`
            : `Held: ${held.label} (trial ${held.trial_id}) failed ${held.attempts} times; redo it or accept it as incomplete with a reason.`,
        )
      : '',
    s.withdrawn_at ? el('p', { class: 'status err' }, `Withdrawn ${when(s.withdrawn_at)}: ${s.withdraw_reason || ''}`) : '',
    s.erased_at ? el('p', { class: 'status err' }, `Data erased ${when(s.erased_at)} (the audit log says by whom and why)`) : '',
    exposureBlock(d.exposure),
    identificationSlot(s.id, trials),
  );
  box.querySelector('.general-notes').replaceChildren(
    ...(generalNotes.length ? [el('h4', {}, 'Notes on the subject'), ...generalNotes.map(noteLine)] : []),
  );

  syncRows(box.querySelector('.schedule-table > tbody'), trials, {
    key: (x) => x.trial.id,
    sig: (x) => {
      const t = x.trial;
      return JSON.stringify([x, notesOf(t.id), rowStatus.get(`trial-${t.id}`), latest.get(t.slot) === t, next && next.id === t.id]);
    },
    attrs: ({ trial: t }) => {
      const isLatest = latest.get(t.slot) === t;
      return {
        'data-trial-row': t.id,
        class: [`st-${t.status}`, isLatest ? '' : 'superseded', next && next.id === t.id ? 'next' : '', t.phase === 'test' ? '' : t.phase].join(' '),
        title: isLatest ? null : 'An earlier attempt: a later attempt of this slot replaced it',
      };
    },
    cells: ({ trial: t, survey }) => {
      const isLatest = latest.get(t.slot) === t;
      const st = rowStatus.get(`trial-${t.id}`);
      const canRedo = isLatest && FINISHED.includes(t.status);
      const canIncomplete = isLatest && !t.accepted_reason && t.status !== 'running';
      return [
        el('td', { class: 'slot' }, el('strong', {}, t.slot), el('div', { class: 'sub' }, `att. ${t.attempt}`), el('div', { class: 'sub' }, `trial ${t.id}`)),
        el('td', { class: 'where' }, el('strong', {}, t.station), el('div', { class: 'sub' }, `block ${t.block} · pos. ${t.position}`)),
        el(
          'td',
          { class: 'controller' },
          COMPENSATOR_NAME[t.controller] || t.controller,
          el('div', { class: 'sub' }, t.controller),
          el('div', { class: 'label' }, `sees “${t.blinded_label}”`),
        ),
        el(
          'td',
          { class: 'status-cell' },
          el('span', { class: `badge st-${t.status}` }, t.status),
          next && next.id === t.id && t.status === 'scheduled' ? el('span', { class: 'tag next' }, 'next') : null,
          isLatest ? null : el('span', { class: 'tag' }, 'superseded'),
          t.status_reason ? el('div', { class: 'reason' }, t.status_reason) : null,
          t.accepted_reason ? el('div', { class: 'reason' }, `accepted as incomplete: ${t.accepted_reason}`) : null,
          t.started_at ? el('div', { class: 'sub validity' }, validityText(t)) : null,
        ),
        el('td', { class: 'num', title: t.mse_tracking_mm2 ?? '' }, num(t.mse_tracking_mm2)),
        el('td', { class: 'num', title: t.ms_cab_accel ?? '' }, num(t.ms_cab_accel)),
        el(
          'td',
          { class: 'survey' },
          survey
            ? [
                `${survey.accuracy} / ${survey.speed} / ${survey.smoothness} / ${survey.controllability}`,
                survey.comment ? el('div', { class: 'comment' }, `“${survey.comment}”`) : null,
              ]
            : t.phase !== 'test'
              ? el('span', { class: 'muted' }, 'no survey')
              : t.status === 'complete' && isLatest
                ? el('span', { class: 'tag warn' }, 'pending')
                : '',
        ),
        el(
          'td',
          { class: 'actions' },
          notesOf(t.id).map(noteLine),
          el('input', {
            'data-keep': `trial-${t.id}`,
            'data-trial-input': t.id,
            placeholder: 'reason / note',
            maxlength: 2000,
            'aria-label': `Reason or note for trial ${t.id}`,
          }),
          el('br'),
          el(
            'button',
            { type: 'button', class: 'small', 'data-action': 'redo', 'data-trial-id': t.id, disabled: !canRedo, title: 'Schedule a new attempt of this finished test (a typed text is its reason, kept in the audit log)' },
            'Redo',
          ),
          el(
            'button',
            { type: 'button', class: 'small', 'data-action': 'incomplete', 'data-trial-id': t.id, disabled: !canIncomplete, title: 'Accept this test as incomplete: it is not repeated (the typed reason is required, kept with the test and in the audit log)' },
            'Mark incomplete',
          ),
          el('button', { type: 'button', class: 'small', 'data-action': 'note', 'data-trial-id': t.id, title: 'Add the typed text as a note on this test' }, 'Add note'),
          st ? el('div', { class: `status ${st[0]}` }, st[1]) : null,
        ),
      ];
    },
  });
}

async function onScheduleClick(e) {
  const btn = e.target.closest('button[data-action][data-trial-id]');
  if (!btn || btn.disabled) return;
  const id = Number(btn.dataset.trialId);
  const action = btn.dataset.action;
  const input = $('schedule').querySelector(`input[data-trial-input="${id}"]`);
  const text = input ? input.value.trim() : '';
  const key = `trial-${id}`;
  if ((action === 'incomplete' || action === 'note') && !text) {
    rowStatus.set(key, ['err', action === 'note' ? 'Type the note first.' : 'Type the reason first.']);
    await loadSchedule(selectedSubject);
    const again = $('schedule').querySelector(`input[data-trial-input="${id}"]`);
    if (again) again.focus();
    return;
  }
  btn.disabled = true;
  const out = el('span');
  let r;
  if (action === 'redo') {
    r = await act(`Redo trial ${id}`, out, () => post(`/api/trials/${id}/redo`, { reason: text || '' }), (d) => `new attempt ${d.attempt} scheduled as trial ${d.id}${text ? ' (reason in the audit log)' : ''}`);
  } else if (action === 'incomplete') {
    r = await act(`Mark trial ${id} incomplete`, out, () => post(`/api/trials/${id}/incomplete`, { reason: text }), () => 'marked incomplete');
  } else if (action === 'note') {
    r = await act(`Note on trial ${id}`, out, () => post(`/api/trials/${id}/note`, { text }), () => 'note added');
  } else return;
  rowStatus.set(key, [r.ok ? 'ok' : 'err', out.textContent]);
  // What was typed went with the action: clear it (the re-render keeps typed values).
  if (r.ok && input) input.value = '';
  btn.disabled = false;
  await refresh();
  if (selectedSubject) await loadSchedule(selectedSubject);
  emit('trial', { trial_id: id, local: true });
}

export function selected() {
  return selectedSubject;
}
