// The hybrid bump / relief renderer of seed 000 §5 in WebGL2, a port of
// pipeline/appearance/relief-render.c with the same conventions, so that a frame agrees with
// `impasto render` (docs/viewer.md, "Matching the CPU renderer"):
//  - canvas frame in mm, texel (i, j) at (i·pitch, j·pitch); here z is shifted so that the
//    bump plane (h_ref + δ0) is z = 0 (a translation: the picture does not change);
//  - §5.1: the plane is a quad at z = 0, shaded with the nearest texel's normal and BRDF at
//    the real surface point (x, y, h);
//  - §5.2: each relief box is drawn as a box; its fragments march the ray from the entry E
//    to the exit S (linear search, one texel per step, then 8 binary steps) over the
//    bilinear heights clamped to the box's texels and to the plane; the nearest hit wins
//    (depth test), a box that is not hit is transparent;
//  - §5.3: α per box from eq. 2 with r = |IB| / |CI|, K = fx by default, ε = 0.5, 2.0;
//    the relief colour is blended over the bump colour with α;
//  - §5.4: V = E·cos θl·(ρd + ρs·max(0, Cx vx lx + Cy vy ly + Cz vz lz)^k) in the texel's
//    local frame, E = I·(1000 / d)² for a point light whose intensity gives E = 1 at the
//    canvas centre; V clamped to [0, 1] and sRGB-encoded.
// Modes: 'bump' (plane only), 'relief' (hybrid, every box relief-mapped), 'adaptive'
// (hybrid + α), 'rm' (relief mapping over the whole canvas as one box: the seed's "RM").

const COMMON = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
uniform sampler2D uSurface, uDiffuse, uSpecular, uLobe;
uniform vec3 uC, uL;
uniform float uE0, uPitch;
uniform ivec2 uGrid;

ivec2 nearestTexel(vec2 xy) {
  ivec2 ij = ivec2(floor(xy / uPitch + 0.5));
  return clamp(ij, ivec2(0), uGrid - 1);
}

// V = E cos(theta_l) f(v, l) at P with texel ij's normal and Lafortune BRDF (seed eq. 1).
vec3 shade(vec3 P, ivec2 ij) {
  vec2 nxy = texelFetch(uSurface, ij, 0).yz;
  float q = dot(nxy, nxy);
  vec3 n = q > 1.0 ? vec3(nxy * inversesqrt(q), 0.0) : vec3(nxy, sqrt(1.0 - q));
  vec3 l = uL - P, v = uC - P;
  float dl = dot(l, l), dv = dot(v, v);
  if (!(dl > 1e-18) || !(dv > 1e-18)) return vec3(0.0);
  l *= inversesqrt(dl);
  v *= inversesqrt(dv);
  float cosl = dot(n, l);
  if (cosl <= 0.0) return vec3(0.0);
  float E = uE0 / dl;
  vec3 ax = abs(n.x) > 0.99 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
  vec3 t = normalize(ax - dot(ax, n) * n);
  vec3 b = cross(n, t);
  vec3 vl = vec3(dot(t, v), dot(b, v), dot(n, v)), ll = vec3(dot(t, l), dot(b, l), dot(n, l));
  if (vl.z <= 0.0 || ll.z <= 0.0) return vec3(0.0);
  vec4 lobe = texelFetch(uLobe, ij, 0);
  float d = lobe.x * vl.x * ll.x + lobe.y * vl.y * ll.y + lobe.z * vl.z * ll.z;
  float lo = d > 0.0 ? pow(d, lobe.w) : 0.0;
  vec3 rd = texelFetch(uDiffuse, ij, 0).rgb, rs = texelFetch(uSpecular, ij, 0).rgb;
  return E * cosl * (rd + rs * lo);
}
`;

const PLANE_VS = `#version 300 es
uniform mat4 uVP;
uniform vec4 uRect;
in vec2 aCorner;
out vec3 vWorld;
void main() {
  vWorld = vec3(mix(uRect.xy, uRect.zw, aCorner), 0.0);
  gl_Position = uVP * vec4(vWorld, 1.0);
}`;

const PLANE_FS = COMMON + `
uniform int uOverlay;
uniform vec2 uHeightRange;
uniform float uSigmaMax;
in vec3 vWorld;
out vec4 oColour;

