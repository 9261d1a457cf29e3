// The frame-rate benchmark of seed 000 Tables 1–2 in the browser (bench/view-fps.py drives
// it; docs/viewer.md publishes the figures). For each technique × distance × view angle it
// renders frames of SIZE for SECS seconds, waiting for the GPU after each (one pixel read
// back), in ROUNDS interleaved rounds, and reports the best round's frames per second (on
// a shared machine the best is the least disturbed). Parameters: size=WxH secs=S table=1|2
// rounds=R.
//   distance: in-shot = the canvas fills the frame; near = 4× closer; far = 4× further;
//   angle: front = 90° elevation, intermediate = 45°, grazing = 15°, from the −y side.
import { Renderer } from './render.js';

const q = new URLSearchParams(location.search);
const out = document.getElementById('out');
window.bench = { done: false, error: null, rows: [] };

async function main() {
  const [meta, buf] = await Promise.all([
    fetch('copy/meta.json').then((r) => { if (!r.ok) throw new Error('meta.json: HTTP ' + r.status); return r.json(); }),
    fetch('copy/textures.bin').then((r) => { if (!r.ok) throw new Error('textures.bin: HTTP ' + r.status); return r.arrayBuffer(); }),
  ]);
  const size = /^(\d+)x(\d+)$/.exec(q.get('size') || '') || [0, 400, 300];
  const canvas = document.getElementById('gl');
  canvas.width = Number(size[1]);
  canvas.height = Number(size[2]);
  const r = new Renderer(canvas, meta, buf);
  const secs = Number(q.get('secs')) || 1;
  const p = meta.pitch_mm, fov = 40, W = canvas.width, H = canvas.height;
  const c = [0.5 * (meta.nx - 1) * p, 0.5 * (meta.ny - 1) * p, meta.plane_mm];
  const shot = 0.5 * Math.max(meta.nx * p, meta.ny * p * W / H) / Math.tan(0.5 * fov * Math.PI / 180);
  const dists = { near: shot / 4, 'in shot': shot, far: shot * 4 };
  const angles = q.get('table') === '2' ? { front: 90, intermediate: 45, grazing: 15 } : { grazing: 15, front: 90 };
  const modes = q.get('table') === '2' ? ['adaptive'] : ['bump', 'rm', 'relief', 'adaptive'];
  const light = { pos: [c[0] - 200, c[1] + 100, c[2] + 300] };
  const opt = { K: 0, epsMin: 0.5, epsMax: 2.0, exposure: 1, overlay: 0, step: 1, binary: 8 };
  const distNames = q.get('table') === '2' ? ['in shot'] : Object.keys(dists);
  const rounds = Number(q.get('rounds')) || 1, best = new Map();
  for (let round = 0; round < rounds; round++)
  for (const dn of distNames)
    for (const [an, el] of Object.entries(angles))
      for (const mode of modes) {
        const e = el * Math.PI / 180, d = dists[dn];
        const eye = [c[0], c[1] - d * Math.cos(e), c[2] + d * Math.sin(e)];
        const view = { eye, target: c, right: [1, 0, 0], fov };
        const o = { ...opt, mode };
        let st = r.render(view, light, o);
        r.finish();
        let n = 0;
        const t0 = performance.now();
        while (performance.now() - t0 < secs * 1000 || n < 2) {
          st = r.render(view, light, o);
          r.finish();
          n++;
        }
        const fps = n / ((performance.now() - t0) / 1000), key = `${dn}|${an}|${mode}`;
        const row = { distance: dn, angle: an, mode, fps: Math.max(fps, best.get(key)?.fps || 0),
                      boxes: meta.boxes.length, drawn: st.drawn, round };
        best.set(key, row);
        out.textContent += JSON.stringify({ ...row, fps }) + '\n';
        if (round === rounds - 1) window.bench.rows.push(row);
        await new Promise((res) => setTimeout(res, 0));
      }
  window.bench.done = true;
}
main().catch((e) => { window.bench.error = String(e.message || e); out.textContent += 'error: ' + window.bench.error; });
