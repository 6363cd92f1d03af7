// Small DOM and number helpers. Text always goes in as text (never as HTML).

/** Creates an element: h('div', {class: 'x', onclick: f}, 'text', child, ...). */
export function h(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith('on') && typeof v === 'function') e.addEventListener(k.slice(2), v);
    else if (k === 'dataset') Object.assign(e.dataset, v);
    else if (v === true) e.setAttribute(k, '');
    else e.setAttribute(k, String(v));
  }
  for (const c of children.flat(Infinity)) {
    if (c === undefined || c === null || c === false) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}

/** Replaces the children of `e`. */
export function put(e, ...children) {
  e.replaceChildren();
  for (const c of children.flat(Infinity)) {
    if (c === undefined || c === null || c === false) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}

/** An axis tick's label: 4 significant digits, or m e k beyond 1e4 and below 1e-3; '' for none. */
export function tickLabel(v) {
  // uPlot passes null for ticks it leaves unlabelled (too close together).
  if (v === null || v === undefined || !Number.isFinite(v)) return '';
  if (v === 0) return '0';
  const a = Math.abs(v);
  if (a >= 1e4 || a < 1e-3) {
    const e = Math.floor(Math.log10(a));
    const m = Number((v / 10 ** e).toPrecision(3));
    return `${m}e${e}`;
  }
  return String(Number(v.toPrecision(4)));
}

/** A number with `digits` significant digits, or an en dash. */
export function num(v, digits = 4) {
  if (v === undefined || v === null || !Number.isFinite(v)) return '\u2013';
  if (v === 0) return '0';
  const a = Math.abs(v);
  if (a >= 1e5 || a < 1e-3) return v.toExponential(digits - 1);
  return Number(v.toPrecision(digits)).toString();
}

/** A value with its unit ("3.92 N/mm"); scale multiplies first (SI -> display unit). */
export function q(v, unit, scale = 1, digits = 4) {
  if (v === undefined || v === null || !Number.isFinite(v)) return '\u2013';
  return `${num(v * scale, digits)} ${unit}`;
}

/**
 * The model error (the residual's part above the sensor noise) with its
 * unit. It is 0 when the residual is within the noise floor: then nothing
 * above the noise is left to explain, which is not the same as a perfect
 * model, so the residual and the noise floor are named beside it.
 */
export function modelErrorText(m, unit = '%', short = false) {
  const e = m ? m.model_error_percent : undefined;
  if (!Number.isFinite(e)) return '\u2013';
  const r = m.residual_percent;
  const n = m.noise_floor_percent;
  if (e === 0 && Number.isFinite(r) && Number.isFinite(n)) {
    if (short) return `0 ${unit} (\u2264 noise)`;
    return `0 ${unit}: the residual ${num(r, 4)} % is within the noise floor ${num(n, 4)} %`;
  }
  return `${num(e, 3)} ${unit}`;
}

/** Seconds as "1 min 05 s" / "12 s". */
export function dur(s) {
  if (s === undefined || s === null || !Number.isFinite(s)) return '\u2013';
  s = Math.max(0, Math.round(s));
  if (s < 60) return `${s} s`;
  return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, '0')} s`;
}

/** An ISO time as local "YYYY-MM-DD HH:MM:SS". */
export function when(iso) {
  if (!iso) return '\u2013';
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return iso;
  const p = (n) => String(n).padStart(2, '0');
  return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())} ${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}`;
}

export function shortId(id) {
  return id ? String(id).slice(0, 8) : '\u2013';
}

/** K(x) = sum k_i x^i (Horner). */
export function poly(c, x) {
  let y = 0;
  for (let i = c.length - 1; i >= 0; i--) y = y * x + c[i];
  return y;
}

/** F(x) = integral of K from 0 to x = sum k_i x^(i+1) / (i+1). */
export function polyIntegral(c, x) {
  let y = 0;
  for (let i = c.length - 1; i >= 0; i--) y = y * x + c[i] / (i + 1);
  return y * x;
}

