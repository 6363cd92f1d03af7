// One measurement: headline figures, K(x), C(x), F(x) (valid range marked,
// hover values with units), the level series Keff(Xpeak) of its job and
// its joint fit (K(x), R and effects over all levels), the coefficients,
// warnings, and the recordings to download.

import { api, download } from './api.js';
import { h, put, q, num, when, shortId, poly, polyIntegral, linspace, pick, row } from './util.js';
import { chart } from './plots.js';

/** K(x) in N/mm at x in mm, from a result document. */
export function stiffnessMm(doc) {
  const s = doc.stiffness || {};
  let c = s.coefficients_n_per_mm_pow_i_plus_1 || s.coefficients_n_per_mm;
  if (!c || !c.length) c = (s.coefficients_n_per_m_pow_i_plus_1 || s.coefficients || []).map((k, i) => k * 1e-3 ** (i + 1));
  const vr = s.valid_range_m || [NaN, NaN];
  return { c, lo: vr[0] * 1e3, hi: vr[1] * 1e3 };
}

/** x grid over the valid range and 25 % beyond each side (mm). */
export function xGrid(lo, hi, n = 241) {
  const m = 0.25 * (hi - lo);
  return linspace(lo - m, hi + m, n);
}

export async function render(main, ctx) {
  const id = ctx.arg;
  const doc = await api(`/api/v1/measurements/${encodeURIComponent(id)}`);
  if (ctx.stale()) return;
  const info = doc.measurement || {};
  const ls = doc.large_signal || {};
  const ss = doc.small_signal || null;
  const model = doc.model || {};
  const plotsEl = h('div', { class: 'plot-grid' });
  const kx = h('div', { id: 'plot-kx' });
  const cx = h('div', { id: 'plot-cx' });
  const fx = h('div', { id: 'plot-fx' });
  const lev = h('div', { id: 'plot-levels' });
  plotsEl.append(kx, cx, fx, lev);
  const dl = (file) =>
    h('button', {
      class: 'link',
      id: `download-${file.replace('.', '-')}`,
      onclick: () => download(`/api/v1/measurements/${id}/recordings/${file}`, `${info.part_serial || 'part'}-${shortId(id)}-${file}`).catch((e) => alert(`Download failed: ${e.message}`)),
    }, file);
  const figures = h('table', { class: 'kv', id: 'figures' },
    row('Keff at Xpeak', q(ls.keff_n_per_m, 'N/mm', 1e-3)),
    Number.isFinite(ls.keff_at_target_n_per_m)
      ? row(`Keff at the target ${q(ls.target_xpeak_m, 'mm', 1e3)} (judged by QC)`, h('span', { id: 'keff-at-target' }, q(ls.keff_at_target_n_per_m, 'N/mm', 1e-3)))
      : null,
    row('Ceff at Xpeak', q(ls.ceff_m_per_n, 'mm/N', 1e3)),
    row('Xpeak', q(ls.xpeak_m, 'mm', 1e3)),
    row('x range', `${q(ls.x_min_m, 'mm', 1e3)} \u2026 ${q(ls.x_max_m, 'mm', 1e3)}`),
    row('resonance (large signal)', q(ls.resonance_hz, 'Hz')),
    row('moving mass', q(ls.moving_mass_kg, 'g', 1e3)),
    ss ? row('f0 (small signal)', `${q(ss.f0_hz, 'Hz')} \u00b1 ${num(ss.f0_se_hz, 2)}`) : null,
    ss ? row('k0 (small signal)', q(ss.k0_n_per_m, 'N/mm', 1e-3)) : null,
    ss ? row('R (small signal)', q(ss.r_ns_per_m, 'N\u00b7s/m')) : null,
    ss ? row('Q', q(pick(ss, 'q', 'q_factor', 'q_1'), '')) : null,
    row('model residual', q(model.residual_percent, '% of RMS(m\u00b7x\u2033)', 1, 3)),
    row('method, order', `${pick(doc, 'stiffness.method') || '\u2013'}, ${pick(doc, 'stiffness.order') ?? '\u2013'}`),
  );
  const { c, lo, hi } = stiffnessMm(doc);
  const se = pick(doc, 'stiffness.coefficients_se_n_per_m_pow_i_plus_1', 'stiffness.coefficients_se') || [];
  const coefTable = h('table', { class: 'list', id: 'coefficients' },
    h('thead', {}, h('tr', {}, h('th', {}, 'i'), h('th', {}, 'k_i'), h('th', {}, 'standard error'), h('th', {}, 'unit'))),
    h('tbody', {}, c.map((k, i) => h('tr', {}, h('td', {}, String(i)), h('td', {}, num(k, 5)), h('td', {}, num((se[i] || NaN) * 1e-3 ** (i + 1), 2)), h('td', {}, `N/mm${i + 1 > 1 ? `^${i + 1}` : ''}`)))));
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Measurement ', h('span', { class: 'mono' }, shortId(id)), ' of part ', h('a', { href: `#/part/${encodeURIComponent(info.part_serial || '')}`, class: 'serial' }, info.part_serial || '?')),
      h('p', { class: 'muted' }, `${when(info.created_at)}; ${info.source || ''}${info.bench_id ? ` on ${info.bench_id}` : ''}${info.job_id ? `, job ${shortId(info.job_id)}` : ''}; software ${info.software_version || '?'}`),
      h('div', { class: 'toolbar' },
        h('a', { href: `#/diagnostics/${id}`, class: 'button', id: 'open-diagnostics' }, 'Diagnostics workspace'),
        h('a', { href: `#/compare?ids=${id}`, class: 'button' }, 'Compare\u2026'),
        h('span', {}, 'Recordings: '), dl('pre.wav'), dl('main.wav')),
      info.analysis_error ? h('p', { class: 'error' }, `The analysis failed: ${info.analysis_error}. The recordings are kept; a fit can be run again.`) : null,
      (doc.warnings || []).length ? h('ul', { class: 'warnings', id: 'warnings' }, doc.warnings.map((w) => h('li', {}, w))) : null,
      h('div', { class: 'two' }, figures, coefTable),
    ),
    h('section', { class: 'card' }, h('h2', {}, 'Stiffness, compliance and force (shaded: outside the measured, valid range)'), plotsEl),
    seriesCard(doc.series, id),
  );
  if (!c.length || !Number.isFinite(lo)) {
    put(plotsEl, h('p', { class: 'muted' }, 'No stiffness result.'));
    return;
  }
  const xs = xGrid(lo, hi);
  const k = xs.map((x) => poly(c, x));
  // With a level series: the joint K(x) beside this level's (inside the series' range).
  const jc = seriesKmm(doc.series);
  const kSeries = [{ label: 'K(x)', unit: 'N/mm' }];
  const kData = [xs, k];
  if (jc) {
    kSeries.push({ label: 'K(x), joint fit of the level series', unit: 'N/mm', dash: true, color: '#ff7f0e' });
    kData.push(xs.map((x) => (x >= jc.lo && x <= jc.hi ? poly(jc.c, x) : null)));
  }
  chart(kx, {
    title: 'Stiffness K(x)', kind: 'K(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: 'stiffness K', unit: 'N/mm' },
    series: kSeries, data: kData, validRange: [lo, hi],
  });
  chart(cx, {
    title: 'Compliance C(x) = 1/K(x)', kind: 'C(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: 'compliance C', unit: 'mm/N' },
    series: [{ label: 'C(x)', unit: 'mm/N', color: '#2ca02c' }], data: [xs, k.map((v) => (v > 0 ? 1 / v : null))], validRange: [lo, hi],
  });
  chart(fx, {
    title: 'Restoring force F(x) = \u222b K dx', kind: 'F(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: 'force F', unit: 'N' },
    series: [{ label: 'F(x)', unit: 'N', color: '#9467bd' }], data: [xs, xs.map((x) => polyIntegral(c, x))], validRange: [lo, hi],
  });
  // Level series: the measurements of the same job (one per level and repeat).
  let levels = [];
  if (info.job_id) {
    try {
      const sib = await api(`/api/v1/measurements?job=${encodeURIComponent(info.job_id)}&limit=200`);
      levels = sib.items.filter((m) => m.summary && Number.isFinite(m.summary.xpeak_m) && Number.isFinite(m.summary.keff_n_per_m));
    } catch {
      levels = [];
    }
  }
  if (!levels.length && Number.isFinite(ls.xpeak_m)) levels = [{ id, summary: { xpeak_m: ls.xpeak_m, keff_n_per_m: ls.keff_n_per_m } }];
  if (ctx.stale()) return;
  levels.sort((a, b) => a.summary.xpeak_m - b.summary.xpeak_m);
  const lx = levels.map((m) => m.summary.xpeak_m * 1e3);
  const ly = levels.map((m) => m.summary.keff_n_per_m * 1e-3);
  const here = levels.map((m) => (m.id === id ? m.summary.keff_n_per_m * 1e-3 : null));
  chart(lev, {
    title: `Level series Keff(Xpeak) of ${info.job_id ? `job ${shortId(info.job_id)}` : 'this measurement'} (${levels.length} level${levels.length === 1 ? '' : 's'})`,
    kind: 'Keff(Xpeak)',
    x: { label: 'peak displacement Xpeak', unit: 'mm' }, y: { label: 'Keff', unit: 'N/mm' },
    series: [
      { label: 'Keff(Xpeak)', unit: 'N/mm', points: true },
      { label: 'this measurement', unit: 'N/mm', points: 'only', color: '#d62728' },
    ],
    data: [lx, ly, here],
    xRange: lx.length === 1 ? [0, lx[0] * 1.5] : undefined,
  });
}

