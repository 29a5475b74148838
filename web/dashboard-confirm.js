// The one confirmation step of the dashboard's irreversible actions (withdraw a subject,
// disable an account): a modal dialog that names what will happen to whom.

const $ = (id) => document.getElementById(id);

/**
 * Asks before an irreversible action; resolves true only if the experimenter confirms.
 * `title` names the action and its target, `text` what it does, `ok` the confirm button.
 */
export function confirmAction({ title, text, ok }) {
  const dialog = $('confirm-dialog');
  $('confirm-title').textContent = title;
  $('confirm-text').textContent = text;
  $('confirm-ok').textContent = ok;
  dialog.returnValue = '';
  return new Promise((resolve) => {
    dialog.addEventListener('close', () => resolve(dialog.returnValue === 'ok'), { once: true });
    dialog.showModal();
    // The safe answer has the focus: Enter alone never confirms.
    $('confirm-cancel').focus();
  });
}
