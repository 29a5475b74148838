// The survey after each test: its rating scales and open question as the study defines them,
// the answers sent, and the server's objections shown next to the field they are about.
// Apart because it is a form with its own accessibility rules (labels, described-by links,
// focus on the first wrong field) and nothing in it depends on the pursuit display.

import { api, el } from './common.js';
import { onUnauthorized, refresh, token } from './station-connection.js';
import { describe, setError } from './station-errors.js';
import { show, state } from './station-phases.js';

/** Longest survey comment, in characters (protocol: study::MAX_COMMENT_CHARS). */
const MAX_COMMENT_CHARS = 2000;

const $ = (id) => document.getElementById(id);

export function renderSurvey(s) {
  const sv = s.survey;
  const form = $('survey');
  $('survey-label').textContent = s.label || 'this test';
  const points = Array.from({ length: sv.scale_points }, (_, i) => i + 1);
  const groups = sv.items.map((item) => {
    const lowId = `${item.key}-low`;
    const highId = `${item.key}-high`;
    return el('fieldset', { dataset: { field: item.key } },
      el('legend', { id: `${item.key}-legend` }, item.label),
      el('div', { class: 'scale' },
        el('span', { class: 'anchor low', id: lowId }, `1 = ${item.low_anchor}`),
        el('div', { class: 'points' }, points.map((p) => {
          const ends = p === 1 ? lowId : p === sv.scale_points ? highId : undefined;
          return el('label', { class: 'point' },
            el('input', { type: 'radio', name: item.key, value: p, 'aria-describedby': ends }),
            el('span', {}, p));
        })),
        el('span', { class: 'anchor high', id: highId }, `${sv.scale_points} = ${item.high_anchor}`)));
  });
  const box = el('textarea', { id: 'comment', name: 'comment', maxlength: MAX_COMMENT_CHARS, rows: 4, 'aria-describedby': 'comment-count' });
  const count = el('p', { id: 'comment-count', class: 'counter', 'aria-live': 'polite' });
  const recount = () => {
    // Counted as maxlength counts (UTF-16 units): the counter says what the box allows,
    // and never more than the server's limit in characters.
    const n = box.value.length;
    count.textContent = `${n} / ${MAX_COMMENT_CHARS}`;
    count.classList.toggle('full', n >= MAX_COMMENT_CHARS);
  };
  box.addEventListener('input', recount);
  recount();
  const comment = el('div', { class: 'comment-block', dataset: { field: 'comment' } },
    el('label', { for: 'comment' }, sv.open_question), box, count);
  const submit = el('div', { class: 'survey-actions' },
    el('button', { type: 'submit', id: 'survey-submit', class: 'primary' }, 'Submit answers'));
  form.replaceChildren(...groups, comment, submit);
}

function clearFieldErrors(form) {
  for (const e of form.querySelectorAll('.field-error')) e.remove();
  for (const e of form.querySelectorAll('[aria-invalid]')) e.removeAttribute('aria-invalid');
  for (const i of form.querySelectorAll('input[type=radio], textarea')) {
    const keep = (i.getAttribute('aria-describedby') || '').split(' ').filter((id) => id && !id.endsWith('-error'));
    if (keep.length) i.setAttribute('aria-describedby', keep.join(' '));
    else i.removeAttribute('aria-describedby');
  }
}

function showFieldErrors(form, fields) {
  let first = null;
  const other = [];
  for (const f of fields) {
    const block = form.querySelector(`[data-field="${CSS.escape(f.field)}"]`);
    if (!block) {
      other.push(`${f.field}: ${f.message}`);
      continue;
    }
    const id = `${f.field}-error`;
    let msg = form.querySelector(`.field-error[data-field="${CSS.escape(f.field)}"]`);
    if (!msg) {
      msg = el('p', { class: 'field-error', id, dataset: { field: f.field } });
      block.append(msg);
    }
    msg.textContent = msg.textContent ? `${msg.textContent} ${f.message}` : f.message;
    const controls = block.querySelectorAll('input[type=radio], textarea');
    if (block.tagName === 'FIELDSET') block.setAttribute('aria-invalid', 'true');
    for (const c of controls) {
      if (c.tagName === 'TEXTAREA') c.setAttribute('aria-invalid', 'true');
      const by = (c.getAttribute('aria-describedby') || '').split(' ').filter(Boolean);
      if (!by.includes(id)) c.setAttribute('aria-describedby', [...by, id].join(' '));
    }
    if (!first) first = [...controls].find((c) => c.checked) || controls[0];
  }
  if (other.length) setError('action', other.join('\n'));
  if (first) first.focus();
}

export async function submitSurvey(ev) {
  ev.preventDefault();
  const form = $('survey');
  const s = state;
  if (!s || s.phase !== 'survey') return;
  const body = { trial_id: s.trial_id };
  for (const item of s.survey.items) {
    const checked = form.querySelector(`input[name="${CSS.escape(item.key)}"]:checked`);
    body[item.key] = checked ? Number(checked.value) : null;
  }
  body.comment = $('comment').value;
  const button = $('survey-submit');
  button.disabled = true;
  const res = await api('POST', '/api/station/survey', body, { bearer: token });
  button.disabled = false;
  clearFieldErrors(form);
  if (res.ok) {
    setError('action', null);
    show(res.data);
    return;
  }
  if (res.status === 422 && res.data && Array.isArray(res.data.fields)) {
    setError('action', null);
    showFieldErrors(form, res.data.fields);
    return;
  }
  setError('action', describe(res));
  if (res.status === 401) onUnauthorized();
  else if (res.status === 409) refresh();
}
