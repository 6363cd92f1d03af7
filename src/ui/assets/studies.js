// The material's memory (issue 33, decision 0142): the two studies of a part
// on a bench, started and watched from the UI.
//
// `#/study?serial=&bench=&mass_g=&level_mm=&kind=` is the form (the
// diagnostics workspace and the part page open it with the part's figures
// filled in); `#/study/<id>` is one study: its state, the operator's prompt
// while an added-mass study waits for the mass (confirm calls POST
// /api/v1/studies/{id}/confirm), cancel (POST /api/v1/jobs/{id}/cancel), and
// the result with units: the recovery's depth (N/m²) and time constant (s)
// with its misfit, the added-mass study's derived mass (kg) and the
// attribution's frequency- and amplitude-dependent shares (N/m) at the
// resonances (Hz). A value that means nothing (no softening found) shows its
// state where the number would be. The API's refusals name their fields,
// beside the inputs.

import { api } from './api.js';
import { h, put, num, shortId, row, stated, effectName, effectParam, withSe, linspace, foldRepeatedReasons } from './util.js';
import { chart } from './plots.js';

const TERMINAL = ['succeeded', 'failed', 'cancelled', 'interrupted'];
const POLL_MS = 500;

/** What the study's own state means for the operator. */
const STATE_TEXT = {
  measuring: 'measuring the part',
  awaiting_operator: 'waiting for the operator',
  confirmed: 'confirmed: measuring with the added mass',
  succeeded: 'done',
  failed: 'failed',
};

const cap = (t) => t.charAt(0).toUpperCase() + t.slice(1);

const KIND_TEXT = { added_mass: 'added-mass study', recovery: 'recovery measurement' };

/** The recovery plan the form starts from (the paper's probes, decision 0117). */
export const RECOVERY_DEFAULTS = { excitation_hz: 30, excitation_v: 50, excitation_s: 2, probe_v: 1.5, delays_s: [0.5, 1, 2, 5, 10, 30] };

export async function render(main, ctx) {
  if (ctx.arg) return renderStudy(main, ctx, ctx.arg);
  return renderForm(main, ctx);
}

// --- the form -------------------------------------------------------------------

/** A number input with its label, unit and the request field it fills (for the API's field errors). */
function numberField(id, label, unit, field, value, attrs = {}) {
  const input = h('input', { id, type: 'number', step: 'any', required: true, value: value ?? '', dataset: { field }, ...attrs });
  const err = h('span', { class: 'field-error', id: `${id}-error` });
  return { input, err, cells: [h('label', { for: id }, `${label} (${unit})`), h('span', {}, input, err)] };
}

