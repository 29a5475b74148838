// The study's words to the subject outside the consent form: the instructions before a
// test, where to move between seats, and the end of the session, as the server filled them
// in from the approved texts (in the study's language). Apart because they are what the
// ethics approval fixes: this module lays them out and adds only a test's number.

import { el } from './common.js';

const $ = (id) => document.getElementById(id);

/** What the progress line says of a test that is not scored. */
export const PROGRESS = { practice: 'Practice run', identification: 'Measurement (not scored)' };

/** The instructions before a test (the practice run, an identification test), and what
 * "ready" means. */
export function renderReady(s) {
  const t = s.test;
  const texts = s.texts || {};
  $('ready-label').textContent = t.label;
  $('ready-progress').textContent = PROGRESS[t.phase] ? PROGRESS[t.phase] : `Test ${t.number} of ${t.of}`;
  // An identification test has its own instructions: the subject does not steer in it.
  $('ready-instructions').replaceChildren(
    ...(t.phase === 'identification'
      ? paragraphs(t.instructions, 'strong')
      : [
        ...paragraphs(texts.instructions),
        ...paragraphs(t.phase === 'practice' ? texts.before_practice : texts.before_test,
          t.phase === 'practice' ? 'strong' : undefined),
      ]),
  );
  $('ready-note').textContent = texts.ready || '';
}

/** The next test is at the other seat. */
export function renderMove(s) {
  const texts = s.texts || {};
  $('move-to').textContent = (s.to === 'on' ? texts.move_to_on : texts.move_to_off) || '';
  $('move-note').textContent = texts.move_note || '';
}

/** The session is over: finished, declined or withdrawn. */
export function renderDone(s) {
  const texts = s.texts || {};
  const [title, text] = s.reason === 'finished'
    ? [texts.finished_title, texts.finished]
    : s.reason === 'declined'
      ? [texts.declined_title, texts.declined]
      : [texts.withdrawn_title, texts.withdrawn];
  $('done').replaceChildren(el('h1', {}, title || ''), ...paragraphs(text, 'lead'));
}

/** A study text as paragraphs: a blank line separates them (the server filled it in). */
export function paragraphs(text, cls) {
  return (text || '')
    .split(/\n\s*\n/)
    .map((p) => p.trim())
    .filter(Boolean)
    .map((p) => el('p', cls ? { class: cls } : {}, p));
}

/** The page's language follows the study's texts (screen readers, hyphenation). */
export function setLanguage(s) {
  const lang = s.texts && s.texts.language;
  if (lang && document.documentElement.lang !== lang) document.documentElement.lang = lang;
}
