// One measurement: its QC verdict (recipe, limits, traceability), headline
// figures rounded to their uncertainty (from the chosen fit), K(x) with the
// recipe's mask, C(x), F(x) (valid range marked, hover values with units),
// the symmetry of K(x) (K(-x)/K(x), the symmetry point against amplitude), the level series Keff(Xpeak) of its job and its joint
// fit, the coefficients, the stored fits, warnings, exports (CSV, JSON,
// clipboard), the printable report and the recordings to download.

import { api, download, daemon } from './api.js';
import { h, put, q, num, when, shortId, poly, polyIntegral, linspace, pick, row, withSe, effectName, effectParam, coefUnitMm, validityOf, stated, modelErrorText, foldRepeatedReasons } from './util.js';
import { chart } from './plots.js';
import { verdictCard } from './verdict.js';
import { parametersCsv, curvesCsv, exportJson, saveText, copyText, GRID_POINTS } from './export.js';

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

/** The root of f in [a, b] by bisection (f(a), f(b) of opposite signs). */
function bisect(f, a, b) {
  let fa = f(a);
  for (let k = 0; k < 60; k++) {
    const m = 0.5 * (a + b);
    const fm = f(m);
    if (fm === 0) return m;
    if (Math.sign(fm) === Math.sign(fa)) {
      a = m;
      fa = fm;
    } else b = m;
  }
  return 0.5 * (a + b);
}

/**
 * The symmetry of K(x) (x in mm, K in N/mm):
 * - K(-x)/K(x) over 0 <= x <= min(-lo, hi) and its largest departure from 1 in %;
 * - the symmetry point x_sym(a) at each amplitude a (Klippel): the rest
 *   position about which K is symmetric over +-a, K(x_sym - a) = K(x_sym + a),
 *   for every a whose window x_sym +- a lies inside the valid range. As a
 *   goes to 0 it is the minimum of K; for a parabola it is that at every a.
 */
export function symmetry(c, lo, hi) {
  const xm = Math.min(-lo, hi);
  if (!(xm > 0)) return null;
  const K = (x) => poly(c, x);
  const xs = linspace(0, xm, 121);
  const ratio = xs.map((x) => K(-x) / K(x));
  const asym = ratio.map((r) => 100 * (r - 1));
  const worst = asym.reduce((w, v, i) => (Math.abs(v) > Math.abs(w.v) ? { v, x: xs[i] } : w), { v: 0, x: 0 });
  // The smallest K inside the valid range (a stationary point, else an end).
  const grid = linspace(lo, hi, 2001);
  let im = 0;
  grid.forEach((x, i) => { if (K(x) < K(grid[im])) im = i; });
  const d = c.map((k, i) => k * i).slice(1);
  const dK = (x) => poly(d, x);
  const kMin = im > 0 && im < grid.length - 1 && Math.sign(dK(grid[im - 1])) !== Math.sign(dK(grid[im + 1]))
    ? bisect(dK, grid[im - 1], grid[im + 1])
    : grid[im];
  // x_sym(a): of the roots of K(s + a) - K(s - a) in [lo + a, hi - a], the one nearest K's minimum.
  const amax = 0.5 * (hi - lo);
  const amps = linspace(amax / 60, amax * (1 - 1e-9), 60);
  const xsym = amps.map((a) => {
    const g = (s) => K(s + a) - K(s - a);
    const ss = linspace(lo + a, hi - a, 201);
    let best = null;
    for (let i = 1; i < ss.length; i++) {
      const g0 = g(ss[i - 1]);
      const g1 = g(ss[i]);
      if (g0 === 0 || Math.sign(g0) !== Math.sign(g1)) {
        const r = g0 === 0 ? ss[i - 1] : bisect(g, ss[i - 1], ss[i]);
        if (best === null || Math.abs(r - kMin) < Math.abs(best - kMin)) best = r;
      }
    }
    return best;
  });
  let last = -1;
  xsym.forEach((v, i) => { if (v !== null) last = i; });
  const atLargest = last >= 0 ? { a: amps[last], x: xsym[last] } : null;
  return { xs, ratio, asym, xm, worst, kMin, amps, xsym, atLargest };
}

/**
 * What a recipe draws on K(x) (N/mm over mm), for a measurement judged under
 * it: its K(x) mask (the limits, judged) and the golden units' band (the
 * smallest to the largest K(x) of the golden units the limits were approved
 * from; shown, never judged). The band comes from the newest approved
 * proposal that made this recipe version or an earlier one.
 */
