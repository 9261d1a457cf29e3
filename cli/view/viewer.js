// impasto view: the page's controls around render.js (docs/viewer.md). URL parameters, as
// `impasto render` takes them: view=X,Y,Z[,TX,TY,TZ] light=X,Y,Z fov=DEG (horizontal)
// mode=bump|relief|adaptive|rm size=WxH overlay=0..3 exposure=STOPS bare=1 (the picture
// alone at the top left, for tests and screenshots). window.impasto is the page's state for
// scripts: ready, error, render(), ruler, profile, view, light.
import { Renderer, sub, norm, normalize, cross } from './render.js';

const $ = (id) => document.getElementById(id);
const q = new URLSearchParams(location.search);
const api = (window.impasto = { ready: false, error: null });

function fail(msg) {
  api.error = String(msg);
  const e = $('error');
  e.hidden = false;
  e.textContent = 'The copy cannot be shown:\n' + msg;
  console.error(msg);
}

function halfToFloat(h) {
  const s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 31, m = h & 1023;
  if (e === 0) return s * m * 2 ** -24;
  if (e === 31) return m ? NaN : s * Infinity;
  return s * (1024 + m) * 2 ** (e - 25);
}

function vec(s, n, m) {
  if (!s) return null;
  const v = s.split(',').map(Number);
  return (v.length === n || v.length === m) && v.every(Number.isFinite) ? v : null;
}

async function load() {
  const [mr, tr] = await Promise.all([fetch('copy/meta.json'), fetch('copy/textures.bin')]);
  if (!mr.ok) throw new Error(`copy/meta.json: HTTP ${mr.status}: ${await mr.text()}`);
  if (!tr.ok) throw new Error(`copy/textures.bin: HTTP ${tr.status}: ${await tr.text()}`);
  return [await mr.json(), await tr.arrayBuffer()];
}

class Viewer {
  constructor(meta, buffer) {
    this.meta = meta;
    this.canvas = $('gl');
    this.marks = $('marks');
    this.bare = q.get('bare') === '1';
    if (this.bare) document.body.classList.add('bare');
    this.renderer = new Renderer(this.canvas, meta, buffer);
    // heights (mm, canvas frame) for the ruler and the profile
    const n = meta.nx * meta.ny, h = new Uint16Array(buffer, 0, 4 * n);
    this.height = new Float32Array(n);
    this.mask = new Uint8Array(n);
    for (let k = 0; k < n; k++) {
      this.height[k] = halfToFloat(h[4 * k]) + meta.plane_mm;
      this.mask[k] = halfToFloat(h[4 * k + 3]) >= 0.5;
    }
    const p = meta.pitch_mm;
    this.centre = [0.5 * (meta.nx - 1) * p, 0.5 * (meta.ny - 1) * p, meta.plane_mm];
    this.opt = { mode: 'adaptive', K: 0, epsMin: 0.5, epsMax: 2.0, exposure: 1, overlay: 0, step: 1, binary: 8 };
    this.tool = 'orbit';
    this.ruler = null;
    this.profileLine = null;
    this.fixedSize = null;
    this.readParams();
    this.bind();
    this.resize();
  }

  readParams() {
    const m = this.meta;
    const fov = Number(q.get('fov'));
    this.fov = fov > 0.1 && fov < 170 ? fov : 40;
    const v = vec(q.get('view'), 3, 6);
    if (v) this.setView(v.slice(0, 3), v.length === 6 ? v.slice(3) : this.centre.slice(), null);
    else this.resetView();
    const l = vec(q.get('light'), 3, 3);
    if (l) this.light = l;
    else this.setLightDir(135, 30, 500);
    const mode = q.get('mode');
    if (['bump', 'relief', 'adaptive', 'rm'].includes(mode)) this.opt.mode = mode;
    const ov = Number(q.get('overlay'));
    if (ov >= 0 && ov <= 3) this.opt.overlay = ov | 0;
    const ex = Number(q.get('exposure'));
    if (Number.isFinite(ex)) this.opt.exposure = 2 ** ex;
    const size = /^(\d+)x(\d+)$/.exec(q.get('size') || '');
    if (size) this.fixedSize = [Number(size[1]), Number(size[2])];
    $('copy-name').textContent = '';
    $('copy-info').textContent = `${m.nx}×${m.ny} texels at ${(m.pitch_mm * 1000).toFixed(1)} µm ` +
      `(${(m.nx * m.pitch_mm).toFixed(1)}×${(m.ny * m.pitch_mm).toFixed(1)} mm), ${m.boxes.length} relief boxes`;
  }