vec3 ramp(float x) {  // dark blue → teal → yellow
  x = clamp(x, 0.0, 1.0);
  return clamp(vec3(-0.2 + 1.3 * x * x, 0.1 + 0.8 * x, 0.45 + 0.35 * sin(3.14159 * x) - 0.35 * x), 0.0, 1.0);
}
vec3 flagColour(int f) {
  if (f == 0) return vec3(0.25, 0.6, 0.3);
  if ((f & 512) != 0) return vec3(0.95, 0.1, 0.1);   // fit failed
  if ((f & 32) != 0) return vec3(0.2, 0.4, 1.0);     // filled
  if ((f & 3) != 0) return vec3(1.0, 0.6, 0.0);      // saturated, dark
  if ((f & 4) != 0) return vec3(0.6, 0.3, 0.8);      // shadowed
  return vec3(1.0, 1.0, 0.2);
}
void main() {
  ivec2 ij = nearestTexel(vWorld.xy);
  vec4 s = texelFetch(uSurface, ij, 0);
  if (uOverlay != 0) {
    vec3 c = vec3(0.08);
    if (s.w >= 0.5) {
      if (uOverlay == 1) c = ramp((s.x - uHeightRange.x) / max(uHeightRange.y - uHeightRange.x, 1e-9));
      else if (uOverlay == 2) c = ramp(texelFetch(uDiffuse, ij, 0).w / max(uSigmaMax, 1e-9));
      else c = flagColour(int(texelFetch(uSpecular, ij, 0).w + 0.5));
    }
    oColour = vec4(c, 1.0);
    return;
  }
  oColour = vec4(shade(vec3(vWorld.xy, s.x), ij), 1.0);
}`;

const BOX_VS = `#version 300 es
uniform mat4 uVP;
in vec3 aCorner;
in vec3 aLo, aHi;
in vec4 aRect;
in float aAlpha;
out vec3 vWorld;
flat out vec3 vLo, vHi;
flat out ivec4 vRect;
flat out float vAlpha;
void main() {
  vWorld = mix(aLo, aHi, aCorner);
  vLo = aLo; vHi = aHi; vRect = ivec4(aRect); vAlpha = aAlpha;
  gl_Position = uVP * vec4(vWorld, 1.0);
}`;

const BOX_FS = COMMON + `
uniform mat4 uVP;
uniform float uFloor, uStep;
uniform int uBinary;
in vec3 vWorld;
flat in vec3 vLo, vHi;
flat in ivec4 vRect;
flat in float vAlpha;
out vec4 oColour;

