// Engineer views: the parts (search by serial or kind) and one part's
// history (its measurements and jobs), with a selection to compare.

import { api } from './api.js';
import { h, put, q, when, shortId } from './util.js';

/** All parts (the API pages them; a station knows thousands at most). */
async function allParts() {
  const out = [];
  let cursor = '';
  for (let i = 0; i < 40; i++) {
    const page = await api(`/api/v1/parts?limit=500${cursor ? `&cursor=${encodeURIComponent(cursor)}` : ''}`);
    out.push(...page.items);
    if (!page.next_cursor) break;
    cursor = page.next_cursor;
  }
  return out;
}

export async function render(main, ctx) {
  const search = h('input', {
    id: 'part-search',
    type: 'search',
    placeholder: 'serial or kind',
    value: ctx.params.get('q') || '',
    'aria-label': 'Search parts',
  });
  const body = h('tbody', { id: 'parts' });
  const count = h('span', { class: 'muted', id: 'parts-count' });
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Parts ', count),
      h('div', { class: 'toolbar' }, h('label', { for: 'part-search' }, 'Search '), search),
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, h('th', {}, 'serial'), h('th', {}, 'kind'), h('th', {}, 'measurements'), h('th', {}, 'last change'))),
        body)),
  );
  search.focus();
  const parts = await allParts();
  if (ctx.stale()) return;
  function draw() {
    const needle = search.value.trim().toLowerCase();
    const hits = parts.filter((p) => !needle || p.serial.toLowerCase().includes(needle) || (p.kind || '').toLowerCase().includes(needle));
    count.textContent = `${hits.length} of ${parts.length}`;
    put(body, hits.length
      ? hits.slice(0, 500).map((p) => h('tr', { dataset: { serial: p.serial } },
        h('td', {}, h('a', { href: `#/part/${encodeURIComponent(p.serial)}` }, p.serial)),
        h('td', {}, p.kind || '\u2013'),
        h('td', {}, String(p.measurement_count)),
        h('td', {}, when(p.updated_at))))
      : h('tr', {}, h('td', { colspan: '4', class: 'muted' }, parts.length ? 'no part matches' : 'no part measured yet')));
  }
  search.addEventListener('input', () => {
    history.replaceState(null, '', `#/parts${search.value ? `?q=${encodeURIComponent(search.value)}` : ''}`);
    draw();
  });
  search.addEventListener('keydown', (ev) => {
    if (ev.key !== 'Enter') return;
    const first = body.querySelector('a');
    if (first) location.hash = first.getAttribute('href');
  });
  draw();
}

export async function renderPart(main, ctx) {
  const serial = ctx.arg;
  const [part, meas, jobs] = await Promise.all([
    api(`/api/v1/parts/${encodeURIComponent(serial)}`),
    api(`/api/v1/parts/${encodeURIComponent(serial)}/measurements?limit=200`),
    api(`/api/v1/jobs?part=${encodeURIComponent(serial)}&limit=50`),
  ]);
  if (ctx.stale()) return;
  const selected = new Set();
  const compareBtn = h('button', { id: 'compare-selected', disabled: true }, 'Compare K(x) of the selected');
  compareBtn.addEventListener('click', () => {
    location.hash = `#/compare?ids=${[...selected].join(',')}`;
  });
  const mrows = meas.items.map((m) => {
    const cb = h('input', { type: 'checkbox', 'aria-label': `select ${m.id}`, dataset: { id: m.id } });
    cb.addEventListener('change', () => {
      if (cb.checked) selected.add(m.id);
      else selected.delete(m.id);
      compareBtn.disabled = selected.size < 1;
    });
    const s = m.summary || {};
    return h('tr', { dataset: { measurement: m.id } },
      h('td', {}, cb),
      h('td', {}, h('a', { href: `#/measurement/${m.id}` }, when(m.created_at))),
      h('td', {}, m.source),
      h('td', {}, q(m.target_xpeak_m, 'mm', 1e3, 3)),
      h('td', {}, q(s.xpeak_m, 'mm', 1e3, 3)),
      h('td', {}, q(s.keff_n_per_m, 'N/mm', 1e-3)),
      h('td', {}, q(s.resonance_hz, 'Hz', 1, 3)),
      h('td', {}, m.analysis_error ? h('span', { class: 'error' }, 'analysis failed') : h('a', { href: `#/diagnostics/${m.id}` }, 'diagnostics')),
    );
  });
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Part ', h('span', { class: 'serial' }, part.serial)),
      h('p', { class: 'muted' }, `${part.kind || 'kind not given'}; first seen ${when(part.created_at)}; ${part.measurement_count} measurements`),
      part.notes ? h('p', {}, part.notes) : null,
      h('h2', {}, 'Measurements'),
      h('table', { class: 'list', id: 'part-measurements' },
        h('thead', {}, h('tr', {}, h('th', {}, ''), h('th', {}, 'measured'), h('th', {}, 'source'), h('th', {}, 'target Xpeak'), h('th', {}, 'Xpeak'), h('th', {}, 'Keff(Xpeak)'), h('th', {}, 'resonance'), h('th', {}, ''))),
        h('tbody', {}, mrows.length ? mrows : h('tr', {}, h('td', { colspan: '8', class: 'muted' }, 'none')))),
      compareBtn,
      h('h2', {}, 'Jobs'),
      h('table', { class: 'list', id: 'part-jobs' },
        h('thead', {}, h('tr', {}, h('th', {}, 'job'), h('th', {}, 'state'), h('th', {}, 'bench'), h('th', {}, 'submitted'), h('th', {}, 'bench time'), h('th', {}, 'problem'))),
        h('tbody', {}, jobs.items.map((j) => h('tr', {},
          h('td', {}, shortId(j.id)),
          h('td', {}, h('span', { class: `badge state-${j.state}` }, j.state)),
          h('td', {}, j.bench_id),
          h('td', {}, when(j.created_at)),
          h('td', {}, q(j.bench_time_s, 's', 1, 3)),
          h('td', {}, (j.problem && (j.problem.detail || j.problem.title)) || ''))))),
    ),
  );
}