/** n points from a to b. */
export function linspace(a, b, n) {
  const out = new Array(n);
  for (let i = 0; i < n; i++) out[i] = a + ((b - a) * i) / (n - 1);
  return out;
}

/** Reads `a.b.c` of an object, or the first of several such paths that exists. */
export function pick(obj, ...paths) {
  for (const p of paths) {
    let v = obj;
    for (const k of p.split('.')) {
      if (v === undefined || v === null) break;
      v = v[k];
    }
    if (v !== undefined && v !== null) return v;
  }
  return undefined;
}

/** A labelled row of a definition table. */
export function row(label, value) {
  return h('tr', {}, h('th', {}, label), h('td', {}, value));
}

// --- numbers and names for people ---------------------------------------------

/**
 * How an SI unit of the API is shown: N/m as N/mm, m as mm, "1" as no unit.
 * Returns {unit, scale} (display value = SI value * scale).
 */
export function displayUnit(si) {
  const u = String(si ?? '').trim();
  const map = {
    'N/m': ['N/mm', 1e-3],
    m: ['mm', 1e3],
    'm/N': ['mm/N', 1e3],
    'N s/m': ['N\u00b7s/m', 1],
    'N s^2/m^2': ['N\u00b7s\u00b2/m\u00b2', 1],
    'N s/m^2': ['N\u00b7s/m\u00b2', 1],
    'N s/m^3': ['N\u00b7s/m\u00b3', 1],
    'N/m^2': ['N/m\u00b2', 1],
    'N/(m s)': ['N/(mm\u00b7s)', 1e-3],
    'm/s': ['mm/s', 1e3],
    s: ['ms', 1e3],
    1: ['', 1],
    '': ['', 1],
  };
  const [unit, scale] = map[u] || [u, 1];
  return { unit, scale };
}

/** "3.92 N/mm" from an SI value and its SI unit ("1": no unit). */
export function siq(v, siUnit, digits = 4) {
  if (v === undefined || v === null || !Number.isFinite(v)) return '\u2013';
  const { unit, scale } = displayUnit(siUnit);
  return `${num(v * scale, digits)}${unit ? ` ${unit}` : ''}`;
}

/**
 * Limits as people write them: "3.1 \u2026 4.9 N/mm", one-sided "\u2264 0.1 N" or
 * "\u2265 2 N/mm", "no limits" (SI values and unit in).
 */
export function limitsText(lower, upper, siUnit) {
  const has = (x) => x !== undefined && x !== null && Number.isFinite(x);
  const { unit, scale } = displayUnit(siUnit);
  const u = unit ? ` ${unit}` : '';
  if (has(lower) && has(upper)) return `${num(lower * scale, 4)} \u2026 ${num(upper * scale, 4)}${u}`;
  if (has(upper)) return `\u2264 ${num(upper * scale, 4)}${u}`;
  if (has(lower)) return `\u2265 ${num(lower * scale, 4)}${u}`;
  return 'no limits';
}

/**
 * A value rounded to its uncertainty: the standard error to 2 significant
 * digits, the value to the same decimal place, the unit after the \u00b1
 * ("3.921 \u00b1 0.012 N/mm"). Without a finite uncertainty: 4 digits.
 */
export function withSe(v, se, unit = '', scale = 1) {
  if (v === undefined || v === null || !Number.isFinite(v)) return '\u2013';
  const u = unit ? ` ${unit}` : '';
  const x = v * scale;
  const s = Math.abs(se * scale);
  if (!Number.isFinite(s) || s === 0) return `${num(x, 4)}${u}`;
  const place = Math.floor(Math.log10(s)) - 1; // 2 significant digits of the error
  const r = (y) => {
    if (place >= 0) return String(Math.round(y / 10 ** place) * 10 ** place);
    return y.toFixed(Math.min(20, -place));
  };
  const a = Math.max(Math.abs(x), s);
  if (a >= 1e6 || a < 1e-4) {
    // Very large or small: a common power of ten.
    const e = Math.floor(Math.log10(a));
    const k = 10 ** e;
    return `(${withSe(x / k, s / k)}) \u00d7 10^${e}${u}`;
  }
  return `${r(x)} \u00b1 ${r(s)}${u}`;
}

