// Diagnostics workspace: the model against the measurement with the
// residual beneath (same time axis), the residual against x and v with the
// noise band, the residual spectrum with the harmonics labelled, the
// candidate effects, and "add this effect": a refit (POST .../fits) whose
// ladder step and change of K(x) are shown side by side, so the user
// watches the model error fall. Also the small-signal transfer function
// against its fit.

import { api } from './api.js';
import { h, put, num, shortId, poly, linspace, withSe, effectName, effectParam } from './util.js';
import { chart, bars } from './plots.js';
import { stiffnessMm } from './measurement.js';

/** The SI stiffness coefficients -> N/mm^(i+1). */
function toMm(c) {
  return (c || []).map((k, i) => k * 1e-3 ** (i + 1));
}

/** One rung of the user's ladder, from a diagnostics document. */
function stepOf(diag, which, effects, fitId) {
  const m = which === 'base' ? diag.base_model : diag.final_model;
  const c = diag.comparison || {};
  const det = c.detail || {};
  const model = which === 'base' ? det.base_modelled_force_n : det.modelled_force_n;
  const rx = (c.residual_vs_x || {})[which] || {};
  const rv = c.residual_vs_v || {};
  const sp = c.spectrum || {};
  return {
    effects,
    fitId,
    label: effects.length ? `+ ${effectName(effects[effects.length - 1])}` : 'base model',
    error: m.model_error_percent,
    residual: m.residual_percent,
    k: toMm(m.stiffness_coefficients_n_per_m_pow_i_plus_1 || m.stiffness_coefficients),
    params: m.parameters || {},
    paramsSe: m.parameters_se || {},
    candidates: diag.candidates || [],
    noiseFloor: diag.noise_floor_percent,
    t: det.t_s || [],
    measured: det.measured_force_n || [],
    model: model || [],
    rxX: (c.residual_vs_x || {}).x_m || [],
    rxPos: rx.positive_v_n || [],
    rxNeg: rx.negative_v_n || [],
    rxCount: (c.residual_vs_x || {}).positive_v_count || null,
    rxCountNeg: (c.residual_vs_x || {}).negative_v_count || null,
    rvV: rv.v_m_per_s || [],
    rvMean: (which === 'base' ? rv.base_n : rv.final_n) || [],
    rvCount: rv.count || null,
    noiseRms: c.noise_rms_n,
    spF: sp.freq_hz || [],
    spP: which === 'base' ? sp.base_psd_n2_per_hz || null : sp.psd_n2_per_hz,
    spNoise: sp.noise_psd_n2_per_hz || [],
    bands: sp.harmonic_bands_hz || [],
    small: c.small_signal || null,
  };
}

/** +-2 sigma of a bin mean (sigma: the noise RMS), per bin. */
function noiseBand(noise, counts, n) {
  if (!Number.isFinite(noise) || !counts) return null;
  return Array.from({ length: n }, (_, i) => (counts[i] >= 20 ? (2 * noise) / Math.sqrt(counts[i]) : null));
}