async function renderForm(main, ctx) {
  const p = ctx.params;
  if (!ctx.can('operator')) {
    put(main, h('section', { class: 'card' }, h('h1', {}, 'Study a part\u2019s memory'), h('p', { class: 'error', id: 'study-role' }, `A study runs on a bench: the operator role is needed (yours: ${ctx.role}).`)));
    return;
  }
  const benches = ((await api('/api/v1/benches')).items || []).map((b) => b.id);
  if (ctx.stale()) return;
  const kind = h('select', { id: 'study-kind', dataset: { field: 'plan' } },
    h('option', { value: 'added_mass' }, 'added-mass study: frequency- or amplitude-dependent?'),
    h('option', { value: 'recovery' }, 'recovery measurement: depth and time constant of the softening'));
  if (p.get('kind') === 'recovery') kind.value = 'recovery';
  const serial = h('input', { id: 'study-serial', required: true, autocomplete: 'off', value: p.get('serial') || '', dataset: { field: 'part_serial' } });
  const serialErr = h('span', { class: 'field-error', id: 'study-serial-error' });
  const bench = h('select', { id: 'study-bench', dataset: { field: 'bench' } }, benches.map((b) => h('option', { value: b }, b)));
  if (benches.includes(p.get('bench'))) bench.value = p.get('bench');
  const benchErr = h('span', { class: 'field-error', id: 'study-bench-error' });
  const mass = numberField('study-mass-g', 'Moving mass as weighed', 'g', 'moving_mass_kg', p.get('mass_g'), { min: '0', title: 'part and inner clamp' });
  const added = numberField('study-added-g', 'Added mass', 'g', 'plan.added_mass.added_mass_kg', p.get('added_g') || '20', { min: '0' });
  const level = numberField('study-level-mm', 'Target Xpeak of both runs', 'mm', 'plan.added_mass.level_m', p.get('level_mm') || '4', { min: '0' });
  const d = RECOVERY_DEFAULTS;
  const exHz = numberField('study-ex-hz', 'Excitation frequency (near the resonance)', 'Hz', 'plan.recovery.excitation_hz', d.excitation_hz, { min: '0' });
  const exV = numberField('study-ex-v', 'Excitation amplitude', 'V', 'plan.recovery.excitation_v', d.excitation_v, { min: '0' });
  const exS = numberField('study-ex-s', 'Excitation duration', 's', 'plan.recovery.excitation_s', d.excitation_s, { min: '0' });
  const prV = numberField('study-probe-v', 'Probe amplitude (small signal)', 'V', 'plan.recovery.probe_v', d.probe_v, { min: '0' });
  const delays = h('input', { id: 'study-delays', required: true, value: d.delays_s.join(', '), dataset: { field: 'plan.recovery.delays_s' }, title: 'seconds after the excitation, comma-separated' });
  const delaysErr = h('span', { class: 'field-error', id: 'study-delays-error' });
  const addedBox = h('div', { class: 'form-grid', id: 'study-added-fields' }, added.cells, level.cells);
  const f0 = Number(p.get('f0_hz'));
  const recBox = h('div', { class: 'form-grid', id: 'study-recovery-fields' },
    Number.isFinite(f0) && f0 > 0 ? [h('span', {}, ''), h('span', { class: 'muted', id: 'study-f0' }, `the part\u2019s small-signal resonance: ${num(f0, 4)} Hz (the probes sit at about 0.5 and 0.8 of the excitation frequency)`)] : null,
    exHz.cells, exV.cells, exS.cells, prV.cells,
    h('label', { for: 'study-delays' }, 'Probes after the excitation (s)'), h('span', {}, delays, delaysErr));
  const msg = h('div', { id: 'study-msg', role: 'status' });
  const show = () => {
    const am = kind.value === 'added_mass';
    addedBox.hidden = !am;
    recBox.hidden = am;
    for (const i of addedBox.querySelectorAll('input')) i.disabled = !am;
    for (const i of recBox.querySelectorAll('input')) i.disabled = am;
  };
  kind.addEventListener('change', show);
  const form = h('form', { id: 'study-form', class: 'card submit', autocomplete: 'off' },
    h('h1', {}, 'Study a part\u2019s memory'),
    h('p', { class: 'muted' }, 'The added-mass study measures the part, asks the operator to add a known mass to the slide, waits for the confirmation, and measures again: the stiffness change that follows the lower resonance is frequency-dependent (creep, viscoelastic), the one that follows the excursion amplitude-dependent (reversible softening). The recovery measurement drives the part hard, then probes it with small signals while it recovers.'),
    h('div', { class: 'form-grid' },
      h('label', { for: 'study-kind' }, 'Study'), kind,
      h('label', { for: 'study-serial' }, 'Part serial'), h('span', {}, serial, serialErr),
      h('label', { for: 'study-bench' }, 'Bench'), h('span', {}, bench, benchErr),
      mass.cells),
    addedBox, recBox,
    h('button', { type: 'submit', id: 'study-submit', class: 'primary' }, 'Start the study'),
    msg);
  put(main, form);
  show();
  (serial.value ? mass.input : serial).focus();

  const fieldErrors = [serialErr, benchErr, mass.err, added.err, level.err, exHz.err, exV.err, exS.err, prV.err, delaysErr];
  form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    for (const e of fieldErrors) e.textContent = '';
    for (const i of form.querySelectorAll('[aria-invalid]')) i.removeAttribute('aria-invalid');
    msg.className = '';
    msg.textContent = '';
    const g = (i) => (i.value.trim() === '' ? NaN : Number(i.value));
    const plan = kind.value === 'added_mass'
      ? { added_mass: { added_mass_kg: g(added.input) / 1e3, level_m: g(level.input) / 1e3 } }
      : {
          recovery: {
            excitation_hz: g(exHz.input),
            excitation_v: g(exV.input),
            excitation_s: g(exS.input),
            probe_v: g(prV.input),
            delays_s: delays.value.split(/[,;\s]+/).filter((s) => s).map(Number),
          },
        };
    const body = { bench: bench.value, part_serial: serial.value.trim(), moving_mass_kg: g(mass.input) / 1e3, plan };
    const btn = document.getElementById('study-submit');
    btn.disabled = true;
    try {
      const v = await api('/api/v1/studies', { method: 'POST', body });
      location.hash = `#/study/${encodeURIComponent(v.id)}`;
    } catch (e) {
      btn.disabled = false;
      msg.className = 'error';
      const errs = (e.problem && e.problem.errors) || [];
      // Each refused field beside its input; the whole list below the button.
      for (const fe of errs) {
        const input = [...form.querySelectorAll('[data-field]')].find((i) => i.dataset.field === fe.field);
        if (!input) continue;
        input.setAttribute('aria-invalid', 'true');
        const out = document.getElementById(`${input.id}-error`);
        if (out) out.textContent = `${fe.field}: ${fe.message}`;
      }
      put(msg, h('p', {}, `The daemon refused the study${e.status ? ` (${e.status})` : ''}:`),
        errs.length
          ? h('ul', { id: 'study-errors' }, errs.map((fe) => h('li', { dataset: { field: fe.field || '' } }, fe.field ? `${fe.field}: ${fe.message}` : fe.message)))
          : h('p', { id: 'study-errors' }, e.message));
    }
  });
}

