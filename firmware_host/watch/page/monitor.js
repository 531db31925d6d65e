// lftrack's monitor page: state and traces from /api/events (server-sent events), the frames with
// the DRR at the registered pose, and the operator's actions (a token, a nonce per action).
'use strict';

const MAX_TRACE = 600;
const trace = [];        // rows as trace_json writes them
let current = null;      // the last state
let images = null;       // the last images event
let token = sessionStorage.getItem('lftrack-token') || '';

const $ = (id) => document.getElementById(id);
const fmt = (v, digits) => (v === undefined || v === null || !isFinite(v)) ? '-' : Number(v).toFixed(digits);

// A token in the address (#token=...) is taken and removed from the address bar, when the page
// opens and when the address changes to one with a token.
function takeTokenFromAddress() {
  const m = /[#&]token=([0-9a-f]+)/.exec(location.hash);
  if (m) {
    token = m[1];
    sessionStorage.setItem('lftrack-token', token);
    history.replaceState(null, '', location.pathname);
    showToken();
  }
}
takeTokenFromAddress();
window.addEventListener('hashchange', takeTokenFromAddress);

function showToken() {
  $('token-status').textContent = token ? 'operator: actions carry the run\'s token' : 'view only: no operator token';
}

$('token-form').addEventListener('submit', (e) => {
  e.preventDefault();
  token = $('token').value.trim();
  $('token').value = '';
  if (token) sessionStorage.setItem('lftrack-token', token); else sessionStorage.removeItem('lftrack-token');
  showToken();
});

async function act(action) {
  const result = $('action-result');
  result.className = '';
  result.textContent = action + '...';
  try {
    const headers = { 'Content-Type': 'application/json' };
    if (token) headers['Authorization'] = 'Bearer ' + token;
    // A nonce is the operator's: it needs the token. Without one (or with a wrong one) the action
    // goes without a nonce, and the server refuses it for the token, which the loop journals.
    const body = { nonce: '' };
    if (token) {
      const issued = await fetch('/api/nonce', { headers: { 'Authorization': 'Bearer ' + token } });
      if (issued.ok) body.nonce = (await issued.json()).nonce;
    }
    if (action !== 'stop' && current && current.hold_id > 0) body.hold_id = current.hold_id;
    const answer = await fetch('/api/' + action, { method: 'POST', headers, body: JSON.stringify(body) });
    const json = await answer.json();
    result.className = json.accepted ? 'accepted' : 'refused';
    result.textContent = json.accepted ? action + ': accepted' : action + ': refused (' + json.reason + ')';
  } catch (err) {
    result.className = 'refused';
    result.textContent = action + ': no answer (' + err + ')';
  }
}
for (const action of ['resume', 'reset', 'stop']) $(action).addEventListener('click', () => act(action));

function showState(s) {
  current = s;
  $('scene').textContent = s.scene;
  if (!s.started) return;
  const state = $('state');
  state.textContent = s.state;
  state.className = 'state ' + s.state;
  $('state-reason').textContent = (s.state === 'HOLD' || s.state === 'FAULT') ? s.state_reason : '';
  $('cycle').textContent = s.cycle;
  $('hold-id').textContent = s.hold_id || '-';
  // An applied cycle may keep the beam off while the patient is still being moved into place.
  $('beam').textContent = s.beam_permit ? 'on' : s.beam_withheld ? 'off: ' + s.beam_withheld : 'off';
  $('gate-decision').textContent = s.gate.shown;
  $('gate-reason').textContent = s.gate.shown_reason || '-';
  $('holds').textContent = s.counts.holds;
  $('faults').textContent = s.counts.faults;
  $('overruns').textContent = s.counts.overruns;
  $('refused').textContent = s.counts.operator_refused;
  $('dropped').textContent = s.counts.records_dropped;
  for (let i = 0; i < 6; i++) {
    const part = i < 3 ? 'translation_mm' : 'rotation_deg';
    $('off' + i).textContent = s.registered ? fmt(s.offset[part][i % 3], 2) : '-';
    $('cmd' + i).textContent = s.command_sent ? fmt(s.correction[part][i % 3], 2) : '-';
  }
  $('similarity').textContent = s.similarity.map((v) => fmt(v, 3)).join(' / ');
  $('registration-ms').textContent = fmt(s.registration_ms, 1);
  // The last correction from exposure to acknowledgement, link by link (the real clock only).
  const chain = s.latency_chain_ms;
  $('latency-chain').textContent = chain ?
      ['arrive', 'preprocess', 'register', 'gate', 'write', 'acknowledge']
              .map((k) => k + ' ' + fmt(chain[k], 2))
              .join(' + ') +
          ' = ' + fmt(chain.total, 2) + ' ms' :
      s.command_sent ? 'n/a (not timed: the simulated clock, or a link not reached)' :
                       '- (no correction sent this cycle)';
  $('residual').textContent = s.true_residual_mm >= 0 ? fmt(s.true_residual_mm, 3) + ' mm' : 'n/a (not simulated)';
  const table = $('transitions');
  while (table.rows.length > 1) table.deleteRow(1);
  for (const t of s.transitions.slice().reverse().slice(0, 12)) {
    const row = table.insertRow();
    for (const text of [t.cycle, t.from, t.to, t.reason + (t.hold_id ? ' (hold ' + t.hold_id + ')' : '')])
      row.insertCell().textContent = text;
  }
}

// ---- Traces ----
const COLORS = ['#ff7b72', '#3fb950', '#58a6ff'];
function plot(canvas, title, series, unit) {
  const ctx = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height, left = 46, top = 14, bottom = 4;
  ctx.clearRect(0, 0, w, h);
  ctx.fillStyle = '#9fb0c0';
  ctx.font = '11px sans-serif';
  ctx.fillText(title, left, 10);
  let lo = Infinity, hi = -Infinity;
  for (const s of series) for (const p of s.points) if (p !== null) { lo = Math.min(lo, p); hi = Math.max(hi, p); }
  if (!isFinite(lo)) return;
  const nonNegative = lo >= 0;
  if (hi - lo < 1e-6) { hi += 0.5; lo -= 0.5; }
  const pad = 0.08 * (hi - lo);
  lo -= pad; hi += pad;
  if (nonNegative) lo = Math.max(lo, 0);  // times and distances: the axis starts at 0
  const n = Math.max(...series.map((s) => s.points.length));
  const x = (i) => left + (w - left - 4) * (n <= 1 ? 0 : i / (n - 1));
  const y = (v) => top + (h - top - bottom) * (1 - (v - lo) / (hi - lo));
  ctx.strokeStyle = '#30363d';
  ctx.beginPath();
  ctx.moveTo(left, y(0)); ctx.lineTo(w - 4, y(0));
  ctx.stroke();
  ctx.fillText(fmt(hi, 2) + ' ' + unit, 2, top + 8);
  ctx.fillText(fmt(lo, 2), 2, h - bottom);
  series.forEach((s, k) => {
    ctx.strokeStyle = s.color || COLORS[k % COLORS.length];
    ctx.beginPath();
    let drawing = false;
    s.points.forEach((v, i) => {
      if (v === null) { drawing = false; return; }
      if (drawing) ctx.lineTo(x(i), y(v)); else ctx.moveTo(x(i), y(v));
      drawing = true;
    });
    ctx.stroke();
    ctx.fillStyle = ctx.strokeStyle;
    ctx.fillText(s.name, w - 40 * (series.length - k), 10);
  });
}

function drawTraces() {
  $('trace-count').textContent = trace.length;
  const col = (c, needRegistered) => trace.map((r) => (needRegistered && !r[1]) ? null : r[c]);
  plot($('trace-translation'), 'registered offset, translation', [
    { name: 'x', points: col(2, true) }, { name: 'y', points: col(3, true) }, { name: 'z', points: col(4, true) }], 'mm');
  plot($('trace-rotation'), 'registered offset, rotation', [
    { name: 'rx', points: col(5, true) }, { name: 'ry', points: col(6, true) }, { name: 'rz', points: col(7, true) }], 'deg');
  plot($('trace-residual'), 'true residual (simulation)', [
    { name: 'mm', points: trace.map((r) => r[8] >= 0 ? r[8] : null), color: '#d2a8ff' }], 'mm');
  plot($('trace-similarity'), 'similarity per view', [
    { name: 'A', points: col(9, true) }, { name: 'B', points: col(10, true) }], '');
  plot($('trace-time'), 'registration time', [{ name: 'ms', points: trace.map((r) => r[11] > 0 ? r[11] : null), color: '#f0b429' }], 'ms');
}

// ---- Images ----
function decode(grey) {
  const bytes = atob(grey.pixels);
  const out = new Uint8ClampedArray(bytes.length);
  for (let i = 0; i < bytes.length; i++) out[i] = bytes.charCodeAt(i);
  return out;
}

function viewCanvases(index) {
  let box = document.getElementById('view-' + index);
  if (!box) {
    box = document.createElement('div');
    box.className = 'view';
    box.id = 'view-' + index;
    box.innerHTML = '<div class="name"></div><canvas class="roi"></canvas><canvas class="thumb"></canvas>';
    $('views').appendChild(box);
  }
  return box;
}

function drawImages() {
  if (!images) return;
  const mode = $('overlay').value;
  $('image-cycle').textContent = '(cycle ' + images.cycle + (images.registered ? '' : ', not registered') + ')';
  images.views.forEach((v, index) => {
    const box = viewCanvases(index);
    box.querySelector('.name').textContent = 'detector ' + v.name + ' (ROI, 1:' + v.bin + ')';
    const frame = decode(v.roi);
    const drr = v.drr.rows ? decode(v.drr) : null;
    const rows = v.roi.rows, cols = v.roi.cols;
    const canvas = box.querySelector('.roi');
    const scale = 270 / Math.max(rows, cols);  // both views side by side
    canvas.width = cols; canvas.height = rows;
    canvas.style.width = Math.round(cols * scale) + 'px';
    canvas.style.height = Math.round(rows * scale) + 'px';
    const ctx = canvas.getContext('2d');
    const img = ctx.createImageData(cols, rows);
    for (let r = 0; r < rows; r++) for (let c = 0; c < cols; c++) {
      const i = r * cols + c;
      let g = frame[i], red = g, green = g, blue = g;
      if (drr && mode === 'drr') red = green = blue = drr[i];
      if (drr && mode === 'checker' && ((Math.floor(r / 16) + Math.floor(c / 16)) % 2 === 1)) red = green = blue = drr[i];
      if (drr && mode === 'edges' && r > 0 && c > 0 && r < rows - 1 && c < cols - 1) {
        const gx = drr[i + 1] - drr[i - 1], gy = drr[i + cols] - drr[i - cols];
        if (gx * gx + gy * gy > 40 * 40) { red = 40; green = 255; blue = 80; }
      }
      img.data[4 * i] = red; img.data[4 * i + 1] = green; img.data[4 * i + 2] = blue; img.data[4 * i + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
    const thumb = box.querySelector('.thumb');
    const t = decode(v.thumbnail);
    thumb.width = v.thumbnail.cols; thumb.height = v.thumbnail.rows;
    const tctx = thumb.getContext('2d');
    const timg = tctx.createImageData(v.thumbnail.cols, v.thumbnail.rows);
    for (let i = 0; i < t.length; i++) {
      timg.data[4 * i] = timg.data[4 * i + 1] = timg.data[4 * i + 2] = t[i];
      timg.data[4 * i + 3] = 255;
    }
    tctx.putImageData(timg, 0, 0);
    const [r0, c0, rr, cc] = v.roi_in_thumbnail;
    tctx.strokeStyle = '#f0b429';
    tctx.strokeRect(c0 + 0.5, r0 + 0.5, cc, rr);
  });
}
$('overlay').addEventListener('change', drawImages);

// ---- Live updates ----
function connect() {
  const events = new EventSource('/api/events');
  events.addEventListener('open', () => { $('link').textContent = 'live'; });
  events.addEventListener('error', () => { $('link').textContent = 'reconnecting...'; });
  events.addEventListener('state', (e) => {
    const data = JSON.parse(e.data);
    showState(data.state);
    for (const row of data.trace) trace.push(row);
    if (trace.length > MAX_TRACE) trace.splice(0, trace.length - MAX_TRACE);
    drawTraces();
  });
  events.addEventListener('images', (e) => {
    images = JSON.parse(e.data);
    drawImages();
  });
}
showToken();
connect();