/** Effects and their parameters as people name them, with display units. */
export const EFFECTS = {
  coulomb_friction: { name: 'dry (Coulomb) friction', params: { force_n: 'friction force', v_eps_m_per_s: 'smoothing velocity' } },
  quadratic_damping: { name: 'quadratic damping (v|v|)', params: { coeff_ns2_per_m2: 'coefficient' } },
  damping_vs_displacement: { name: 'damping varying with x', params: { r1_ns_per_m2: 'R slope (x)', r2_ns_per_m3: 'R curvature (x\u00b2)' } },
  creep: { name: 'creep (viscoelastic)', params: { k_n_per_m: 'creep stiffness', tau_s: 'time constant' } },
  stiffness_drift: { name: 'stiffness drift (warming)', params: { dk0_dt_n_per_m_s: 'drift of k0' } },
  channel_delay: { name: 'delay between channels', params: { delay_s: 'delay' } },
  hysteresis: { name: 'hysteresis (material memory)', params: { k_n_per_m: 'hysteretic stiffness', x_yield_m: 'yield excursion' } },
  // Recovers in seconds: its time constant in s, not ms (`units`: SI unit -> shown unit and scale).
  reversible_softening: { name: 'reversible softening (recovers in seconds)', params: { depth_n_per_m2: 'K(0) drop per m of excursion', tau_s: 'recovery time' }, units: { tau_s: ['s', 1] } },
  stiffness_order: { name: 'higher K(x) order', params: {} },
};

export function effectName(e) {
  return (EFFECTS[e] && EFFECTS[e].name) || String(e).replace(/_/g, ' ');
}

/** SI unit of an effect parameter from its name's suffix (force_n -> N). */
export function unitOfParam(name) {
  const suffixes = [
    ['_ns2_per_m2', 'N s^2/m^2'],
    ['_ns_per_m3', 'N s/m^3'],
    ['_ns_per_m2', 'N s/m^2'],
    ['_n_per_m_s', 'N/(m s)'],
    ['_n_per_m2', 'N/m^2'],
    ['_n_per_m', 'N/m'],
    ['_m_per_s', 'm/s'],
    ['_n', 'N'],
    ['_s', 's'],
    ['_m', 'm'],
  ];
  const f = suffixes.find(([s]) => name.endsWith(s));
  return f ? f[1] : '1';
}

/** {label, unit, scale} of an effect parameter ("friction force", "N", 1). */
export function effectParam(effect, name) {
  const e = EFFECTS[effect];
  const label = (e && e.params[name]) || name.replace(/_/g, ' ');
  const own = e && e.units && e.units[name];
  return { label, ...(own ? { unit: own[0], scale: own[1] } : displayUnit(unitOfParam(name))) };
}

/** A judged parameter's label: the recipe's name; a K(x) mask point names its x. */
export function paramLabel(p) {
  if (p.name === 'kx_mask' || p.quantity === 'kx_mask') {
    return `K(x) mask${Number.isFinite(p.x_m) ? ` at ${num(p.x_m * 1e3, 3)} mm` : ''}`;
  }
  return p.name;
}

/** Verdict words as a station shows them. */
export const VERDICT_WORDS = { pass: 'PASS', fail: 'FAIL', invalid: 'INVALID', no_limits: 'NO LIMITS' };

const SUPERSCRIPT = { 2: '\u00b2', 3: '\u00b3', 4: '\u2074', 5: '\u2075', 6: '\u2076', 7: '\u2077', 8: '\u2078', 9: '\u2079' };