// --- one study -------------------------------------------------------------------

/** The operator's prompt of an added-mass study, from the request (the API's added mass in kg). */
export function promptText(s) {
  // A study view and a job both carry the request as `request`.
  const r = s.request || {};
  const am = (r.plan || {}).added_mass || {};
  return `Add ${num(am.added_mass_kg * 1e3, 4)} g to the slide of bench \u2018${r.bench}\u2019 (part ${r.part_serial}), then confirm.`;
}

async function renderStudy(main, ctx, id) {
  const head = h('section', { class: 'card', id: 'study-head' }, h('h1', {}, 'Study ', h('span', { class: 'mono' }, shortId(id))));
  const stateEl = h('p', { id: 'study-state', role: 'status' });
  const promptEl = h('section', { class: 'card prompt', id: 'study-prompt', hidden: true });
  const cancel = h('button', { id: 'study-cancel', class: 'danger', hidden: true }, 'Cancel the study');
  const msg = h('p', { id: 'study-action-msg', role: 'status' });
  const resultEl = h('div', { id: 'study-result' });
  put(main, head, promptEl, h('section', { class: 'card' }, stateEl, cancel, msg), resultEl);
  let timer = null;
  let drawnResult = false;
  let confirming = false;

  cancel.addEventListener('click', async () => {
    const ok = await ctx.confirm('Cancel this study? The bench stops; a study cannot be resumed (submit it again).', { yes: 'Yes, cancel the study', no: 'Keep it' });
    if (!ok) return;
    cancel.disabled = true;
    try {
      await api(`/api/v1/jobs/${encodeURIComponent(id)}/cancel`, { method: 'POST' });
      msg.className = 'status';
      msg.textContent = 'Cancel requested: the bench stops.';
    } catch (e) {
      msg.className = 'error';
      msg.textContent = `The cancel was refused: ${e.message}`;
      cancel.disabled = false;
    }
    tick();
  });

  async function confirm(btn) {
    if (confirming) return;
    confirming = true;
    btn.disabled = true;
    try {
      await api(`/api/v1/studies/${encodeURIComponent(id)}/confirm`, { method: 'POST' });
      msg.className = 'status';
      msg.textContent = 'Confirmed: the study measures the part with the added mass.';
    } catch (e) {
      msg.className = 'error';
      msg.textContent = `The confirmation was refused: ${e.message}`;
      btn.disabled = false;
    }
    confirming = false;
    tick();
  }

  function draw(s) {
    const r = s.request || {};
    const done = TERMINAL.includes(s.job_state);
    main.dataset.studyState = s.state || 'queued';
    main.dataset.jobState = s.job_state;
    put(head,
      h('h1', {}, `${cap(KIND_TEXT[s.kind] || s.kind)} `, h('span', { class: 'mono' }, shortId(s.id)), ' of part ', h('a', { href: `#/part/${encodeURIComponent(r.part_serial)}`, class: 'serial' }, r.part_serial)),
      h('p', { class: 'muted' }, `bench ${r.bench}${r.preset ? `, preset ${r.preset}` : ''}; moving mass as weighed ${num(r.moving_mass_kg * 1e3, 4)} g (${num(r.moving_mass_kg, 4)} kg)`, planText(r.plan)));
    // A study stopped by a cancel or a daemon stop says so (its own state reads `failed`).
    const words = s.job_state === 'cancelled' ? 'cancelled: no result'
      : s.job_state === 'interrupted' ? 'interrupted (the daemon stopped): no result; submit the study again'
      : s.state ? STATE_TEXT[s.state] || s.state : 'queued on its bench';
    put(stateEl, h('span', { class: `badge state-${s.job_state}`, id: 'study-job-state' }, s.job_state), ' ',
      h('span', { id: 'study-step', dataset: { state: s.state || '' } }, words),
      s.confirmed_by ? h('span', { class: 'muted' }, ` (confirmed by ${s.confirmed_by})`) : null);
    cancel.hidden = done || !ctx.can('operator');
    // The operator's step: the prompt and the confirm button while the study waits.
    const waiting = s.state === 'awaiting_operator' && !done;
    promptEl.hidden = !waiting;
    if (waiting && !promptEl.dataset.shown) {
      promptEl.dataset.shown = '1';
      const btn = h('button', { id: 'study-confirm', class: 'primary big' }, 'The mass is on: confirm');
      btn.addEventListener('click', () => confirm(btn));
      put(promptEl,
        h('h2', {}, 'Operator: add the mass'),
        h('p', { class: 'prompt-text', id: 'study-prompt-text', dataset: { addedKg: String(((r.plan || {}).added_mass || {}).added_mass_kg) } }, promptText(s)),
        h('p', { class: 'muted' }, 'The study waits until you confirm; the second run measures the part with the mass at the same level.'),
        ctx.can('operator') ? btn : h('p', { class: 'error' }, `Confirming needs the operator role (yours: ${ctx.role}).`));
      if (ctx.can('operator')) btn.focus();
    }
    if (!waiting) delete promptEl.dataset.shown;
    if (done && s.job_state === 'failed') {
      put(resultEl, h('section', { class: 'card' }, h('p', { class: 'error', id: 'study-problem' }, `The study failed: ${(s.problem && (s.problem.detail || s.problem.title)) || 'no reason given'}`)));
    } else if (done && !s.result && s.job_state !== 'succeeded') {
      put(resultEl, h('section', { class: 'card' }, h('p', { class: 'error', id: 'study-ended' }, `The study was ${s.job_state}: no result.${s.problem && s.problem.detail ? ` ${s.problem.detail}` : ''}`)));
    }
    if (s.result && !drawnResult) {
      drawnResult = true;
      put(resultEl, s.result.kind === 'recovery' ? recoveryResult(s.result) : addedMassResult(s.result));
    }
    return done;
  }

  async function tick() {
    clearTimeout(timer);
    let s;
    try {
      s = await api(`/api/v1/studies/${encodeURIComponent(id)}`);
    } catch (e) {
      if (ctx.stale()) return;
      msg.className = 'error';
      msg.textContent = `Cannot read the study: ${e.message}`;
      if (e.status !== 404) timer = setTimeout(tick, 2000);
      return;
    }
    if (ctx.stale()) return;
    const done = draw(s);
    if (!done && !ctx.stale()) timer = setTimeout(tick, POLL_MS);
  }
  await tick();
  return () => clearTimeout(timer);
}

