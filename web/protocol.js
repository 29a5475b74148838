// The ethics board's protocol package: its one button prints the page (or saves it as a PDF,
// in the browser's print dialog). A module of its own: the pages' CSP allows no inline script.

const button = document.getElementById('print');
if (button) button.addEventListener('click', () => window.print());