  // A view as `impasto render --view` sets it: image x along canvas x (canvas y when the
  // view looks along x); `right` given keeps the orbit's own.
  setView(eye, target, right) {
    if (!right) {
      right = [1, 0, 0];
      if (Math.abs(eye[1] - target[1]) < 1e-9 && Math.abs(eye[2] - target[2]) < 1e-9) right = [0, 1, 0];
    }
    this.view = { eye, target, right, fov: this.fov };
  }

  resetView() {
    const m = this.meta, p = m.pitch_mm, [W, H] = this.size();
    const half = 0.6 * Math.max(m.nx * p, m.ny * p * W / H);
    const r = half / Math.tan(0.5 * this.fov * Math.PI / 180);
    const el = 70 * Math.PI / 180;
    this.setView([this.centre[0], this.centre[1] - r * Math.cos(el), this.centre[2] + r * Math.sin(el)],
                 this.centre.slice(), null);
  }

  // Light at azimuth az (degrees from canvas +x towards +y), elevation el, distance d (mm)
  // from the canvas centre.
  setLightDir(az, el, d) {
    const a = az * Math.PI / 180, e = el * Math.PI / 180;
    this.light = [this.centre[0] + d * Math.cos(e) * Math.cos(a), this.centre[1] + d * Math.cos(e) * Math.sin(a),
                  this.centre[2] + d * Math.sin(e)];
  }

  lightPolar() {
    const v = sub(this.light, this.centre), d = norm(v);
    return { d, az: (Math.atan2(v[1], v[0]) * 180 / Math.PI + 360) % 360, el: Math.asin(v[2] / d) * 180 / Math.PI };
  }

  size() {
    if (this.fixedSize) return this.fixedSize;
    const st = $('stage'), dpr = window.devicePixelRatio || 1;
    return [Math.max(1, Math.round(st.clientWidth * dpr)), Math.max(1, Math.round(st.clientHeight * dpr))];
  }

  resize() {
    const [W, H] = this.size(), dpr = this.fixedSize ? 1 : window.devicePixelRatio || 1;
    for (const c of [this.canvas, this.marks]) {
      c.width = W;
      c.height = H;
      c.style.width = W / dpr + 'px';
      c.style.height = H / dpr + 'px';
    }
    this.dpr = dpr;
    this.draw();
  }

  draw() {
    const t0 = performance.now();
    const st = this.renderer.render(this.view, { pos: this.light }, this.opt);
    this.drawMarks();
    this.drawLightDisk();
    const pol = this.lightPolar();
    $('light-readout').textContent = `azimuth ${pol.az.toFixed(0)}°, elevation ${pol.el.toFixed(1)}°, ${pol.d.toFixed(0)} mm`;
    $('light-dist').value = Math.round(pol.d);
    $('light-dist-val').textContent = Math.round(pol.d);
    $('exposure-val').textContent = `${Math.log2(this.opt.exposure).toFixed(1)} stops`;
    $('stats').textContent = st.below ? 'the eye is below the paint: nothing to see' :
      `${st.drawn} of ${st.boxes} boxes relief-mapped (${st.blended} blended), ${(performance.now() - t0).toFixed(1)} ms to submit`;
    $('legend').textContent = ['', `height ${this.meta.height_min_mm.toFixed(3)} … ${this.meta.height_max_mm.toFixed(3)} mm (blue → yellow)`,
      `σ 0 … ${(this.meta.sigma_p99_mm * 1000).toFixed(1)} µm (99th percentile)`,
      'green none, red fit failed, blue filled from normals, orange saturated/dark, violet shadowed, yellow other'][this.opt.overlay];
    api.view = this.view;
    api.light = this.light;
    api.stats = st;
  }

  heightAt(x, y) {  // bilinear, mm
    const m = this.meta, p = m.pitch_mm;
    const fx = Math.min(Math.max(x / p, 0), m.nx - 1), fy = Math.min(Math.max(y / p, 0), m.ny - 1);
    const i0 = Math.floor(fx), j0 = Math.floor(fy), i1 = Math.min(i0 + 1, m.nx - 1), j1 = Math.min(j0 + 1, m.ny - 1);
    const a = fx - i0, b = fy - j0, H = this.height, n = m.nx;
    return (1 - b) * ((1 - a) * H[j0 * n + i0] + a * H[j0 * n + i1]) + b * ((1 - a) * H[j1 * n + i0] + a * H[j1 * n + i1]);
  }