export async function recipeBands(verdict) {
  if (!verdict) return { mask: null, golden: null };
  const name = encodeURIComponent(verdict.recipe_name);
  const [rec, props] = await Promise.all([
    api(`/api/v1/recipes/${name}/versions/${verdict.recipe_version}`).catch(() => null),
    // Limit proposals are a station's (the center holds the approved versions).
    daemon.center ? null : api(`/api/v1/recipes/${name}/limit-proposals`).catch(() => null),
  ]);
  const m = rec && rec.recipe && rec.recipe.kx_mask;
  const mask = m && m.x_m && m.x_m.length
    ? { x: m.x_m.map((x) => x * 1e3), lo: m.lower_n_per_m.map((k) => k * 1e-3), hi: m.upper_n_per_m.map((k) => k * 1e-3), recipe: `${verdict.recipe_name} v${verdict.recipe_version}` }
    : null;
  const approved = ((props && props.items) || [])
    .filter((p) => p.state === 'approved' && p.approved_version <= verdict.recipe_version && p.proposal && p.proposal.golden_kx)
    .sort((a, b) => b.approved_version - a.approved_version)[0];
  const g = approved && approved.proposal.golden_kx;
  const golden = g && g.x_m.length
    ? { x: g.x_m.map((x) => x * 1e3), lo: g.min_n_per_m.map((k) => k * 1e-3), hi: g.max_n_per_m.map((k) => k * 1e-3), n: g.n, version: approved.approved_version, proposal: approved.id }
    : null;
  return { mask, golden };
}

/**
 * The figures table: each value rounded to its uncertainty, the unit after
 * the \u00b1, and each headline value with its state (issue 22): a value not
 * valid shows its state and reason; a not_determined one no number.
 */
export function figuresTable(doc) {
  const ls = doc.large_signal || {};
  const ss = doc.small_signal || null;
  const model = doc.model || {};
  const st = doc.stiffness || {};
  const vr = st.valid_range_m || [NaN, NaN];
  const v = (field) => validityOf(doc, field);
  return h('table', { class: 'kv', id: 'figures' },
    row('Keff at Xpeak', stated(withSe(ls.keff_n_per_m, ls.keff_se_n_per_m, 'N/mm', 1e-3), v('large_signal.keff_n_per_m'), { unit: 'N/mm', scale: 1e-3, raw: ls.keff_n_per_m, id: 'fig-keff' })),
    Number.isFinite(ls.target_xpeak_m)
      ? row(`Keff at the target ${q(ls.target_xpeak_m, 'mm', 1e3)} (judged by QC)`, stated(q(ls.keff_at_target_n_per_m, 'N/mm', 1e-3), v('large_signal.keff_at_target_n_per_m'), { unit: 'N/mm', scale: 1e-3, id: 'keff-at-target' }))
      : null,
    // Ceff is 1/Keff: it carries Keff's state.
    row('Ceff at Xpeak', stated(q(ls.ceff_m_per_n, 'mm/N', 1e3), asKeff(v('large_signal.keff_n_per_m')), { unit: 'mm/N', scale: 1e3, raw: ls.ceff_m_per_n, id: 'fig-ceff' })),
    row('Xpeak', q(ls.xpeak_m, 'mm', 1e3)),
    row('x range', `${q(ls.x_min_m, 'mm', 1e3)} \u2026 ${q(ls.x_max_m, 'mm', 1e3)}`),
    row('resonance (large signal)', stated(q(ls.resonance_hz, 'Hz'), v('large_signal.resonance_hz'), { unit: 'Hz', raw: ls.resonance_hz, id: 'fig-resonance' })),
    row('K(x) over its valid range', stated(`${q(vr[0], 'mm', 1e3, 3)} \u2026 ${q(vr[1], 'mm', 1e3, 3)}`, v('stiffness.k_of_x'), { id: 'fig-kx' })),
    row('moving mass', q(ls.moving_mass_kg, 'g', 1e3)),
    ss ? row('f0 (small signal)', stated(withSe(ss.f0_hz, ss.f0_se_hz, 'Hz'), v('small_signal.f0_hz'), { unit: 'Hz', id: 'fig-f0' })) : null,
    ss ? row('k0 (small signal)', stated(withSe(ss.k0_n_per_m, ss.k0_se_n_per_m, 'N/mm', 1e-3), v('small_signal.k0_n_per_m'), { unit: 'N/mm', scale: 1e-3, id: 'fig-k0' })) : null,
    ss ? row('R (small signal)', stated(withSe(ss.r_ns_per_m, ss.r_se_ns_per_m, 'N\u00b7s/m'), v('small_signal.r_ns_per_m'), { unit: 'N\u00b7s/m', id: 'fig-r-small' })) : null,
    ss ? row('Q (small signal)', stated(withSe(ss.q, ss.q_se), qValidity(doc), { id: 'fig-q' })) : null,
    row('R (large signal)', stated(withSe(st.r_ns_per_m, st.r_se_ns_per_m, 'N\u00b7s/m'), v('stiffness.r_ns_per_m'), { unit: 'N\u00b7s/m', raw: st.r_ns_per_m, id: 'fig-r' })),
    row('model error', h('span', { id: 'fig-model-error' }, modelErrorText(model, '% of RMS(m\u00b7x\u2033)'))),
    row('noise floor', q(model.noise_floor_percent, '%', 1, 3)),
    row('effects in the model', effectsText(model.effects)),
    row('method, order', `${pick(doc, 'stiffness.method') || '\u2013'}, ${pick(doc, 'stiffness.order') ?? '\u2013'}`),
  );
}

