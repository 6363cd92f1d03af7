// The shell: token login, role, navigation (hash routes), the
// "daemon unreachable" banner. Each view is a module with
// `render(main, ctx)` that may return a cleanup function.

import { api, token, on, ApiError, Unreachable, daemon } from './api.js';
import { h, put } from './util.js';
import * as operator from './operator.js';
import * as parts from './parts.js';
import * as measurement from './measurement.js';
import * as compare from './compare.js';
import * as diagnostics from './diagnostics.js';
import * as qc from './qc.js';
import * as report from './report.js';
import * as longterm from './longterm.js';
import * as studies from './studies.js';

const ROLES = ['viewer', 'operator', 'admin'];
const main = document.getElementById('view');
const banner = document.getElementById('banner');
const nav = document.getElementById('nav');
const who = document.getElementById('who');

const state = { session: null, cleanup: null, renderSeq: 0 };

const views = {
  operator: operator.render,
  parts: parts.render,
  part: parts.renderPart,
  measurement: measurement.render,
  compare: compare.render,
  diagnostics: diagnostics.render,
  qc: qc.render,
  report: report.render,
  'long-term': longterm.render,
  study: studies.render,
};

/** True when the session's role includes `role`. */
function can(role) {
  const mine = state.session && state.session.role;
  return ROLES.indexOf(mine) >= ROLES.indexOf(role) && ROLES.indexOf(mine) >= 0;
}

/**
 * A modal yes/no question (keyboard: Enter confirms the focused button, Escape keeps).
 * `yes` / `no` label the buttons (default: cancelling a job).
 */
function confirmDialog(text, { yes = 'Yes, cancel the job', no = 'Keep running' } = {}) {
  const d = document.getElementById('confirm');
  document.getElementById('confirm-text').textContent = text;
  document.getElementById('confirm-yes').textContent = yes;
  document.getElementById('confirm-no').textContent = no;
  return new Promise((resolve) => {
    d.addEventListener('close', () => resolve(d.returnValue === 'ok'), { once: true });
    d.returnValue = 'cancel';
    d.showModal();
    document.getElementById('confirm-no').focus();
  });
}

