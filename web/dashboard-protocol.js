// The ethics board's protocol package of the selected study: a link that opens the server's
// printable page of the saved study (print it to PDF from the browser's print dialog).

import { S, on } from './dashboard-core.js';

const $ = (id) => document.getElementById(id);

export function init() {
  on('study', show);
  show();
}

function show() {
  const link = $('protocol-package');
  link.hidden = !S.studyId;
  if (S.studyId) link.href = `/api/studies/${S.studyId}/protocol.html`;
}