/** Ceff = 1/Keff: Keff's state, Keff's fit value inverted, the reason pointing at Keff's. */
function asKeff(kv) {
  if (!kv || kv.state === 'valid') return kv;
  return { ...kv, reason: 'Ceff is 1/Keff: the reason is given at Keff at Xpeak', fit_value: Number.isFinite(kv.fit_value) ? 1 / kv.fit_value : undefined };
}

/** Q's state; a document from before the states with a null Q: not determined with its reason. */
function qValidity(doc) {
  const ss = doc.small_signal || {};
  const v = validityOf(doc, 'small_signal.q');
  if (v.state === 'valid' && !Number.isFinite(ss.q)) return { state: 'not_determined', reason: ss.q_null_reason || 'no value' };
  return v;
}

/** K(x) coefficients with standard errors (N/mm^(i+1)). */
export function coefficientTable(doc) {
  const { c } = stiffnessMm(doc);
  const se = pick(doc, 'stiffness.coefficients_se_n_per_m_pow_i_plus_1', 'stiffness.coefficients_se') || [];
  // K(x)'s state above the table; a K(x) not determined is the fit's, not a measurement.
  const v = validityOf(doc, 'stiffness.k_of_x');
  const nd = v.state === 'not_determined';
  return h('table', { class: 'list', id: 'coefficients', dataset: { state: v.state } },
    v.state !== 'valid' ? h('caption', {}, stated('', v)) : null,
    h('thead', {}, h('tr', {}, h('th', {}, nd ? 'K(x) fit coefficient (diagnostic, not a measurement)' : 'K(x) coefficient'), h('th', {}, 'value \u00b1 standard error'))),
    h('tbody', {}, c.map((k, i) => h('tr', {}, h('td', {}, `k${i}`), h('td', { class: 'num' }, withSe(k, (se[i] ?? NaN) * 1e-3 ** (i + 1), coefUnitMm(i)))))));
}