export async function render(main, ctx) {
  const id = ctx.arg;
  const status = h('p', { class: 'status', id: 'diag-status', role: 'status' }, 'Fitting the base model and every candidate effect\u2026');
  put(main, h('section', { class: 'card' }, h('h1', {}, 'Diagnostics workspace'), status));
  const [doc, d0] = await Promise.all([
    api(`/api/v1/measurements/${encodeURIComponent(id)}`),
    api(`/api/v1/measurements/${encodeURIComponent(id)}/diagnostics`),
  ]);
  if (ctx.stale()) return;
  const info = doc.measurement || {};
  const { lo, hi } = stiffnessMm(doc);
  const steps = [stepOf(d0.diagnostics, 'base', [], null)];
  let current = 0;
  // The workspace opens on the fit chosen as the measurement's headline.
  const chosen = info.headline && info.headline.fit_id;
  let opened = null;
  if (chosen) {
    try {
      const fits = (await api(`/api/v1/measurements/${encodeURIComponent(id)}/fits`)).items || [];
      const f = fits.find((x) => x.id === chosen);
      const diag = f && f.result && f.result.diagnostics;
      if (diag) {
        steps.push(stepOf(diag, 'final', (f.request && f.request.effects) || [], f.id));
        current = 1;
        opened = f;
      }
    } catch {
      /* the base model, as without a choice */
    }
  }
  if (ctx.stale()) return;

  const errEl = h('span', { class: 'model-error', id: 'model-error' });
  const ladderEl = h('div', { id: 'ladder' });
  const kEl = h('div', { id: 'plot-k-change' });
  const fitEl = h('div', { id: 'plot-model' });
  const resEl = h('div', { id: 'plot-residual' });
  const rxEl = h('div', { id: 'plot-res-x' });
  const rvEl = h('div', { id: 'plot-res-v' });
  const spEl = h('div', { id: 'plot-spectrum' });
  const ssEl = h('div', { id: 'plot-small-signal' });
  const candBody = h('tbody', { id: 'candidates' });
  const modelEl = h('p', { id: 'model-effects' });
  // The fitted parameters of the effects in the current model, with their units.
  const paramsEl = h('div', { id: 'model-params' });
  const undo = h('button', { id: 'undo', disabled: true }, 'Remove the last effect');
  undo.addEventListener('click', () => {
    if (steps.length > 1) {
      const gone = steps.pop();
      current = steps.length - 1;
      status.className = 'status';
      status.textContent = `Removed ${gone.label.replace(/^\+ /, '')}: back to ${steps[current].label} (model error ${num(steps[current].error, 3)} %). The stored fit is kept; the measurement page chooses which fit is its headline.`;
      draw();
    }
  });

  put(
    main,
    h('section', { class: 'card' },
      h('h1', {}, 'Diagnostics workspace: measurement ', h('a', { href: `#/measurement/${id}`, class: 'mono' }, shortId(id)), ' of part ', h('span', { class: 'serial' }, info.part_serial || '?')),
      h('div', { class: 'toolbar' }, h('span', {}, 'Model error now: '), errEl, modelEl, undo),
      paramsEl,
      status),
    h('div', { class: 'diag-top' },
      h('section', { class: 'card' }, h('h2', {}, 'Model ladder'),
        h('p', { class: 'muted' }, 'Model error: RMS of the residual that is not noise, on held-out data, in % of RMS(m\u00b7x\u2033) (the inertial force).'),
        ladderEl),
      h('section', { class: 'card' }, h('h2', {}, 'K(x) before and after the last step'), kEl)),
    h('section', { class: 'card', id: 'diag-candidates' }, h('h2', {}, 'Candidate effects (tested against the current model)'),
      h('table', { class: 'list candidates' },
        h('thead', {}, h('tr', {}, h('th', {}, 'effect'), h('th', {}, 'error reduction'), h('th', {}, 'significant'), h('th', {}, 'parameters \u00b1 standard error'), h('th', {}, 'notes'), h('th', {}, ''))),
        candBody)),
    memoryCard(doc, ctx),
    h('section', { class: 'card', id: 'diag-time' }, h('h2', {}, 'Model against measurement (largest excursion), residual beneath on the same time axis'), fitEl, resEl),
    h('section', { class: 'card', id: 'diag-residuals' }, h('div', { class: 'plot-grid' }, rxEl, rvEl)),
    h('section', { class: 'card', id: 'diag-spectra' }, h('div', { class: 'plot-grid' }, spEl, ssEl)),
  );

  async function addEffect(effect, button) {
    const effects = [...steps[current].effects, effect];
    button.disabled = true;
    status.className = 'status';
    status.textContent = `Refitting with ${effects.map(effectName).join(', ')}\u2026`;
    try {
      const fit = await api(`/api/v1/measurements/${encodeURIComponent(id)}/fits`, { method: 'POST', body: { effects } });
      if (ctx.stale()) return;
      const diag = (fit.result && fit.result.diagnostics) || fit.diagnostics;
      if (!diag) throw new Error('the fit returned no diagnostics');
      steps.splice(current + 1);
      steps.push(stepOf(diag, 'final', effects, fit.id));
      current = steps.length - 1;
      const a = steps[current - 1];
      const b = steps[current];
      status.textContent = `Added ${effectName(effect)}: model error ${num(a.error, 3)} % \u2192 ${num(b.error, 3)} % (fit ${shortId(fit.id)} stored).`;
      draw();
    } catch (e) {
      status.className = 'status error';
      status.textContent = `The refit failed: ${e.message}`;
      button.disabled = false;
    }
  }

  function drawLadder() {
    const items = steps.map((s, i) => ({ label: s.label, value: s.error, highlight: i === current && i > 0 }));
    bars(ladderEl, items, { unit: '%', floor: undefined });
    ladderEl.dataset.steps = String(steps.length);
    ladderEl.dataset.errors = steps.map((s) => num(s.error, 4)).join(',');
    const nf = steps[current].noiseFloor;
    ladderEl.append(h('p', { class: 'muted' }, `Noise floor (the residual the model cannot explain): ${num(nf, 3)} % of RMS(m\u00b7x\u2033). Residual including noise: ${num(steps[current].residual, 3)} %.`));
  }

  function drawK() {
    const s = steps[current];
    const prev = steps[Math.max(0, current - 1)];
    const xs = linspace(lo - 0.25 * (hi - lo), hi + 0.25 * (hi - lo), 241);
    const series = [{ label: `K(x), ${s.label}`, unit: 'N/mm', color: '#2ca02c', width: 2 }];
    const data = [xs, xs.map((x) => poly(s.k, x))];
    if (current > 0) {
      series.unshift({ label: `K(x), ${prev.label}`, unit: 'N/mm', color: '#d62728', dash: true });
      data.splice(1, 0, xs.map((x) => poly(prev.k, x)));
      series.push({ label: 'change (right axis)', unit: 'N/mm', color: '#999', width: 1, y2: true });
      data.push(xs.map((x) => poly(s.k, x) - poly(prev.k, x)));
    }
    chart(kEl, {
      title: current > 0 ? `K(x) before and after ${s.label}` : 'K(x) of the base model',
      kind: 'K(x) change',
      x: { label: 'displacement x', unit: 'mm' },
      y: { label: 'stiffness K', unit: 'N/mm' },
      y2: current > 0 ? { label: 'change of K', unit: 'N/mm' } : undefined,
      series, data, validRange: [lo, hi], height: 240,
    });
  }

  function drawCandidates() {
    const s = steps[current];
    const cands = s.candidates.slice().sort((a, b) => b.error_reduction_percent - a.error_reduction_percent);
    put(candBody, cands.map((c) => {
      const params = Object.entries(c.parameters || {}).map(([k, v]) => {
        const se = (c.parameters_se || {})[k];
        const d = effectParam(c.effect, k);
        return h('div', { title: k }, `${d.label} = ${withSe(v, se, d.unit, d.scale)}`);
      });
      const already = s.effects.includes(c.effect);
      const btn = ctx.can('operator') && !already
        ? h('button', { class: c.significant ? 'primary' : '', dataset: { effect: c.effect }, id: `add-${c.effect}` }, 'Add this effect')
        : null;
      if (btn) btn.addEventListener('click', () => addEffect(c.effect, btn));
      const notes = [];
      if (c.note) notes.push(h('div', { class: 'note' }, c.note));
      else if (!c.identifiable) notes.push(h('div', { class: 'note' }, `cannot tell apart from ${c.collinear_with}`));
      if (c.significant && c.collinear_with && c.variance_inflation > 10) notes.push(h('div', { class: 'muted' }, `partly collinear with ${c.collinear_with} (variance inflation ${num(c.variance_inflation, 3)})`));
      return h('tr', { class: c.significant ? 'significant' : '', dataset: { effect: c.effect, significant: String(c.significant) } },
        h('td', { title: c.effect }, effectName(c.effect)),
        h('td', { class: 'num' }, `${num(c.error_reduction_percent, 3)} %`),
        h('td', {}, c.significant ? `yes (p = ${num(c.p_value, 2)})` : `no (p = ${num(c.p_value, 2)}, needs < ${num(c.alpha, 2)})`),
        h('td', {}, params),
        h('td', {}, notes),
        h('td', {}, already ? h('span', { class: 'muted' }, 'in the model') : btn || h('span', { class: 'muted' }, ctx.can('operator') ? '' : 'operator role needed')));
    }));
  }

  function drawTime() {
    const s = steps[current];
    const res = s.measured.map((m, i) => m - s.model[i]);
    chart(fitEl, {
      title: `Force balance: measured m\u00b7x\u2033 and the model (${s.label})`, kind: 'model vs measurement',
      x: { label: 'time', unit: 's' }, y: { label: 'force', unit: 'N' },
      series: [{ label: 'measured m\u00b7x\u2033', unit: 'N' }, { label: `model (${s.label})`, unit: 'N', color: '#d62728', dash: true }],
      data: [s.t, s.measured, s.model], sync: 'diag-time', height: 220,
    });
    chart(resEl, {
      title: `Residual = measured \u2212 model${Number.isFinite(s.noiseRms) ? ' (shaded: \u00b1 noise RMS)' : ''}`, kind: 'residual over time',
      x: { label: 'time', unit: 's' }, y: { label: 'residual', unit: 'N', symmetric: true },
      series: [{ label: 'residual', unit: 'N', color: '#555' }],
      data: [s.t, res], sync: 'diag-time', height: 180,
      hBands: Number.isFinite(s.noiseRms) ? [{ from: -s.noiseRms, to: s.noiseRms }] : [],
    });
  }

  function drawResiduals() {
    const s = steps[current];
    const xmm = s.rxX.map((v) => v * 1e3);
    const bx = noiseBand(s.noiseRms, s.rxCount && s.rxCountNeg ? s.rxCount.map((c, i) => Math.min(c, s.rxCountNeg[i])) : null, xmm.length);
    const sx = [{ label: 'v > 0', unit: 'N' }, { label: 'v < 0', unit: 'N', color: '#d62728' }];
    const dx = [xmm, s.rxPos, s.rxNeg];
    if (bx) {
      sx.push({ label: 'noise band +2\u03c3', unit: 'N', color: '#2ca02c', dash: true }, { label: '\u22122\u03c3', unit: 'N', color: '#2ca02c', dash: true });
      dx.push(bx, bx.map((v) => (v === null ? null : -v)));
    }
    chart(rxEl, {
      title: `Mean residual against displacement (${s.label})`, kind: 'residual vs x',
      x: { label: 'displacement x', unit: 'mm' }, y: { label: 'mean residual force', unit: 'N' },
      series: sx, data: dx, height: 240,
    });
    const bv = noiseBand(s.noiseRms, s.rvCount, s.rvV.length);
    const sv = [{ label: 'mean residual', unit: 'N' }];
    const dv = [s.rvV, s.rvMean];
    if (bv) {
      sv.push({ label: 'noise band +2\u03c3', unit: 'N', color: '#2ca02c', dash: true }, { label: '\u22122\u03c3', unit: 'N', color: '#2ca02c', dash: true });
      dv.push(bv, bv.map((v) => (v === null ? null : -v)));
    }
    chart(rvEl, {
      title: `Mean residual against velocity (${s.label})`, kind: 'residual vs v',
      x: { label: 'velocity v', unit: 'm/s' }, y: { label: 'mean residual force', unit: 'N' },
      series: sv, data: dv, height: 240,
    });
  }

  function drawSpectrum() {
    const s = steps[current];
    if (!s.spP) {
      put(spEl, h('p', { class: 'muted' }, 'No residual spectrum of this model in the diagnostics document.'));
      return;
    }
    const bands = s.bands.map((b, i) => ({ from: b[0], to: b[1], label: `${i + 1}f`, fill: i % 2 ? 'rgba(240,200,80,0.22)' : 'rgba(240,200,80,0.36)' }));
    chart(spEl, {
      title: `Residual spectrum (${s.label}); shaded: harmonics 1f, 2f, \u2026 of the swept fundamental`, kind: 'residual spectrum',
      x: { label: 'frequency', unit: 'Hz', log: true }, y: { label: 'PSD', unit: 'N\u00b2/Hz', log: true, maxDecades: 6 },
      series: [{ label: 'residual', unit: 'N\u00b2/Hz' }, { label: 'noise floor', unit: 'N\u00b2/Hz', color: '#2ca02c', dash: true }],
      data: [s.spF, s.spP, s.spNoise], xBands: bands, height: 260,
    });
  }

  function drawSmallSignal() {
    const ss = steps[0].small;
    if (!ss || !ss.freq_hz) {
      put(ssEl, h('p', { class: 'muted' }, 'No small-signal transfer function (no usable pre-measurement).'));
      return;
    }
    chart(ssEl, {
      title: `Small signal: |X/Mic| of the pre-measurement and the resonator fit (misfit ${num(ss.misfit_percent, 3)} %${ss.reliable ? '' : ', unreliable'})`,
      kind: 'small signal',
      x: { label: 'frequency', unit: 'Hz', log: true }, y: { label: '|Hx|', unit: 'm/V', log: true },
      series: [{ label: 'measured', unit: 'm/V' }, { label: 'linear fit', unit: 'm/V', color: '#d62728', dash: true }],
      data: [ss.freq_hz, ss.measured_abs_m_per_v, ss.fit_abs_m_per_v], height: 260,
    });
  }

  function drawParams() {
    const s = steps[current];
    const ids = Object.keys(s.params || {});
    paramsEl.dataset.effects = ids.join(',');
    if (!ids.length) {
      put(paramsEl);
      return;
    }
    put(paramsEl, h('span', { class: 'muted' }, 'Fitted parameters \u00b1 standard error: '),
      ids.map((e, n) => h('span', { class: 'model-effect', dataset: { effect: e } }, n ? '; ' : '', h('b', {}, effectName(e)), ' ',
        Object.entries(s.params[e] || {}).map(([k, v], i) => {
          const d = effectParam(e, k);
          const se = ((s.paramsSe || {})[e] || {})[k];
          return h('span', { class: 'param', title: `${e}.${k}`, dataset: { param: k, si: String(v) } }, `${i ? ', ' : ''}${d.label} = ${withSe(v, se, d.unit, d.scale)}`);
        }))));
  }

  function draw() {
    const s = steps[current];
    errEl.textContent = `${num(s.error, 3)} %`;
    errEl.dataset.si = String(s.error);
    put(modelEl, s.effects.length ? `effects in the model: ${s.effects.map(effectName).join(', ')}` : 'base model (no extra effects)');
    drawParams();
    undo.disabled = steps.length < 2 || !ctx.can('operator');
    drawLadder();
    drawK();
    drawCandidates();
    drawTime();
    drawResiduals();
    drawSpectrum();
    drawSmallSignal();
  }

  const sig = steps[current].candidates.filter((c) => c.significant).map((c) => effectName(c.effect));
  status.textContent = opened
    ? `Opened on the headline fit ${shortId(opened.id)} (${steps[current].label.replace(/^\+ /, '')}), chosen by ${info.headline.chosen_by || 'open access'}.`
    : sig.length
    ? `The base model misses something: significant candidates ${sig.join(', ')}.${ctx.can('operator') ? ' Add one to refit.' : ''}`
    : 'No candidate effect is significant: the base model explains the measurement down to the noise.';
  draw();
}