/** The joint K(x) of a level series in N/mm over mm, with its range (mm). */
function seriesKmm(series) {
  const j = series && series.joint;
  const c = j && j.stiffness_coefficients_n_per_m_pow_i_plus_1;
  if (!c || !c.length || !j.valid_range_m) return null;
  return { c: c.map((k, i) => k * 1e-3 ** (i + 1)), lo: j.valid_range_m[0] * 1e3, hi: j.valid_range_m[1] * 1e3 };
}

/** Effects with their parameters, one line ("coulomb_friction: force_n 0.2008, ..."). */
function effectsText(e) {
  const parts = Object.entries(e || {}).filter(([, v]) => v).map(([name, p]) =>
    `${name}: ${Object.entries(p).map(([k, v]) => `${k} ${num(v)}`).join(', ')}`);
  return parts.length ? parts.join('; ') : 'none';
}

/** The joint fit over the levels of the measurement's series (absent: nothing). */
function seriesCard(series, id) {
  if (!series || !series.joint || !Array.isArray(series.levels)) return null;
  const j = series.joint;
  const r = j.valid_range_m || [NaN, NaN];
  return h('section', { class: 'card', id: 'level-series' },
    h('h2', {}, `Level series: one K(x), R and effects fitted jointly over ${series.levels.length} levels`),
    h('p', { class: 'muted' }, 'Effects that change with amplitude (friction, v|v| damping) separate from K(x) only over several levels; the joint K(x) holds over the whole series\' range, each level\'s own fit only over its own.'),
    h('table', { class: 'kv', id: 'series-joint' },
      row('effects (joint)', effectsText(j.effects)),
      row('x range', `${q(r[0], 'mm', 1e3)} \u2026 ${q(r[1], 'mm', 1e3)}`),
      row('K(0) (joint)', q((j.stiffness_coefficients_n_per_m_pow_i_plus_1 || [])[0], 'N/mm', 1e-3)),
      row('R (joint)', `${q(j.r_ns_per_m, 'N\u00b7s/m')} \u00b1 ${num(j.r_se_ns_per_m, 2)}`),
      row('model error, noise floor', `${q(j.model_error_percent, '%', 1, 3)}, ${q(j.noise_floor_percent, '%', 1, 3)}`),
      row('K(x) order', String(j.order ?? '\u2013'))),
    h('table', { class: 'list', id: 'series-levels' },
      h('thead', {}, h('tr', {}, h('th', {}, 'level'), h('th', {}, 'target'), h('th', {}, 'x range'), h('th', {}, 'K(0), own fit'), h('th', {}, 'R, own fit'), h('th', {}, 'effects, own fit'))),
      h('tbody', {}, series.levels.map((l, i) => h('tr', { class: l.measurement_id === id ? 'current' : null },
        h('td', {}, l.measurement_id && l.measurement_id !== id ? h('a', { href: `#/measurement/${encodeURIComponent(l.measurement_id)}` }, String(i + 1)) : `${i + 1} (this)`),
        h('td', {}, q(l.target_xpeak_m, 'mm', 1e3)),
        h('td', {}, `${q((l.range_m || [])[0], 'mm', 1e3)} \u2026 ${q((l.range_m || [])[1], 'mm', 1e3)}`),
        h('td', {}, q((l.stiffness_coefficients_n_per_m_pow_i_plus_1 || [])[0], 'N/mm', 1e-3)),
        h('td', {}, q(l.r_ns_per_m, 'N\u00b7s/m')),
        h('td', {}, effectsText(l.effects)))))));
}