/** K(x), C(x), F(x) over the valid range and 25 % beyond; the recipe's mask and the golden units' band on K(x). */
export function drawCurves(els, doc, { mask, golden, jointSeries, height, vector } = {}) {
  const { c, lo, hi } = stiffnessMm(doc);
  const xs = xGrid(lo, hi);
  const k = xs.map((x) => poly(c, x));
  const kSeries = [{ label: 'K(x)', unit: 'N/mm' }];
  const kData = [xs, k];
  const jc = seriesKmm(jointSeries);
  if (jc) {
    kSeries.push({ label: 'K(x), joint fit of the level series', unit: 'N/mm', dash: true, color: '#ff7f0e' });
    kData.push(xs.map((x) => (x >= jc.lo && x <= jc.hi ? poly(jc.c, x) : null)));
  }
  const areas = [];
  if (mask) {
    const inter = (arr) => xs.map((x) => interp(mask.x, arr, x));
    kSeries.push({ label: `K(x) mask of ${mask.recipe} (the limits): lower`, unit: 'N/mm', color: '#2ca02c', dash: true, width: 1 });
    kSeries.push({ label: 'mask: upper', unit: 'N/mm', color: '#2ca02c', dash: true, width: 1 });
    kData.push(inter(mask.lo), inter(mask.hi));
    areas.push({ lower: kSeries.length - 1, upper: kSeries.length, fill: 'rgba(44,160,44,0.13)', label: 'inside the mask' });
  }
  if (golden) {
    const inter = (arr) => xs.map((x) => interp(golden.x, arr, x));
    kSeries.push({ label: `golden units (${golden.n}, approved in v${golden.version}): lowest K`, unit: 'N/mm', color: '#b8860b', width: 1 });
    kSeries.push({ label: 'golden units: highest K', unit: 'N/mm', color: '#b8860b', width: 1 });
    kData.push(inter(golden.lo), inter(golden.hi));
    areas.push({ lower: kSeries.length - 1, upper: kSeries.length, fill: 'rgba(184,134,11,0.28)', label: 'golden units\u2019 band' });
  }
  chart(els.kx, {
    title: 'Stiffness K(x)', kind: 'K(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: height ? 'K' : 'stiffness K', unit: 'N/mm' },
    series: kSeries, data: kData, validRange: [lo, hi], areas, height, vector,
  });
  if (els.kx && mask) els.kx.dataset.mask = String(mask.x.length);
  if (els.kx && golden) els.kx.dataset.golden = `${golden.n},${golden.version},${golden.proposal}`;
  chart(els.cx, {
    title: 'Compliance C(x) = 1/K(x)', kind: 'C(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: height ? 'C' : 'compliance C', unit: 'mm/N' },
    series: [{ label: 'C(x)', unit: 'mm/N', color: '#2ca02c' }], data: [xs, k.map((v) => (v > 0 ? 1 / v : null))], validRange: [lo, hi], height, vector,
  });
  chart(els.fx, {
    title: 'Restoring force F(x) = \u222b K dx', kind: 'F(x)',
    x: { label: 'displacement x', unit: 'mm' }, y: { label: height ? 'F' : 'force F', unit: 'N' },
    series: [{ label: 'F(x)', unit: 'N', color: '#9467bd' }], data: [xs, xs.map((x) => polyIntegral(c, x))], validRange: [lo, hi], height, vector,
  });
}

/** Linear interpolation of (xs, ys) at x; null outside. */
function interp(xs, ys, x) {
  if (!xs.length || x < xs[0] || x > xs[xs.length - 1]) return null;
  for (let i = 1; i < xs.length; i++) {
    if (x <= xs[i]) {
      const t = (x - xs[i - 1]) / (xs[i] - xs[i - 1] || 1);
      return ys[i - 1] + t * (ys[i] - ys[i - 1]);
    }
  }
  return ys[ys.length - 1];
}

/** Keff(Xpeak) of the measurement's job (one point per level). */
export async function drawLevels(el, doc, id, { height, vector } = {}) {
  const info = doc.measurement || {};
  const ls = doc.large_signal || {};
  let levels = [];
  if (info.job_id) {
    try {
      const sib = await api(`/api/v1/measurements?job=${encodeURIComponent(info.job_id)}&limit=200`);
      // A Keff not determined is no point of the curve (issue 22).
      levels = sib.items.filter((m) => m.summary && Number.isFinite(m.summary.xpeak_m) && Number.isFinite(m.summary.keff_n_per_m)
        && (m.summary.keff_validity || {}).state !== 'not_determined');
    } catch {
      levels = [];
    }
  }
  if (!levels.length && Number.isFinite(ls.xpeak_m) && validityOf(doc, 'large_signal.keff_n_per_m').state !== 'not_determined') {
    levels = [{ id, summary: { xpeak_m: ls.xpeak_m, keff_n_per_m: ls.keff_n_per_m } }];
  }
  levels.sort((a, b) => a.summary.xpeak_m - b.summary.xpeak_m);
  const lx = levels.map((m) => m.summary.xpeak_m * 1e3);
  const ly = levels.map((m) => m.summary.keff_n_per_m * 1e-3);
  const here = levels.map((m) => (m.id === id ? m.summary.keff_n_per_m * 1e-3 : null));
  chart(el, {
    title: `Keff(Xpeak) of ${info.job_id ? `job ${shortId(info.job_id)}` : 'this measurement'} (${levels.length} level${levels.length === 1 ? '' : 's'})`,
    kind: 'Keff(Xpeak)',
    x: { label: 'peak displacement Xpeak', unit: 'mm' }, y: { label: 'Keff', unit: 'N/mm' },
    series: [
      { label: 'Keff(Xpeak)', unit: 'N/mm', points: true },
      { label: 'this measurement', unit: 'N/mm', points: 'only', color: '#d62728' },
    ],
    data: [lx, ly, here],
    xRange: lx.length === 1 ? [0, lx[0] * 1.5] : undefined,
    height,
    vector,
  });
}