/**
 * The material's memory (issue 33): the two experiments that tell its
 * effects apart, started for this part on the bench that measured it
 * (the study form filled in with the measurement's part, bench, moving
 * mass and level).
 */
function memoryCard(doc, ctx) {
  const info = doc.measurement || {};
  const ls = doc.large_signal || {};
  const ss = doc.small_signal || {};
  if (!info.bench_id || !info.part_serial) return null;
  const ps = new URLSearchParams({ serial: info.part_serial, bench: info.bench_id });
  if (Number.isFinite(ls.moving_mass_kg)) ps.set('mass_g', String(Number((ls.moving_mass_kg * 1e3).toPrecision(6))));
  const level = [info.target_xpeak_m, ls.target_xpeak_m, ls.xpeak_m].find(Number.isFinite);
  if (Number.isFinite(level)) ps.set('level_mm', String(Number((level * 1e3).toPrecision(4))));
  if (Number.isFinite(ss.f0_hz)) ps.set('f0_hz', String(Number(ss.f0_hz.toPrecision(4))));
  const link = (kind, id, text) => {
    const q = new URLSearchParams(ps);
    q.set('kind', kind);
    return h('a', { href: `#/study?${q}`, id, class: 'button' }, text);
  };
  return h('section', { class: 'card', id: 'diag-memory' },
    h('h2', {}, 'The material\u2019s memory: experiments that tell its effects apart'),
    h('p', { class: 'muted' }, 'Hysteresis, creep and a reversible softening can explain the same sweep. An added-mass study (the same part with a second mass on the slide) splits the stiffness change into a frequency-dependent share (creep) and an amplitude-dependent one (softening); a recovery measurement gives the softening\u2019s depth and time constant.'),
    ctx.can('operator')
      ? h('p', { class: 'toolbar' }, link('added_mass', 'start-added-mass', `Added-mass study of ${info.part_serial} on ${info.bench_id}`), ' ', link('recovery', 'start-recovery', `Recovery measurement of ${info.part_serial} on ${info.bench_id}`))
      : h('p', { class: 'muted' }, 'Starting a study needs the operator role.'));
}