function planText(plan) {
  if (!plan) return '';
  if (plan.added_mass) return `; ${num(plan.added_mass.added_mass_kg * 1e3, 4)} g added at ${num(plan.added_mass.level_m * 1e3, 3)} mm`;
  const p = plan.recovery || {};
  return `; excitation ${num(p.excitation_hz, 4)} Hz at ${num(p.excitation_v, 4)} V for ${num(p.excitation_s, 3)} s, probes at ${num(p.probe_v, 3)} V after ${(p.delays_s || []).map((t) => num(t, 3)).join(', ')} s`;
}

/** A number with its unit, `data-si` its SI value (the page's figure for the tests and for copying). */
function val(id, v, unit, digits = 4, scale = 1) {
  return h('span', { id, class: 'value', dataset: { si: String(v) } }, Number.isFinite(v) ? `${num(v * scale, digits)}${unit ? ` ${unit}` : ''}` : '\u2013');
}

/** The standard error beside a value (" \u00b1 120 N/m\u00b2 (standard error)"); nothing when the result has none (stored before it was computed). */
function seOf(id, se, unit) {
  if (!Number.isFinite(se)) return null;
  return h('span', { class: 'se' }, ' \u00b1 ', h('span', { id, class: 'value', dataset: { si: String(se) } }, `${num(se, 2)} ${unit}`), ' (standard error)');
}

