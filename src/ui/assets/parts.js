// Engineer views: the parts (search by serial or kind, filter by verdict and
// kind) and one part's page: its verdict with the recipe, limits and
// traceability, its measurements and jobs, with a selection to compare.

import { api, daemon } from './api.js';
import { h, put, q, when, shortId, VERDICT_WORDS, stated } from './util.js';
import { verdictCard } from './verdict.js';
import { studyKind, KIND_TEXT } from './studies.js';

/** A verdict badge (or a dash for a part never judged). */
export function verdictBadge(v) {
  return v ? h('span', { class: `badge verdict-${v}` }, VERDICT_WORDS[v] || v) : h('span', { class: 'muted' }, '\u2013');
}

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
  const verdictSel = h('select', { id: 'filter-verdict', 'aria-label': 'Filter by verdict' },
    h('option', { value: '' }, 'any verdict'),
    ['pass', 'fail', 'invalid', 'no_limits'].map((v) => h('option', { value: v }, VERDICT_WORDS[v])),
    h('option', { value: 'none' }, 'not judged'));
  const kindSel = h('select', { id: 'filter-kind', 'aria-label': 'Filter by kind' }, h('option', { value: '' }, 'any kind'));
  verdictSel.value = ctx.params.get('verdict') || '';
  const body = h('tbody', { id: 'parts' });
  const count = h('span', { class: 'muted', id: 'parts-count' });
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Parts ', count),
      h('div', { class: 'toolbar' },
        h('label', { for: 'part-search' }, 'Search '), search,
        h('label', { for: 'filter-verdict' }, 'Verdict '), verdictSel,
        h('label', { for: 'filter-kind' }, 'Kind '), kindSel),
      h('table', { class: 'list' },
        h('thead', {}, h('tr', {}, h('th', {}, 'serial'), daemon.center ? h('th', {}, 'station') : null, h('th', {}, 'kind'), h('th', {}, 'verdict'), h('th', {}, 'measurements'), h('th', {}, 'last change'))),
        body)),
  );
  search.focus();
  const parts = await allParts();
  if (ctx.stale()) return;
  const kinds = [...new Set(parts.map((p) => p.kind || ''))].sort();
  for (const k of kinds) kindSel.append(h('option', { value: k || 'none' }, k ? k.replace(/_/g, ' ') : 'not given'));
  kindSel.value = ctx.params.get('kind') || '';
  function draw() {
    const needle = search.value.trim().toLowerCase();
    const wantV = verdictSel.value;
    const wantK = kindSel.value;
    const hits = parts.filter((p) =>
      (!needle || p.serial.toLowerCase().includes(needle) || (p.kind || '').toLowerCase().includes(needle))
      && (!wantV || (wantV === 'none' ? !p.verdict : p.verdict === wantV))
      && (!wantK || (wantK === 'none' ? !p.kind : p.kind === wantK)));
    count.textContent = `${hits.length} of ${parts.length}`;
    put(body, hits.length
      ? hits.slice(0, 500).map((p) => h('tr', { dataset: { serial: p.serial, verdict: p.verdict || '', kind: p.kind || '' } },
        h('td', {}, h('a', { href: `#/part/${encodeURIComponent(p.serial)}` }, p.serial)),
        daemon.center ? h('td', { class: 'station' }, p.station_id || '\u2013') : null,
        h('td', {}, p.kind ? p.kind.replace(/_/g, ' ') : '\u2013'),
        h('td', {}, verdictBadge(p.verdict)),
        h('td', {}, String(p.measurement_count)),
        h('td', {}, when(p.updated_at))))
      : h('tr', {}, h('td', { colspan: daemon.center ? '6' : '5', class: 'muted' }, parts.length ? 'no part matches' : 'no part measured yet')));
  }
  const keep = () => {
    const ps = new URLSearchParams();
    if (search.value) ps.set('q', search.value);
    if (verdictSel.value) ps.set('verdict', verdictSel.value);
    if (kindSel.value) ps.set('kind', kindSel.value);
    const qs = ps.toString();
    history.replaceState(null, '', `#/parts${qs ? `?${qs}` : ''}`);
    draw();
  };
  search.addEventListener('input', keep);
  verdictSel.addEventListener('change', keep);
  kindSel.addEventListener('change', keep);
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
    // The center holds no job queue (a station's); it has the jobs' verdicts.
    daemon.center ? null : api(`/api/v1/jobs?part=${encodeURIComponent(serial)}&limit=50`),
  ]);
  // The newest job verdict with its detail, for a part judged under a recipe
  // (the part's `verdict`; asking for the others would be a 404).
  const verdict = part.verdict ? await api(`/api/v1/parts/${encodeURIComponent(serial)}/verdict`) : null;
  // The kind: the part's own, else its recipe's.
  let kind = part.kind ? part.kind.replace(/_/g, ' ') : null;
  if (!kind && verdict) {
    try {
      const r = await api(`/api/v1/recipes/${encodeURIComponent(verdict.recipe_name)}`);
      if (r.recipe && r.recipe.part_kind) kind = `${r.recipe.part_kind.replace(/_/g, ' ')} (from recipe ${verdict.recipe_name})`;
    } catch {
      /* retired or unreadable: "not given" */
    }
  }
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
      daemon.center ? h('td', { class: 'station' }, m.station_id || '\u2013') : null,
      h('td', {}, m.source),
      h('td', {}, q(m.target_xpeak_m, 'mm', 1e3, 3)),
      h('td', {}, q(s.xpeak_m, 'mm', 1e3, 3)),
      h('td', {}, stated(q(s.keff_n_per_m, 'N/mm', 1e-3), s.keff_validity, { unit: 'N/mm', scale: 1e-3, raw: s.keff_n_per_m })),
      h('td', {}, stated(q(s.resonance_hz, 'Hz', 1, 3), s.resonance_validity, { unit: 'Hz', raw: s.resonance_hz })),
      h('td', {}, m.analysis_error ? h('span', { class: 'error' }, 'analysis failed') : daemon.center ? '' : h('a', { href: `#/diagnostics/${m.id}` }, 'diagnostics')),
    );
  });
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Part ', h('span', { class: 'serial' }, part.serial)),
      h('p', { class: 'muted', id: 'part-kind' }, `${kind || 'kind not given'}; first seen ${when(part.created_at)}; ${part.measurement_count} measurement${part.measurement_count === 1 ? '' : 's'}`),
      part.notes ? h('p', {}, part.notes) : null,
    ),
    verdict
      ? verdictCard(verdict, { title: `Verdict of the newest judged job (${when(verdict.created_at)})`, id: 'part-verdict' })
      : h('section', { class: 'card', id: 'part-verdict', dataset: { verdict: '' } }, h('p', { class: 'muted' }, 'Not judged: no job of this part ran under a QC recipe.')),
    h('section', { class: 'card' },
      h('h2', {}, 'Measurements'),
      h('table', { class: 'list', id: 'part-measurements' },
        h('thead', {}, h('tr', {}, h('th', {}, ''), h('th', {}, 'measured'), daemon.center ? h('th', {}, 'station') : null, h('th', {}, 'source'), h('th', {}, 'target Xpeak'), h('th', {}, 'Xpeak'), h('th', {}, 'Keff(Xpeak)'), h('th', {}, 'resonance'), h('th', {}, ''))),
        h('tbody', {}, mrows.length ? mrows : h('tr', {}, h('td', { colspan: daemon.center ? '9' : '8', class: 'muted' }, 'none')))),
      compareBtn,
      // The memory's studies (issue 33): on the bench of the part's newest job.
      !daemon.center && ctx.can('operator')
        ? h('p', { class: 'toolbar' }, h('a', { class: 'button', id: 'part-study', href: `#/study?${new URLSearchParams({ serial: part.serial, ...(jobs && jobs.items[0] ? { bench: jobs.items[0].bench_id } : {}) })}` }, 'Study this part\u2019s memory (added mass, recovery)'))
        : null,
      h('h2', { class: 'after-toolbar' }, 'Jobs'),
      !jobs ? h('p', { class: 'muted', id: 'part-jobs-center' }, 'Jobs are held by the station that ran them; the fleet\u2019s center holds their measurements and verdicts (above).') : h('table', { class: 'list', id: 'part-jobs' },
        h('thead', {}, h('tr', {}, h('th', {}, 'job'), h('th', {}, 'state'), h('th', {}, 'verdict'), h('th', {}, 'recipe'), h('th', {}, 'bench'), h('th', {}, 'submitted'), h('th', {}, 'bench time'), h('th', {}, 'problem'))),
        h('tbody', {}, jobs.items.length ? null : h('tr', {}, h('td', { colspan: '8', class: 'muted' }, mrows.length ? 'none: this part was not measured by a job here (its measurements were imported)' : 'none')),
          jobs.items.map((j) => h('tr', { dataset: { job: j.id, verdict: j.verdict || '', study: studyKind(j) || '' } },
          h('td', {}, studyKind(j) ? h('a', { href: `#/study/${encodeURIComponent(j.id)}`, class: 'mono', title: KIND_TEXT[studyKind(j)] }, `${shortId(j.id)} (${KIND_TEXT[studyKind(j)]})`) : shortId(j.id)),
          h('td', {}, h('span', { class: `badge state-${j.state}` }, j.state)),
          h('td', {}, verdictBadge(j.verdict)),
          h('td', {}, j.request && j.request.recipe ? `${j.request.recipe.name} v${j.request.recipe.version}` : '\u2013'),
          h('td', {}, j.bench_id),
          h('td', {}, when(j.created_at)),
          h('td', {}, q(j.bench_time_s, 's', 1, 3)),
          h('td', {}, (j.problem && (j.problem.detail || j.problem.title)) || ''))))),
    ),
  );
}