/** The stored fits: which one supplies the headline, and the choice (operator). */
function fitsCard(id, fits, headline, ctx) {
  const chosen = headline && headline.fit_id;
  const choose = async (fitId) => {
    try {
      await api(`/api/v1/measurements/${encodeURIComponent(id)}/headline`, { method: 'PUT', body: { fit_id: fitId } });
      ctx.reload();
    } catch (e) {
      alert(`Not chosen: ${e.message}`);
    }
  };
  const btn = (fitId, label) => (ctx.can('operator') && !daemon.center
    ? h('button', { class: 'link', id: `headline-${fitId || 'base'}`, onclick: () => choose(fitId) }, label)
    : null);
  const eff = (f) => {
    const e = (f.request && f.request.effects) || [];
    return e.length ? e.map(effectName).join(', ') : (f.request && f.request.exact === false ? 'chosen by the diagnostics' : 'base model');
  };
  return h('section', { class: 'card', id: 'fits' },
    h('h2', {}, 'Fits of this measurement'),
    h('p', { class: 'muted' }, 'The headline figures, the plots, the exports and the report come from the chosen fit. Refits are made in the diagnostics workspace.'),
    h('table', { class: 'list', id: 'fit-list' },
      h('thead', {}, h('tr', {}, h('th', {}, 'fit'), h('th', {}, 'effects'), h('th', {}, 'model error'), h('th', {}, 'K(0)'), h('th', {}, 'made'), h('th', {}, 'headline'))),
      h('tbody', {},
        h('tr', { class: chosen ? '' : 'current', dataset: { fit: '' } },
          h('td', {}, 'measurement\u2019s own result'), h('td', {}, 'as measured'), h('td', {}, '\u2013'), h('td', {}, '\u2013'), h('td', {}, ''),
          h('td', {}, chosen ? btn(null, 'use this') : h('strong', {}, 'headline'))),
        fits.map((f) => h('tr', { class: f.id === chosen ? 'current' : '', dataset: { fit: f.id } },
          h('td', { class: 'mono' }, shortId(f.id)),
          h('td', {}, eff(f)),
          h('td', {}, modelErrorText(pick(f, 'result.model'))),
          h('td', {}, q((pick(f, 'result.stiffness.coefficients_n_per_m_pow_i_plus_1') || [])[0], 'N/mm', 1e-3)),
          h('td', {}, when(f.created_at)),
          h('td', {}, f.id === chosen ? h('strong', {}, 'headline') : btn(f.id, 'use as headline')))))),
    chosen ? h('p', { class: 'muted', id: 'headline-chosen' }, `Chosen by ${headline.chosen_by || 'open access'} at ${when(headline.chosen_at)}.`) : null);
}

/** The measurement's document with the chosen fit's result in place of its own. */
export async function headlineDoc(id, doc) {
  const info = doc.measurement || {};
  let fits = [];
  try {
    fits = (await api(`/api/v1/measurements/${encodeURIComponent(id)}/fits`)).items || [];
  } catch {
    fits = [];
  }
  const fid = info.headline && info.headline.fit_id;
  const fit = fid ? fits.find((f) => f.id === fid) : null;
  const shown = fit ? { ...fit.result, measurement: info } : doc;
  return { shown, fit, fits };
}