function parseRoute() {
  const raw = location.hash.replace(/^#\/?/, '');
  const [path, query] = raw.split('?');
  const [name, ...rest] = path.split('/');
  return {
    name: name || (daemon.center ? 'parts' : 'operator'),
    arg: rest.map(decodeURIComponent).join('/'),
    params: new URLSearchParams(query || ''),
  };
}

function setBanner(text, kind) {
  if (!text) {
    banner.hidden = true;
    banner.textContent = '';
    return;
  }
  banner.hidden = false;
  banner.className = kind || 'error';
  banner.textContent = text;
}

async function route() {
  if (state.cleanup) {
    try {
      state.cleanup();
    } catch {
      /* a view's cleanup must not stop navigation */
    }
    state.cleanup = null;
  }
  if (!state.session) {
    loginView();
    return;
  }
  const r = parseRoute();
  // The fleet's center runs no bench and holds no recordings' analyses: say so
  // instead of a view that would only show errors.
  const view = daemon.center && CENTER_ONLY_AT_STATION[r.name] ? centerNote(CENTER_ONLY_AT_STATION[r.name]) : views[r.name];
  for (const a of nav.querySelectorAll('a')) a.classList.toggle('active', a.dataset.view === r.name);
  const seq = ++state.renderSeq;
  main.replaceChildren();
  main.dataset.view = r.name;
  if (!view) {
    put(main, h('p', { class: 'error' }, `No page '${r.name}'. `), h('a', { href: '#/operator' }, 'Go to the operator view'));
    return;
  }
  const ctx = {
    role: state.session.role,
    can,
    arg: r.arg,
    params: r.params,
    confirm: confirmDialog,
    stale: () => seq !== state.renderSeq,
    // Draws the current route again (after a change the page made).
    rerender: () => route(),
  };
  try {
    const c = await view(main, ctx);
    if (seq === state.renderSeq) state.cleanup = typeof c === 'function' ? c : null;
    else if (typeof c === 'function') c();
  } catch (e) {
    if (seq !== state.renderSeq) return;
    main.append(h('p', { class: 'error', id: 'view-error' }, errorText(e)));
  }
}

export function errorText(e) {
  if (e instanceof Unreachable) return `Cannot reach the daemon: ${e.message}.`;
  if (e instanceof ApiError) {
    if (e.status === 403) return `Your token's role (${state.session && state.session.role}) does not allow this: ${e.message}`;
    return `The daemon refused (${e.status}): ${e.message}`;
  }
  return `Error: ${e.message || e}`;
}

// Views a station has and the fleet's center has not, and why.
const CENTER_ONLY_AT_STATION = {
  operator: 'The fleet\u2019s center runs no bench: jobs are submitted and watched at a station. Here: the parts, measurements, comparisons and QC of every station.',
  diagnostics: 'The diagnostics workspace refits a measurement from its recordings: open it on the station that measured it.',
  study: 'A study of a part\u2019s memory runs on a bench: start and watch it at the station that has the bench.',
};

function centerNote(text) {
  return (main) => put(main, h('section', { class: 'card', id: 'center-note' }, h('h1', {}, 'Not at the fleet\u2019s center'), h('p', {}, text), h('a', { href: '#/parts' }, 'Parts of every station')));
}

function showWho() {
  const s = state.session;
  put(
    who,
    daemon.center ? h('span', { class: 'role', id: 'daemon-center', title: 'The fleet\u2019s center: every station\u2019s results, read only' }, 'fleet center') : null,
    daemon.center ? ' ' : null,
    h('span', { class: `role role-${s.role}`, id: 'role' }, s.role),
    s.name ? h('span', { class: 'muted' }, ` ${s.name}`) : h('span', { class: 'muted' }, ' open access'),
    s.auth_required ? h('button', { id: 'logout', class: 'link', onclick: logout }, 'Log out') : null,
  );
}

function logout() {
  token.clear();
  state.session = null;
  if (location.hash && location.hash !== '#/operator') location.hash = '#/operator'; // route() shows the login
  else loginView();
}

function loginView(message) {
  nav.hidden = true;
  put(who);
  main.dataset.view = 'login';
  const input = h('input', {
    id: 'token',
    type: 'password',
    autocomplete: 'current-password',
    required: true,
    minlength: 1,
    'aria-label': 'Access token',
  });
  const err = h('p', { class: 'error', id: 'login-error' }, message || '');
  const form = h(
    'form',
    { id: 'login', class: 'card login' },
    h('h1', {}, 'Sign in'),
    h('p', { class: 'muted' }, 'Paste or scan the access token of this station (viewer, operator or admin).'),
    h('label', { for: 'token' }, 'Token'),
    input,
    h('button', { type: 'submit', id: 'login-submit' }, 'Sign in'),
    err,
  );
  form.addEventListener('submit', async (ev) => {
    ev.preventDefault();
    token.set(input.value.trim());
    try {
      const s = await api('/api/v1/session');
      if (!s.role) {
        token.clear();
        err.textContent = 'This token is not known to the daemon.';
        input.select();
        return;
      }
      start(s);
    } catch (e) {
      token.clear();
      err.textContent = errorText(e);
    }
  });
  put(main, form);
  input.focus();
}

let started = false;
function start(session) {
  state.session = session;
  daemon.center = session.daemon === 'center';
  nav.querySelector('a[data-view="operator"]').hidden = daemon.center;
  document.querySelector('.brand').setAttribute('href', daemon.center ? '#/parts' : '#/operator');
  nav.hidden = false;
  showWho();
  if (!started) {
    started = true;
    window.addEventListener('hashchange', route);
  }
  route();
}

async function boot() {
  try {
    const s = await api('/api/v1/session');
    if (s.auth_required && !s.role) {
      loginView(token.get() ? 'The stored token is no longer accepted.' : '');
      token.clear();
      return;
    }
    start(s);
  } catch (e) {
    put(main, h('p', { class: 'error', id: 'boot-error' }, errorText(e)), h('button', { onclick: boot }, 'Try again'));
  }
}

// Reachability: a banner while the daemon does not answer; poll /healthz until it does.
let poll = null;
on('reachable', (ok, detail) => {
  if (ok) {
    setBanner('');
    document.body.classList.remove('offline');
    if (poll) clearInterval(poll);
    poll = null;
    if (state.session) route();
    return;
  }
  document.body.classList.add('offline');
  setBanner(`The daemon at ${location.host} does not answer. What you see may be out of date; retrying every 2 s. (${detail || ''})`);
  if (!poll)
    poll = setInterval(() => {
      api('/healthz').catch(() => {});
    }, 2000);
});
on('unauthorized', () => {
  if (state.session && state.session.auth_required) {
    token.clear();
    state.session = null;
    loginView('The daemon no longer accepts the token: sign in again.');
  }
});

boot();
