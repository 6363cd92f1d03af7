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