export async function render(main, ctx) {
  const id = ctx.arg;
  const doc = await api(`/api/v1/measurements/${encodeURIComponent(id)}`);
  const info = doc.measurement || {};
  const { shown, fit, fits } = await headlineDoc(id, doc);
  const { mask, golden } = await recipeBands(info.verdict);
  if (ctx.stale()) return;
  ctx.reload = () => {
    if (!ctx.stale()) ctx.rerender();
  };
  const plotsEl = h('div', { class: 'plot-grid' });
  const kx = h('div', { id: 'plot-kx' });
  const cx = h('div', { id: 'plot-cx' });
  const fx = h('div', { id: 'plot-fx' });
  const lev = h('div', { id: 'plot-levels' });
  const sym = h('div', { id: 'plot-symmetry' });
  plotsEl.append(kx, cx, fx, lev);
  const exportMsg = h('span', { class: 'muted', id: 'export-msg', role: 'status' });
  const base = `${info.part_serial || 'part'}-${shortId(id)}${fit ? `-fit-${shortId(fit.id)}` : ''}`;
  const dl = (file) =>
    h('button', {
      class: 'link',
      id: `download-${file.replace('.', '-')}`,
      onclick: () => download(`/api/v1/measurements/${id}/recordings/${file}`, `${info.part_serial || 'part'}-${shortId(id)}-${file}`).catch((e) => alert(`Download failed: ${e.message}`)),
    }, file);
  const save = (what, text, type, name) => h('button', { class: 'link', id: `export-${what}`, onclick: () => saveText(name, text(), type) }, name.split('.').pop().toUpperCase());
  const copy = (what, text) => h('button', {
    class: 'link', id: `copy-${what}`,
    onclick: async () => {
      const ok = await copyText(text());
      exportMsg.textContent = ok ? `Copied the ${what === 'parameters' ? 'parameter table' : 'K(x), C(x), F(x) table'} (tab-separated, for a spreadsheet).` : 'The browser refused the clipboard.';
    },
  }, 'copy');
  const exports = h('div', { class: 'toolbar exports', id: 'exports' },
    h('span', {}, 'Parameters: '), save('parameters-csv', () => parametersCsv(shown), 'text/csv', `${base}-parameters.csv`), copy('parameters', () => parametersCsv(shown, '\t')),
    h('span', {}, ` K(x), C(x), F(x) (${GRID_POINTS} points inside the valid range): `), save('curves-csv', () => curvesCsv(shown), 'text/csv', `${base}-curves.csv`), copy('curves', () => curvesCsv(shown, '\t')),
    h('span', {}, ' Everything: '), save('json', () => exportJson(shown), 'application/json', `${base}.json`),
    exportMsg);
  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Measurement ', h('span', { class: 'mono' }, shortId(id)), ' of part ', h('a', { href: `#/part/${encodeURIComponent(info.part_serial || '')}`, class: 'serial' }, info.part_serial || '?')),
      h('p', { class: 'muted', id: 'measurement-origin' }, `${when(info.created_at)}; ${info.station_id ? `station ${info.station_id}, ` : ''}${info.source || ''}${info.bench_id ? ` on ${info.bench_id}` : ''}${info.job_id ? `, job ${shortId(info.job_id)}` : ''}; software ${info.software_version || '?'}`),
      h('div', { class: 'toolbar' },
        daemon.center ? null : h('a', { href: `#/diagnostics/${id}`, class: 'button', id: 'open-diagnostics' }, 'Diagnostics workspace'),
        h('a', { href: `#/compare?ids=${id}`, class: 'button' }, 'Compare\u2026'),
        h('a', { href: `#/report/${id}`, class: 'button', id: 'open-report' }, 'Printable report'),
        h('span', {}, 'Recordings: '), dl('pre.wav'), dl('main.wav'),
        daemon.center ? h('span', { class: 'muted', id: 'center-recordings' }, ` (here when station ${info.station_id || '?'} sends them to the center; the diagnostics workspace: on that station)`) : null),
      exports,
      info.void_correction_id ? h('p', { class: 'error', id: 'measurement-void', dataset: { correction: info.void_correction_id } }, `Voided (correction ${shortId(info.void_correction_id)}; the reason is in the audit log): it counts in no SPC, yield or part verdict.`) : null,
      info.analysis_error ? h('p', { class: 'error' }, `The analysis failed: ${info.analysis_error}. The recordings are kept; a fit can be run again.`) : null,
      fit
        ? h('p', { class: 'headline-note', id: 'headline-source', dataset: { fit: fit.id } }, `Headline from fit ${shortId(fit.id)} (${((fit.request && fit.request.effects) || []).map(effectName).join(', ') || 'refit'}), chosen by ${info.headline.chosen_by || 'open access'} at ${when(info.headline.chosen_at)}.`)
        : h('p', { class: 'muted', id: 'headline-source', dataset: { fit: '' } }, 'Headline from the measurement\u2019s own result.'),
      (shown.warnings || []).length ? h('ul', { class: 'warnings', id: 'warnings' }, shown.warnings.map((w) => h('li', {}, w))) : null,
      foldRepeatedReasons(h('div', { class: 'two', id: 'headline-values' }, figuresTable(shown), coefficientTable(shown))),
    ),
    info.verdict ? verdictCard(info.verdict, { title: 'QC verdict of this measurement', id: 'measurement-verdict' }) : null,
    h('section', { class: 'card' }, h('h2', {}, 'Stiffness, compliance, force and Keff(Xpeak) (shaded: outside the measured, valid range)'), plotsEl),
    h('section', { class: 'card', id: 'symmetry' }, h('h2', {}, 'Symmetry of K(x)'), sym),
    fitsCard(id, fits, info.headline, ctx),
    seriesCard(shown.series, id),
  );
  const { c, lo, hi } = stiffnessMm(shown);
  if (!c.length || !Number.isFinite(lo)) {
    put(plotsEl, h('p', { class: 'muted' }, 'No stiffness result.'));
    return;
  }
  drawCurves({ kx, cx, fx }, shown, { mask, golden, jointSeries: shown.series });
  drawSymmetry(sym, c, lo, hi);
  await drawLevels(lev, shown, id);
}