// --- the recovery's result ---------------------------------------------------------

function recoveryResult(r) {
  // Depth and tau mean something only when the part softened (decision 0117).
  const v = r.softening_found
    ? { state: 'valid' }
    : { state: 'not_determined', reason: `no reversible softening found: the drop of K is within five times the recovery law\u2019s misfit (${num(r.misfit_n_per_m, 3)} N/m) or 0.5 % of K, so depth and time constant mean nothing`, fit_value: undefined };
  const plot = h('div', { id: 'plot-recovery' });
  const pts = r.points || [];
  const card = h('section', { class: 'card', id: 'recovery-result', dataset: { found: String(!!r.softening_found) } },
    h('h2', {}, 'Recovery of the stiffness'),
    h('p', { id: 'recovery-found', class: r.softening_found ? '' : 'error' }, r.softening_found
      ? 'The part softens reversibly: K(0) falls after the large excitation and recovers with the time constant below.'
      : 'No reversible softening found.'),
    foldRepeatedReasons(h('table', { class: 'kv', id: 'recovery-figures' },
      row('depth (K(0) drop per m of the excitation\u2019s peak excursion)', stated(h('span', {}, val('rec-depth', r.depth_n_per_m2, 'N/m\u00b2'), seOf('rec-depth-se', r.depth_se_n_per_m2, 'N/m\u00b2')), v, { unit: 'N/m\u00b2', raw: r.depth_n_per_m2 })),
      row('time constant of the recovery', stated(h('span', {}, val('rec-tau', r.tau_s, 's'), seOf('rec-tau-se', r.tau_se_s, 's')), v, { unit: 's', raw: r.tau_s })),
      row('drop of K(0) when the excitation ends', stated(h('span', {}, val('rec-drop', r.depth_n_per_m, 'N/m'), seOf('rec-drop-se', r.depth_se_n_per_m, 'N/m')), v, { unit: 'N/m', raw: r.depth_n_per_m })),
      row('misfit of the recovery law (RMS)', val('rec-misfit', r.misfit_n_per_m, 'N/m')),
      row('K(0) once recovered', val('rec-k', r.k_recovered_n_per_m, 'N/mm', 4, 1e-3)),
      row('peak excursion of the excitation', val('rec-xpeak', r.excitation_peak_m, 'mm', 4, 1e3)),
      row('damping of the probes', val('rec-r', r.r_ns_per_m, 'N\u00b7s/m')),
      row('probes', String(pts.length)))),
    plot,
    h('table', { class: 'list', id: 'recovery-points' },
      h('thead', {}, h('tr', {}, h('th', {}, 't after the excitation (s)'), h('th', {}, 'K (N/mm)'), h('th', {}, 'peak excursion (mm)'))),
      h('tbody', {}, pts.map((p) => h('tr', {}, h('td', { class: 'num' }, num(p.t_s, 3)), h('td', { class: 'num' }, num(p.k_n_per_m * 1e-3, 5)), h('td', { class: 'num' }, num(p.x_peak_m * 1e3, 3)))))));
  if (pts.length) {
    const tmax = Math.max(...pts.map((p) => p.t_s));
    const ts = linspace(0, tmax, 200);
    const law = (t) => (r.k_recovered_n_per_m - r.depth_n_per_m * Math.exp(-t / r.tau_s)) * 1e-3;
    const series = [{ label: 'probes', unit: 'N/mm', points: 'only' }];
    const data = [[...new Set(ts.concat(pts.map((p) => p.t_s)))].sort((a, b) => a - b)];
    const at = new Map(pts.map((p) => [p.t_s, p.k_n_per_m * 1e-3]));
    data.push(data[0].map((t) => (at.has(t) ? at.get(t) : null)));
    if (r.softening_found) {
      series.push({ label: `K(t) = K\u221e \u2212 depth\u00b7exp(\u2212t/\u03c4), \u03c4 = ${num(r.tau_s, 3)} s`, unit: 'N/mm', color: '#d62728', spanGaps: true });
      data.push(data[0].map(law));
    }
    // Drawn once the card is on the page (the chart needs its width).
    requestAnimationFrame(() => chart(plot, {
      title: 'K(0) of the probes after the large excitation', kind: 'recovery',
      x: { label: 'time after the excitation', unit: 's' }, y: { label: 'stiffness K', unit: 'N/mm' },
      series, data, height: 240,
    }));
  }
  return card;
}