  setRuler(a, b) {
    const d = Math.hypot(b[0] - a[0], b[1] - a[1]);
    const ha = this.heightAt(a[0], a[1]), hb = this.heightAt(b[0], b[1]);
    const d3 = Math.hypot(d, hb - ha);
    this.ruler = { a, b, mm: d, mm3d: d3 };
    api.ruler = this.ruler;
    $('ruler-readout').textContent = `ruler: ${d.toFixed(3)} mm across the canvas (${d3.toFixed(3)} mm over the relief)`;
  }

  setProfile(a, b) {
    const p = this.meta.pitch_mm, len = Math.hypot(b[0] - a[0], b[1] - a[1]);
    const n = Math.max(2, Math.ceil(len / (0.5 * p)) + 1), pts = [];
    for (let k = 0; k < n; k++) {
      const t = k / (n - 1);
      pts.push([t * len, this.heightAt(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))]);
    }
    this.profileLine = { a, b, pts };
    api.profile = this.profileLine;
    const c = $('profile'), g = c.getContext('2d');
    g.clearRect(0, 0, c.width, c.height);
    const hs = pts.map((s) => s[1]), lo = Math.min(...hs), hi = Math.max(...hs), span = Math.max(hi - lo, 1e-6);
    g.strokeStyle = '#e8c060';
    g.beginPath();
    pts.forEach(([x, h], k) => {
      const X = 30 + (c.width - 40) * x / Math.max(len, 1e-9), Y = c.height - 20 - (c.height - 30) * (h - lo) / span;
      if (k) g.lineTo(X, Y); else g.moveTo(X, Y);
    });
    g.stroke();
    g.fillStyle = '#aaa';
    g.fillText(`${(span * 1000).toFixed(1)} µm`, 2, 12);
    g.fillText(`0`, 24, c.height - 6);
    g.fillText(`${len.toFixed(2)} mm`, c.width - 60, c.height - 6);
  }

  drawMarks() {
    const g = this.marks.getContext('2d');
    g.clearRect(0, 0, this.marks.width, this.marks.height);
    for (const [line, colour] of [[this.ruler, '#4cf'], [this.profileLine, '#e8c060']]) {
      if (!line) continue;
      const A = this.renderer.project(line.a), B = this.renderer.project(line.b);
      if (!A || !B) continue;
      g.strokeStyle = colour;
      g.lineWidth = 2 * this.dpr;
      g.beginPath();
      g.moveTo(A[0], A[1]);
      g.lineTo(B[0], B[1]);
      g.stroke();
      if (line === this.ruler) {
        g.fillStyle = colour;
        g.font = `${12 * this.dpr}px system-ui`;
        g.fillText(`${line.mm.toFixed(2)} mm`, 0.5 * (A[0] + B[0]) + 6, 0.5 * (A[1] + B[1]) - 6);
      }
    }
  }

  drawLightDisk() {
    const c = $('light-disk'), g = c.getContext('2d'), R = c.width / 2 - 6, cx = c.width / 2, cy = c.height / 2;
    g.clearRect(0, 0, c.width, c.height);
    g.strokeStyle = '#666';
    for (const el of [0, 30, 60]) {
      g.beginPath();
      g.arc(cx, cy, R * Math.cos(el * Math.PI / 180), 0, 2 * Math.PI);
      g.stroke();
    }
    const v = normalize(sub(this.light, this.centre));
    g.fillStyle = '#ffd84a';
    g.beginPath();
    g.arc(cx + R * v[0], cy - R * v[1], 6, 0, 2 * Math.PI);
    g.fill();
  }

  // Device-pixel position of a mouse event on the picture.
  pix(ev) {
    const r = this.canvas.getBoundingClientRect();
    return [(ev.clientX - r.left) * this.canvas.width / r.width, (ev.clientY - r.top) * this.canvas.height / r.height];
  }

  orbit(dx, dy) {
    const v = this.view, o = sub(v.eye, v.target), r = norm(o);
    let az = Math.atan2(o[1], o[0]) - dx * 0.01, el = Math.asin(o[2] / r) + dy * 0.01;
    el = Math.min(Math.max(el, 0.5 * Math.PI / 180), 89.9 * Math.PI / 180);
    const eye = [v.target[0] + r * Math.cos(el) * Math.cos(az), v.target[1] + r * Math.cos(el) * Math.sin(az),
                 v.target[2] + r * Math.sin(el)];
    const z = normalize(sub(v.target, eye)), right = normalize(cross(z, [0, 0, 1])) || v.right;
    this.view = { ...v, eye, right };
  }

  pan(dx, dy) {
    const c = this.renderer.lastCam, v = this.view;
    const s = norm(sub(v.eye, v.target)) / c.fx;
    const m = [0, 1, 2].map((k) => -(c.x[k] * dx + c.y[k] * dy) * s);
    this.view = { ...v, eye: v.eye.map((e, k) => e + m[k]), target: v.target.map((e, k) => e + m[k]) };
  }

  zoom(f) {
    const v = this.view, o = sub(v.eye, v.target);
    this.view = { ...v, eye: v.target.map((t, k) => t + o[k] * f) };
  }

  bind() {
    let drag = null;
    const stage = $('stage');
    stage.addEventListener('contextmenu', (ev) => ev.preventDefault());
    stage.addEventListener('mousedown', (ev) => {
      const p = this.pix(ev);
      drag = { p, last: [ev.clientX, ev.clientY], pan: ev.shiftKey || ev.button === 2, a: this.renderer.unproject(...p) };
    });
    window.addEventListener('mousemove', (ev) => {
      if (!drag) return;
      const dx = ev.clientX - drag.last[0], dy = ev.clientY - drag.last[1];
      drag.last = [ev.clientX, ev.clientY];
      if (this.tool === 'orbit' || drag.pan) {
        if (drag.pan) this.pan(dx * this.dpr, dy * this.dpr); else this.orbit(dx, dy);
      } else if (drag.a) {
        const b = this.renderer.unproject(...this.pix(ev));
        if (b) this.tool === 'ruler' ? this.setRuler(drag.a, b) : this.setProfile(drag.a, b);
      }
      this.draw();
    });
    window.addEventListener('mouseup', (ev) => {
      if (drag && drag.a && !drag.pan && this.tool !== 'orbit') {
        const b = this.renderer.unproject(...this.pix(ev));
        if (b) this.tool === 'ruler' ? this.setRuler(drag.a, b) : this.setProfile(drag.a, b);
        this.draw();
      }
      drag = null;
    });
    stage.addEventListener('wheel', (ev) => {
      ev.preventDefault();
      this.zoom(Math.exp(ev.deltaY * 0.001));
      this.draw();
    }, { passive: false });
    for (const r of document.querySelectorAll('input[name=tool]'))
      r.addEventListener('change', () => { this.tool = r.value; });
    const disk = $('light-disk');
    const moveLight = (ev) => {
      const rc = disk.getBoundingClientRect(), R = rc.width / 2 - 6;
      let u = (ev.clientX - rc.left - rc.width / 2) / R, v = -(ev.clientY - rc.top - rc.height / 2) / R;
      const l = Math.hypot(u, v);
      if (l > 0.999) { u *= 0.999 / l; v *= 0.999 / l; }
      const d = this.lightPolar().d;
      this.light = [this.centre[0] + d * u, this.centre[1] + d * v, this.centre[2] + d * Math.sqrt(1 - u * u - v * v)];
      this.draw();
    };
    let lightDrag = false;
    disk.addEventListener('mousedown', (ev) => { lightDrag = true; moveLight(ev); ev.stopPropagation(); });
    window.addEventListener('mousemove', (ev) => { if (lightDrag) moveLight(ev); });
    window.addEventListener('mouseup', () => { lightDrag = false; });
    $('light-dist').addEventListener('input', (ev) => {
      const p = this.lightPolar();
      this.setLightDir(p.az, p.el, Number(ev.target.value));
      this.draw();
    });
    for (const b of document.querySelectorAll('#presets button'))
      b.addEventListener('click', () => {
        this.setLightDir(Number(b.dataset.az), Number(b.dataset.el), this.lightPolar().d);
        this.draw();
      });
    $('exposure').addEventListener('input', (ev) => { this.opt.exposure = 2 ** Number(ev.target.value); this.draw(); });
    $('mode').value = this.opt.mode;
    $('mode').addEventListener('change', (ev) => { this.opt.mode = ev.target.value; this.draw(); });
    $('overlay').value = String(this.opt.overlay);
    $('overlay').addEventListener('change', (ev) => { this.opt.overlay = Number(ev.target.value); this.draw(); });
    $('reset').addEventListener('click', () => { this.resetView(); this.draw(); });
    for (const r of document.querySelectorAll('input[name=tool]')) if (r.value === q.get('tool')) { r.checked = true; this.tool = r.value; }
    if (!this.fixedSize) new ResizeObserver(() => this.resize()).observe($('stage'));
  }
}

try {
  const [meta, buffer] = await load();
  const v = new Viewer(meta, buffer);
  api.viewer = v;
  api.render = () => v.draw();
  api.meta = meta;
  api.ready = true;
} catch (e) {
  fail(e.message || e);
}