/** The unit of the K(x) coefficient k_i in N/mm^(i+1): "N/mm", "N/mm\u00b2", ... */
export function coefUnitMm(i) {
  return i === 0 ? 'N/mm' : `N/mm${SUPERSCRIPT[i + 1] || `^${i + 1}`}`;
}

// --- headline values and their states (issue 22, decision 0032) ---------------

/** How each state of a headline value is written (a value not valid: capitals). */
export const STATE_WORDS = { valid: 'valid', extrapolated: 'EXTRAPOLATED', unreliable: 'UNRELIABLE', not_determined: 'NOT DETERMINED' };

/**
 * The state of a headline value of a result document, by its API field
 * ('small_signal.k0_n_per_m', 'large_signal.keff_at_target_n_per_m',
 * 'stiffness.k_of_x', 'stiffness.r_ns_per_m', ...): {state, reason,
 * fit_value}, as `<section>.validity.<name>` states it. A document from
 * before the states: valid, or unreliable with an unreliable small-signal fit.
 */
export function validityOf(doc, field) {
  const [sec, name] = String(field).split('.');
  const v = pick(doc || {}, `${sec}.validity.${name}`);
  if (v && v.state) return v;
  const ss = (doc || {}).small_signal;
  if (sec === 'small_signal' && ss && ss.reliable === false) {
    return { state: 'unreliable', reason: `the small-signal fit is unreliable (misfit ${num(ss.misfit_percent, 3)} %)` };
  }
  return { state: 'valid' };
}

/** The state as one line of text: 'valid', or 'UNRELIABLE: <reason>'. */
export function stateText(v) {
  if (!v || !v.state || v.state === 'valid') return 'valid';
  return `${STATE_WORDS[v.state] || v.state}: ${v.reason || 'no reason given'}`;
}

/**
 * Each reason written out once: a value whose reason repeats an earlier
 * value's keeps its state word, and its reason folds away under "the same
 * reason as <that value>" (the text stays on the page, one click away).
 * A dark surface made five values unreliable for one reason, written five
 * times.
 */
export function foldRepeatedReasons(el) {
  const first = new Map();
  for (const why of el.querySelectorAll('.validity-reason')) {
    const text = why.textContent;
    if (!first.has(text)) {
      const th = why.closest('tr') && why.closest('tr').querySelector('th');
      first.set(text, th ? th.textContent : '');
      continue;
    }
    const at = first.get(text);
    const fold = h('details', { class: 'validity-again' }, h('summary', {}, at ? `the same reason as ${at}` : 'the same reason as above'));
    why.replaceWith(fold);
    fold.append(why);
  }
  return el;
}

/**
 * A headline value as every page shows it: `text` (the formatted number)
 * when valid; with its state word and reason visible when not; a
 * `not_determined` value shows no number, the fit's own number (the
 * state's fit_value, else `raw`, SI) only under a named diagnostic label.
 */
export function stated(text, v, { unit = '', scale = 1, raw, id } = {}) {
  const state = (v && v.state) || 'valid';
  if (state === 'valid') return h('span', { id, class: 'validity validity-valid', dataset: { state } }, text);
  const word = h('span', { class: 'validity-word' }, STATE_WORDS[state] || state);
  const why = h('span', { class: 'validity-reason' }, v.reason || 'no reason given');
  if (state === 'not_determined') {
    const f = Number.isFinite(v.fit_value) ? v.fit_value : raw;
    const fit = Number.isFinite(f) ? h('span', { class: 'validity-fit' }, `fit value (diagnostic, not a measurement): ${num(f * scale, 4)}${unit ? ` ${unit}` : ''}`) : null;
    return h('span', { id, class: `validity validity-${state}`, dataset: { state } }, word, h('br'), why, fit ? [h('br'), fit] : null);
  }
  return h('span', { id, class: `validity validity-${state}`, dataset: { state } }, text, ' ', word, h('br'), why);
}