// --- the added-mass study's result ---------------------------------------------------

function runRow(name, m) {
  return h('tr', {},
    h('th', {}, name),
    h('td', { class: 'num' }, `${num(m.mass_given_kg, 5)} kg`),
    h('td', { class: 'num' }, `${num(m.f0_hz, 4)} Hz`),
    h('td', { class: 'num' }, `${num(m.k0_given_mass_n_per_m * 1e-3, 4)} N/mm`),
    h('td', { class: 'num' }, `${num(m.keff_n_per_m * 1e-3, 4)} N/mm`),
    h('td', { class: 'num' }, `${num(m.resonance_hz, 4)} Hz`),
    h('td', { class: 'num' }, `${num(m.xpeak_m * 1e3, 4)} mm`));
}

/** The effects of a model with their parameters and units (`effects`: {id: {param: value}}). */
export function effectsList(effects, id) {
  const ids = Object.keys(effects || {});
  if (!ids.length) return h('p', { id, class: 'muted' }, 'no extra effect');
  return h('ul', { id, class: 'effects' }, ids.map((e) => h('li', { dataset: { effect: e } },
    h('b', {}, effectName(e)), ': ',
    Object.entries(effects[e] || {}).map(([k, x], i) => {
      const d = effectParam(e, k);
      return h('span', { class: 'param', dataset: { param: k, si: String(x) } }, `${i ? '; ' : ''}${d.label} = ${withSe(x, NaN, d.unit, d.scale)}`);
    }))));
}