/** K(-x)/K(x) with the asymmetry in %, and the symmetry point against the amplitude. */
export function drawSymmetry(el, c, lo, hi, { height } = {}) {
  const s = symmetry(c, lo, hi);
  if (!s) {
    put(el, h('p', { class: 'muted' }, 'The valid range does not reach both sides of x = 0.'));
    return;
  }
  const L = s.atLargest;
  const note = h('p', {
    id: 'symmetry-figures',
    dataset: {
      asymmetryPercent: String(s.worst.v), asymmetryAtMm: String(s.worst.x), kMinMm: String(s.kMin),
      symmetryPointMm: L ? String(L.x) : '', symmetryAmplitudeMm: L ? String(L.a) : '',
    },
  },
  `Largest asymmetry ${num(s.worst.v, 3)} % at |x| = ${num(s.worst.x, 3)} mm (K(\u2212x) ${s.worst.v >= 0 ? 'stiffer' : 'softer'} than K(x)). `,
  L ? `Symmetry point ${num(L.x, 3)} mm at amplitude ${num(L.a, 3)} mm (the largest whose window lies inside the valid range); ` : 'No symmetry point inside the valid range; ',
  `minimum of K at x = ${num(s.kMin, 3)} mm (the symmetry point at small amplitude).`);
  const ratioEl = h('div', { id: 'plot-symmetry-ratio' });
  const pointEl = h('div', { id: 'plot-symmetry-point' });
  put(el, note, h('div', { class: 'plot-grid' }, ratioEl, pointEl));
  chart(ratioEl, {
    title: 'K(\u2212x) / K(x) over |x|', kind: 'symmetry',
    x: { label: 'displacement |x|', unit: 'mm' }, y: { label: 'K(\u2212x)/K(x)', unit: '' },
    series: [{ label: 'K(\u2212x)/K(x)', unit: '' }],
    data: [s.xs, s.ratio], height: height || 220,
  });
  chart(pointEl, {
    title: 'Symmetry point against amplitude', kind: 'symmetry point',
    x: { label: 'amplitude a', unit: 'mm' }, y: { label: 'x_sym', unit: 'mm' },
    series: [{ label: 'x_sym: K(x_sym \u2212 a) = K(x_sym + a)', unit: 'mm', color: '#9467bd' }],
    data: [s.amps, s.xsym], xRange: [0, s.amps[s.amps.length - 1]], height: height || 220,
  });
}

/** The joint K(x) of a level series in N/mm over mm, with its range (mm). */
function seriesKmm(series) {
  const j = series && series.joint;
  const c = j && j.stiffness_coefficients_n_per_m_pow_i_plus_1;
  if (!c || !c.length || !j.valid_range_m) return null;
  return { c: c.map((k, i) => k * 1e-3 ** (i + 1)), lo: j.valid_range_m[0] * 1e3, hi: j.valid_range_m[1] * 1e3 };
}

/** Effects with their parameters, one line ("dry (Coulomb) friction: friction force 0.2008 N, ..."). */
export function effectsText(e) {
  const parts = Object.entries(e || {}).filter(([, v]) => v).map(([name, p]) =>
    `${effectName(name)}: ${Object.entries(p).map(([k, v]) => {
      const d = effectParam(name, k);
      return `${d.label} ${num(v * d.scale, 4)}${d.unit ? ` ${d.unit}` : ''}`;
    }).join(', ')}`);
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