float h(ivec2 ij) { return texelFetch(uSurface, ij, 0).x; }
// Bilinear height inside the box, clamped to its texels and to the floor (the plane).
float boxHeight(vec2 xy) {
  vec2 f = xy / uPitch, f0 = floor(f), a = f - f0;
  ivec2 lo = vRect.xy, hi = vRect.xy + vRect.zw - 1;
  ivec2 i0 = clamp(ivec2(f0), lo, hi), i1 = clamp(ivec2(f0) + 1, lo, hi);
  float v = (1.0 - a.y) * ((1.0 - a.x) * h(i0) + a.x * h(ivec2(i1.x, i0.y))) +
            a.y * ((1.0 - a.x) * h(ivec2(i0.x, i1.y)) + a.x * h(i1));
  return max(v, uFloor);
}
void main() {
  vec3 d = normalize(vWorld - uC);
  vec3 s = vec3(d.x >= 0.0 ? 1.0 : -1.0, d.y >= 0.0 ? 1.0 : -1.0, d.z >= 0.0 ? 1.0 : -1.0);
  vec3 inv = s / max(abs(d), vec3(1e-30));
  vec3 ta = (vLo - uC) * inv, tb = (vHi - uC) * inv;
  vec3 tmin = min(ta, tb), tmax = max(ta, tb);
  float tE = max(max(max(tmin.x, tmin.y), tmin.z), 0.0), tS = min(min(tmax.x, tmax.y), tmax.z);
  if (!(tE <= tS)) discard;
  // §5.2: linear search from E to S, one step per texel of the ray's footprint
  int n = int(min(ceil(length(d.xy) * (tS - tE) / (uStep * uPitch)), 4096.0));
  n = max(n, 2);
  float dt = (tS - tE) / float(n), prev = tE, th = -1.0;
  for (int k = 0; k <= n; k++) {
    float t = k == n ? tS : tE + float(k) * dt;
    vec3 p = uC + t * d;
    if (p.z <= boxHeight(p.xy)) {
      if (k == 0) { th = tE; break; }  // entered through a wall below the surface
      float lo = prev, hi = t;
      for (int it = 0; it < uBinary; it++) {
        float m = 0.5 * (lo + hi);
        vec3 q = uC + m * d;
        if (q.z <= boxHeight(q.xy)) hi = m; else lo = m;
      }
      th = hi;
      break;
    }
    prev = t;
  }
  if (th < 0.0) discard;
  vec3 P = uC + th * d;
  vec4 clip = uVP * vec4(P, 1.0);
  gl_FragDepth = clamp(0.5 * clip.z / clip.w + 0.5, 0.0, 1.0);
  oColour = vec4(shade(P, nearestTexel(P.xy)), vAlpha);
}`;

const COMPOSITE_VS = `#version 300 es
in vec2 aCorner;
void main() { gl_Position = vec4(aCorner * 2.0 - 1.0, 0.0, 1.0); }`;

const COMPOSITE_FS = `#version 300 es
precision highp float;
uniform sampler2D uBump, uRelief;
uniform float uExposure;
uniform int uOverlay;
out vec4 oColour;
float srgb(float v) {
  v = clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 b = texelFetch(uBump, p, 0), r = texelFetch(uRelief, p, 0);
  if (uOverlay != 0) { oColour = vec4(b.rgb, 1.0); return; }
  vec3 v = (r.a * r.rgb + (1.0 - r.a) * b.rgb) * uExposure;
  oColour = vec4(srgb(v.r), srgb(v.g), srgb(v.b), 1.0);
}`;

function compile(gl, vs, fs) {
  const p = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS))
      throw new Error('shader: ' + gl.getShaderInfoLog(s));
    gl.attachShader(p, s);
  }
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS))
    throw new Error('program: ' + gl.getProgramInfoLog(p));
  const u = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const name = gl.getActiveUniform(p, i).name;
    u[name] = gl.getUniformLocation(p, name);
  }
  return { p, u, a: (name) => gl.getAttribLocation(p, name) };
}

// Vector helpers on plain arrays.
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const norm = (a) => Math.hypot(a[0], a[1], a[2]);
export function normalize(a) {
  const n = norm(a);
  return n > 1e-300 ? [a[0] / n, a[1] / n, a[2] / n] : null;
}

// imp_pinhole_look_at: rows x (image right), y (image down), z (forward).
export function lookAt(eye, target, right) {
  const z = normalize(sub(target, eye)) || [0, 0, -1];
  let x = normalize(sub(right, z.map((c) => c * dot(right, z))));
  if (!x)
    for (const ax of [[1, 0, 0], [0, 1, 0], [0, 0, 1]]) {
      x = normalize(sub(ax, z.map((c) => c * dot(ax, z))));
      if (x) break;
    }
  const y = cross(z, x);
  return [x, y, z];
}

export class Renderer {
  constructor(canvas, meta, buffer) {
    const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true, alpha: false });
    if (!gl) throw new Error('this browser has no WebGL2');
    if (!gl.getExtension('EXT_color_buffer_float') && !gl.getExtension('EXT_color_buffer_half_float'))
      throw new Error('WebGL2 without float render targets (EXT_color_buffer_float)');
    const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
    if (meta.nx > max || meta.ny > max)
      throw new Error(`the copy is ${meta.nx}×${meta.ny} texels, larger than this GPU's ${max}-texel textures`);
    this.gl = gl;
    this.canvas = canvas;
    this.meta = meta;
    this.progPlane = compile(gl, PLANE_VS, PLANE_FS);
    this.progBox = compile(gl, BOX_VS, BOX_FS);
    this.progComp = compile(gl, COMPOSITE_VS, COMPOSITE_FS);
    this.textures = this.uploadTextures(buffer);
    this.makeGeometry();
    this.targets = null;
    this.stats = {};
  }

  uploadTextures(buffer) {
    const gl = this.gl, m = this.meta, n = m.nx * m.ny;
    const halves = new Uint16Array(buffer);
    if (halves.length !== 4 * 4 * n)
      throw new Error(`textures.bin holds ${halves.length} values, expected ${16 * n}`);
    return m.textures.map((_, t) => {
      const tex = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, tex);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, m.nx, m.ny, 0, gl.RGBA, gl.HALF_FLOAT,
                    halves.subarray(t * 4 * n, (t + 1) * 4 * n));
      for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
      for (const p of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T]) gl.texParameteri(gl.TEXTURE_2D, p, gl.CLAMP_TO_EDGE);
      return tex;
    });
  }

  makeGeometry() {
    const gl = this.gl;
    this.quad = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 0, 1, 0, 0, 1, 1, 1]), gl.STATIC_DRAW);
    // a unit cube as 12 triangles
    const c = [];
    const faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]];
    const v = (k) => [k & 1, (k >> 1) & 1, (k >> 2) & 1];
    for (const f of faces) for (const k of [f[0], f[1], f[2], f[0], f[2], f[3]]) c.push(...v(k));
    this.cube = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.cube);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(c), gl.STATIC_DRAW);
    this.instances = gl.createBuffer();
    this.boxVao = gl.createVertexArray();
    gl.bindVertexArray(this.boxVao);
    const pb = this.progBox;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.cube);
    gl.enableVertexAttribArray(pb.a('aCorner'));
    gl.vertexAttribPointer(pb.a('aCorner'), 3, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.instances);
    const stride = 11 * 4;
    for (const [name, size, off] of [['aLo', 3, 0], ['aHi', 3, 3], ['aRect', 4, 6], ['aAlpha', 1, 10]]) {
      const loc = pb.a(name);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, gl.FLOAT, false, stride, off * 4);
      gl.vertexAttribDivisor(loc, 1);
    }
    gl.bindVertexArray(null);
    for (const name of ['planeVao', 'compVao']) {
      const prog = name === 'planeVao' ? this.progPlane : this.progComp;
      this[name] = gl.createVertexArray();
      gl.bindVertexArray(this[name]);
      gl.bindBuffer(gl.ARRAY_BUFFER, this.quad);
      gl.enableVertexAttribArray(prog.a('aCorner'));
      gl.vertexAttribPointer(prog.a('aCorner'), 2, gl.FLOAT, false, 0, 0);
    }
    gl.bindVertexArray(null);
  }

  // Two float targets of the canvas size: the bump pass and the relief pass (with depth).
  ensureTargets(W, H) {
    const gl = this.gl;
    if (this.targets && this.targets.W === W && this.targets.H === H) return this.targets;
    if (this.targets) {
      for (const t of this.targets.tex) gl.deleteTexture(t);
      for (const f of this.targets.fbo) gl.deleteFramebuffer(f);
      gl.deleteRenderbuffer(this.targets.depth);
    }
    const tex = [0, 1].map(() => {
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA16F, W, H);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
      return t;
    });
    const depth = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, W, H);
    const fbo = tex.map((t, i) => {
      const f = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, f);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, t, 0);
      if (i === 1) gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
      if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE)
        throw new Error('float render target not supported');
      return f;
    });
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    this.targets = { W, H, tex, fbo, depth };
    return this.targets;
  }

  // The camera of a view {eye, target, right, fov (horizontal, degrees)} in the shifted
  // frame (plane at z = 0), for a W×H image: as imp_pinhole with fx = W/2 / tan(fov/2).
  camera(view, W, H) {
    const [x, y, z] = lookAt(view.eye, view.target, view.right);
    const fx = 0.5 * W / Math.tan(0.5 * view.fov * Math.PI / 180), fy = fx;
    const m = this.meta, p = m.pitch_mm;
    // near/far from the distances to the corners of the relief's bounding box
    const top = Math.max(m.height_max_mm - m.plane_mm, 0) + p, bot = Math.min(m.height_min_mm - m.plane_mm, 0) - p;
    let dmin = Infinity, dmax = 0;
    for (const cx of [-p, m.nx * p]) for (const cy of [-p, m.ny * p]) for (const cz of [bot, top]) {
      const dz = dot(sub([cx, cy, cz], view.eye), z);
      dmin = Math.min(dmin, dz);
      dmax = Math.max(dmax, dz);
    }
    const far = Math.max(dmax * 1.5, 1), near = Math.max(dmin * 0.5, far * 1e-5);
    const a = (far + near) / (far - near), b = -2 * far * near / (far - near);
    const e = view.eye, t = [-dot(x, e), -dot(y, e), -dot(z, e)];
    const P = [2 * fx / W, -2 * fy / H];
    // column-major clip = [P0·xc, P1·yc, a·zc + b, zc]
    const vp = new Float32Array(16);
    for (let c = 0; c < 3; c++) {
      vp[4 * c + 0] = P[0] * x[c];
      vp[4 * c + 1] = P[1] * y[c];
      vp[4 * c + 2] = a * z[c];
      vp[4 * c + 3] = z[c];
    }
    vp[12] = P[0] * t[0];
    vp[13] = P[1] * t[1];
    vp[14] = a * t[2] + b;
    vp[15] = t[2];
    return { x, y, z, fx, fy, W, H, vp, eye: view.eye };
  }

  // α per box (imp_relief_box_alpha): eq. 2 with K·r = K·(|I z| / cos θ) / |CI|.
  boxAlpha(cam, opt) {
    const m = this.meta, p = m.pitch_mm, C = cam.eye;
    const K = opt.K > 0 ? opt.K : cam.fx;
    return m.boxes.map((b) => {
      if (!(C[2] > 0) || opt.mode === 'bump') return 0;
      if (opt.mode !== 'adaptive') return 1;
      const I = [b[5] * p, b[6] * p, b[4] - m.plane_mm], v = sub(I, C), CI = norm(v);
      const above = Math.max(I[2], 0), cos = CI > 0 ? -v[2] / CI : 0;
      if (above === 0) return 0;
      if (!(cos > 1e-12) || !(CI > 0)) return 1;
      const kr = K * (above / cos) / CI;
      if (kr < opt.epsMin) return 0;
      if (kr > opt.epsMax) return 1;
      const a = (kr - opt.epsMin) / (opt.epsMax - opt.epsMin);
      return Number.isFinite(a) ? a : 1;
    });
  }

  // Instances: [lo xyz, hi xyz, u0 v0 w h, α] of the drawn boxes.
  instanceData(alpha, opt) {
    const m = this.meta, p = m.pitch_mm;
    if (opt.mode === 'rm') {
      const lo = m.height_min_mm - m.plane_mm, hi = Math.max(m.height_max_mm - m.plane_mm, lo + 1e-6);
      return { data: new Float32Array([-0.5 * p, -0.5 * p, lo, (m.nx - 0.5) * p, (m.ny - 0.5) * p, hi,
                                       0, 0, m.nx, m.ny, 1]), n: 1, floor: lo };
    }
    const out = [];
    m.boxes.forEach((b, i) => {
      if (!(alpha[i] > 0)) return;
      out.push((b[0] - 0.5) * p, (b[1] - 0.5) * p, 0, (b[0] + b[2] - 0.5) * p, (b[1] + b[3] - 0.5) * p,
               b[7] - m.plane_mm, b[0], b[1], b[2], b[3], alpha[i]);
    });
    return { data: new Float32Array(out), n: out.length / 11, floor: 0 };
  }

  bindCommon(prog, cam, light) {
    const gl = this.gl, m = this.meta, u = prog.u;
    this.textures.forEach((t, i) => {
      gl.activeTexture(gl.TEXTURE0 + i);
      gl.bindTexture(gl.TEXTURE_2D, t);
    });
    gl.uniform1i(u.uSurface, 0);
    gl.uniform1i(u.uDiffuse, 1);
    gl.uniform1i(u.uSpecular, 2);
    gl.uniform1i(u.uLobe, 3);
    gl.uniformMatrix4fv(u.uVP, false, cam.vp);
    gl.uniform3fv(u.uC, cam.eye);
    gl.uniform3fv(u.uL, light.pos);
    gl.uniform1f(u.uE0, light.e0);
    gl.uniform1f(u.uPitch, m.pitch_mm);
    gl.uniform2i(u.uGrid, m.nx, m.ny);
  }

  // view: {eye, target, right, fov} in the canvas frame (mm, unshifted); light: {pos};
  // opt: {mode, K, epsMin, epsMax, exposure, overlay (0 none, 1 height, 2 σ, 3 flags),
  // step, binary}.
  render(view, light, opt) {
    const gl = this.gl, m = this.meta, W = this.canvas.width, H = this.canvas.height;
    const shift = (a) => [a[0], a[1], a[2] - m.plane_mm];
    const cam = this.camera({ ...view, eye: shift(view.eye), target: shift(view.target) }, W, H);
    const centre = [0.5 * (m.nx - 1) * m.pitch_mm, 0.5 * (m.ny - 1) * m.pitch_mm, 0];
    const lp = shift(light.pos), dc = norm(sub(centre, lp));
    const L = { pos: lp, e0: dc * dc };
    const T = this.ensureTargets(W, H);
    const below = !(cam.eye[2] > 0);
    const alpha = this.boxAlpha(cam, opt);
    const inst = opt.overlay || below ? { n: 0 } : opt.mode === 'bump' ? { n: 0 } : this.instanceData(alpha, opt);
    gl.viewport(0, 0, W, H);
    gl.disable(gl.BLEND);
    // §5.1: the bump-mapped plane
    gl.bindFramebuffer(gl.FRAMEBUFFER, T.fbo[0]);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    if (!below && (opt.mode !== 'rm' || opt.overlay)) {
      const pp = this.progPlane;
      gl.useProgram(pp.p);
      this.bindCommon(pp, cam, L);
      const p = m.pitch_mm;
      gl.uniform4f(pp.u.uRect, -0.5 * p, -0.5 * p, (m.nx - 0.5) * p, (m.ny - 0.5) * p);
      gl.uniform1i(pp.u.uOverlay, opt.overlay | 0);
      gl.uniform2f(pp.u.uHeightRange, m.height_min_mm - m.plane_mm, m.height_max_mm - m.plane_mm);
      gl.uniform1f(pp.u.uSigmaMax, m.sigma_p99_mm);
      gl.disable(gl.DEPTH_TEST);
      gl.disable(gl.CULL_FACE);
      gl.bindVertexArray(this.planeVao);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    }
    // §5.2–5.3: the relief boxes, nearest hit first
    gl.bindFramebuffer(gl.FRAMEBUFFER, T.fbo[1]);
    gl.clearColor(0, 0, 0, 0);
    gl.clearDepth(1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (inst.n > 0) {
      const pb = this.progBox;
      gl.useProgram(pb.p);
      this.bindCommon(pb, cam, L);
      gl.uniform1f(pb.u.uFloor, inst.floor);
      gl.uniform1f(pb.u.uStep, opt.step || 1);
      gl.uniform1i(pb.u.uBinary, opt.binary ?? 8);
      gl.bindBuffer(gl.ARRAY_BUFFER, this.instances);
      gl.bufferData(gl.ARRAY_BUFFER, inst.data, gl.DYNAMIC_DRAW);
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      gl.enable(gl.CULL_FACE);
      gl.cullFace(gl.FRONT);   // back faces: one fragment per pixel even from inside a box
      gl.bindVertexArray(this.boxVao);
      gl.drawArraysInstanced(gl.TRIANGLES, 0, 36, inst.n);
      gl.disable(gl.DEPTH_TEST);
      gl.disable(gl.CULL_FACE);
    }
    // composite: α·relief + (1 − α)·bump, exposure, sRGB
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    const pc = this.progComp;
    gl.useProgram(pc.p);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, T.tex[0]);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_2D, T.tex[1]);
    gl.uniform1i(pc.u.uBump, 0);
    gl.uniform1i(pc.u.uRelief, 1);
    gl.uniform1f(pc.u.uExposure, opt.exposure ?? 1);
    gl.uniform1i(pc.u.uOverlay, opt.overlay | 0);
    gl.bindVertexArray(this.compVao);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    gl.bindVertexArray(null);
    this.stats = {
      boxes: m.boxes.length, drawn: alpha.filter((a) => a > 0).length,
      blended: alpha.filter((a) => a > 0 && a < 1).length, instances: inst.n, below,
    };
    this.lastCam = cam;
    return this.stats;
  }

  // Waits for the GPU (one pixel read back): for timing.
  finish() {
    const px = new Uint8Array(4);
    this.gl.readPixels(0, 0, 1, 1, this.gl.RGBA, this.gl.UNSIGNED_BYTE, px);
  }

  // The canvas point (mm, canvas frame, on the bump plane) under canvas pixel (mx, my)
  // (continuous device-pixel coordinates, (0, 0) the top-left corner); null off the plane.
  unproject(mx, my) {
    const c = this.lastCam;
    if (!c) return null;
    const dev = [(mx - 0.5 * c.W) / c.fx, (my - 0.5 * c.H) / c.fy, 1];
    const d = [0, 1, 2].map((k) => c.x[k] * dev[0] + c.y[k] * dev[1] + c.z[k] * dev[2]);
    if (!(d[2] < -1e-12)) return null;
    const t = -c.eye[2] / d[2];
    return [c.eye[0] + t * d[0], c.eye[1] + t * d[1], this.meta.plane_mm];
  }

  // Canvas point (mm, canvas frame) → continuous device pixel; null behind the camera.
  project(P) {
    const c = this.lastCam;
    if (!c) return null;
    const q = sub([P[0], P[1], P[2] - this.meta.plane_mm], c.eye);
    const zc = dot(c.z, q);
    if (!(zc > 1e-9)) return null;
    return [0.5 * c.W + c.fx * dot(c.x, q) / zc, 0.5 * c.H + c.fy * dot(c.y, q) / zc];
  }
}