function addedMassResult(r) {
  const a = r.attribution;
  const card = h('section', { class: 'card', id: 'added-mass-result' },
    h('h2', {}, 'Two masses'),
    h('table', { class: 'kv', id: 'added-mass-figures' },
      row('added mass', h('span', {}, val('am-added', r.added_mass_kg, 'kg', 4), ` (${num(r.added_mass_kg * 1e3, 4)} g)`)),
      row('moving mass from the two resonances', val('am-mass', r.moving_mass_derived_kg, 'kg', 4)),
      row('the weighed mass against it', val('am-weighed-error', r.weighed_mass_error_percent, '%', 3)),
      row('k0 from the derived mass', val('am-k0', r.k0_derived_n_per_m, 'N/mm', 4, 1e-3)),
      row('k0 with the weighed mass against it', val('am-k0-error', r.k0_given_mass_error_percent, '%', 3)),
      // Model-free: the runs' excursions differ a little, and a hardening K(x)
      // moves Keff by more than creep does (decision 0122); said beside it.
      row('Keff with the mass against Keff without (same target level, model-free)', h('span', {},
        val('am-keff-change', r.keff_change_with_frequency_percent, '%', 3),
        h('span', { class: 'muted', id: 'am-keff-note' }, ` Xpeak ${num(r.without.xpeak_m * 1e3, 4)} mm \u2192 ${num(r.with_mass.xpeak_m * 1e3, 4)} mm: Keff\u2019s change with the excursion is in this figure; the attribution below separates the causes`)))),
    h('table', { class: 'list', id: 'added-mass-runs' },
      h('thead', {}, h('tr', {}, ['run', 'mass given', 'f0 (small signal)', 'k0 with that mass', 'Keff', 'resonance (large signal)', 'Xpeak'].map((t) => h('th', {}, t)))),
      h('tbody', {}, runRow('without the added mass', r.without), runRow('with the added mass', r.with_mass))));
  const att = a
    ? h('section', { class: 'card', id: 'attribution' },
        h('h2', {}, 'Which cause the stiffness change goes to'),
        h('p', { class: 'muted' }, 'Both runs fitted as one part (one K(x), one set of effects; only the mass differs). Frequency-dependent: creep\u2019s stiffness at the second resonance minus at the first. Amplitude-dependent: the drop of K(0) after the runs\u2019 peak excursion (reversible softening). 0 when the joint model has no such cause.'),
        h('table', { class: 'kv', id: 'attribution-figures' },
          row('frequency-dependent (creep, viscoelastic)', h('span', {}, val('att-frequency', a.frequency_dependent_n_per_m, 'N/m'), a.effects && a.effects.creep ? '' : h('span', { class: 'muted' }, ' none found: no creep in the joint model'))),
          row('amplitude-dependent (reversible softening)', h('span', {}, val('att-amplitude', a.amplitude_dependent_n_per_m, 'N/m'), a.effects && a.effects.reversible_softening ? '' : h('span', { class: 'muted' }, ' none found: no softening in the joint model'))),
          row('between the resonances', h('span', { id: 'att-resonances', dataset: { si: (a.resonances_hz || []).join(',') } }, `${num(a.resonances_hz[0], 4)} Hz \u2192 ${num(a.resonances_hz[1], 4)} Hz`)),
          row('at the peak excursion', val('att-xpeak', a.xpeak_m, 'mm', 4, 1e3)),
          row('moving mass of the fit (corrected for creep)', val('att-mass', a.moving_mass_kg, 'kg', 4)),
          row('model error of the joint fit', val('att-model-error', a.model_error_percent, '%', 3)),
          row('the joint model\u2019s effects', effectsList(a.effects, 'att-effects'))),
        a.notes && a.notes.length ? h('ul', { id: 'attribution-notes' }, a.notes.map((n) => h('li', {}, n))) : null)
    : h('section', { class: 'card', id: 'attribution' }, h('p', { class: 'error', id: 'attribution-missing' }, 'No attribution: it could not be computed (the job\u2019s log says why).'));
  return [card, att];
}

/** A study's row in a part's job list: its kind (or null for another job). */
export function studyKind(job) {
  const r = job && job.request;
  if (!r || r.type !== 'study') return null;
  return r.plan && r.plan.added_mass ? 'added_mass' : 'recovery';
}

export { KIND_TEXT };
