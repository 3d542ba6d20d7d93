#!/usr/bin/env node
// three.js against `bake render`: loads `bake export --bake-light`'s GLB with three.js' GLTFLoader
// (npm `three`, pinned in package-lock.json; scripts/install-threejs.sh) in headless Chromium,
// renders it from the same camera with the same exposure and tone map, and compares the picture
// with bake's PNG (docs/MATERIALS.md, "Export to glTF", has the bounds and why).
//
//   node scripts/threejs/check.js --glb scene.glb --bake bake.png --regions regions.png \
//        --render-json render.json --out DIR [--three DIR] [--chromium PATH] [--timeout S]
//        [--hide-instances 1] [--lod-select 1] [--terms ambient]
//
// bake.png, regions.png and render.json come from one `bake render PACK -o bake.png --regions
// regions.png --json` (its stats give the camera, the exposure and the sky's ambient); with
// --terms ambient from `bake render --terms ambient` and the GLB from `bake export
// --vertex-ambient`: the models' COLOR_0 against bake's ambient term (AMBIENT_BOUNDS). No
// puppeteer: a local HTTP server serves the page (page.js), three.js, the GLB and the images;
// Chromium (`--headless`, SwiftShader WebGL) posts back the numbers and the pictures.
// Writes DIR/three.png, DIR/side-by-side.png (bake | three.js | |difference| × 4) and
// DIR/metrics.json; exit 0 within the bounds, 1 outside, 3 when the check could not run.
'use strict';
const fs = require('fs');
const http = require('http');
const os = require('os');
const path = require('path');
const { spawn } = require('child_process');

// The bounds (docs/MATERIALS.md). Terrain pixels (the region image's R ≥ 250/255): the baked
// light is the same light map both renderers read, so the means agree closely; the differences
// left are bake's shadow map (direct sun) against the light map's traced shadows, and filtering.
const BOUNDS = {
  coverage_iou: 0.97, // drawn pixels (three.js: not the clear colour; bake: region coverage ≥ ½)
  terrain_ratio: [0.92, 1.08], // mean linear luminance three.js / bake over terrain pixels
  tile_ratio: [0.85, 1.15], // the same per tile of a 4 × 3 grid with ≥ 5 % terrain pixels
  terrain_blurred_rms: 0.05, // RMS of 9×9-blurred sRGB values (0..1) over terrain pixels
  // Model pixels: three.js' metallic-roughness GGX under the sun and a hemisphere light, no
  // shadows, against bake's two-layer Schlick with shadows and PRT: a sanity bound only.
  models_ratio: [0.4, 2.5],
};
// --terms ambient (bake.png from `bake render --terms ambient`, the GLB from `bake export
// --vertex-ambient`): model pixels only (g + b ≥ 250/255 in the region image), the models drawn
// unlit as base colour × COLOR_0 × vertex_ambient_scale against bake's ambient term. What is
// left between them (docs/MATERIALS.md): COLOR_0 is one light per vertex (the mean of the
// model's instances' light, the front side's mix, no top layer), bake's is per instance and side.
// The bounds hold where COLOR_0 is exactly bake's ambient (tests/export.rs' shelter scene: one
// instance, no top layer, no model light map); measured there 1.001, tiles 0.997–1.003, RMS 0.006.
const AMBIENT_BOUNDS = {
  coverage_iou: 0.97,
  models_ratio: [0.97, 1.03], // mean linear luminance three.js / bake over model pixels
  model_tile_ratio: [0.95, 1.05], // the same per tile of a 4 × 3 grid with ≥ 5 % model pixels
  models_blurred_rms: 0.025, // RMS of 9×9-blurred sRGB values (0..1) over model pixels
};
const TILE_MIN = 0.05;

function args() {
  const a = {};
  const v = process.argv.slice(2);
  for (let i = 0; i < v.length; i += 2) {
    if (!v[i].startsWith('--') || v[i + 1] === undefined) usage(`bad argument ${v[i]}`);
    a[v[i].slice(2)] = v[i + 1];
  }
  for (const k of ['glb', 'bake', 'regions', 'render-json', 'out']) if (!a[k]) usage(`--${k} is required`);
  const root = path.resolve(__dirname, '../..');
  a.three = a.three || process.env.THREEJS || path.join(root, 'target/threejs/node_modules/three');
  a.chromium = a.chromium || process.env.CHROMIUM || '/usr/bin/chromium';
  a.timeout = Number(a.timeout || 120);
  return a;
}

function usage(msg) {
  console.error(`check.js: ${msg}\nusage: node scripts/threejs/check.js --glb F --bake F.png --regions F.png --render-json F.json --out DIR [--three DIR] [--chromium PATH] [--timeout S]`);
  process.exit(3);
}

const a = args();
if (!fs.existsSync(path.join(a.three, 'package.json'))) {
  console.error(`check.js: three.js is not in ${a.three} (scripts/install-threejs.sh)`);
  process.exit(3);
}
const render = JSON.parse(fs.readFileSync(a['render-json'], 'utf8'));
const s = render.stats;
const params = {
  width: s.width, height: s.height, eye: s.eye, target: s.target, fov_y_deg: s.fov_y_deg,
  exposure: s.exposure, ambient: s.lighting.ambient,
  hide_instances: a['hide-instances'] === '1',
  // --lod-select 1: per instance, the level bake's rule picks for this view (the GLB's MSFT_lod
  // nodes, `bake export --lod`) and only the instances whose sphere meets the view frustum.
  lod_select: a['lod-select'] === '1',
  // --terms ambient: the ambient term alone, judged on the models (AMBIENT_BOUNDS).
  terms: a.terms || 'all',
};
if (!['all', 'ambient'].includes(params.terms)) usage(`--terms ${params.terms}: all or ambient`);
fs.mkdirSync(a.out, { recursive: true });

const page = `<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
"three/addons/": "/three/examples/jsm/"}}</script></head>
<body style="margin:0"><script type="module" src="/page.js"></script></body></html>`;
const types = { '.js': 'text/javascript', '.png': 'image/png', '.glb': 'model/gltf-binary', '.json': 'application/json' };

let chrome = null;
const started = Date.now();
let finished = false;
function finish(code, msg) {
  if (finished) return;
  finished = true;
  if (msg) console.error(msg);
  if (chrome && chrome.exitCode === null) chrome.kill('SIGKILL');
  server.close();
  clearTimeout(timer);
  process.exitCode = code;
  setTimeout(() => process.exit(code), 500).unref();
}

function file(res, f) {
  fs.readFile(f, (err, data) => {
    if (err) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'content-type': types[path.extname(f)] || 'application/octet-stream' });
    res.end(data);
  });
}

function body(req) {
  return new Promise((resolve) => {
    const chunks = [];
    req.on('data', (c) => chunks.push(c));
    req.on('end', () => resolve(JSON.parse(Buffer.concat(chunks).toString('utf8'))));
  });
}

const server = http.createServer(async (req, res) => {
  const url = decodeURIComponent(req.url.split('?')[0]);
  if (req.method === 'POST') {
    const b = await body(req);
    res.end('ok');
    if (url === '/progress') console.log(`check.js: ${((Date.now() - started) / 1000).toFixed(1)} s: ${b.stage}`);
    else if (url === '/log') retryOr(`the page failed: ${b.error}`);
    else if (url === '/result') judge(b);
    return;
  }
  if (url === '/') { res.writeHead(200, { 'content-type': 'text/html' }); res.end(page); return; }
  if (url === '/page.js') return file(res, path.join(__dirname, 'page.js'));
  if (url === '/params.json') { res.writeHead(200, { 'content-type': types['.json'] }); res.end(JSON.stringify(params)); return; }
  if (url === '/scene.glb') return file(res, a.glb);
  if (url === '/bake.png') return file(res, a.bake);
  if (url === '/regions.png') return file(res, a.regions);
  if (url.startsWith('/three/') && !url.includes('..')) return file(res, path.join(a.three, url.slice(7)));
  res.writeHead(404);
  res.end();
});

function judge(b) {
  const m = b.metrics;
  fs.writeFileSync(path.join(a.out, 'three.png'), Buffer.from(b.three_png, 'base64'));
  fs.writeFileSync(path.join(a.out, 'side-by-side.png'), Buffer.from(b.side_png, 'base64'));
  const fails = [];
  const within = (name, v, [lo, hi]) => { if (!(v >= lo && v <= hi)) fails.push(`${name} ${v} outside [${lo}, ${hi}]`); };
  if (params.terms === 'ambient') return judgeAmbient(b, m, fails, within);
  // --hide-instances 1: the models are loaded but not drawn, so only the terrain is judged
  // (bake's terrain pixels are terrain in three.js too; the coverage and model bounds do not apply).
  if (!params.hide_instances && !(m.coverage_iou >= BOUNDS.coverage_iou)) fails.push(`coverage IoU ${m.coverage_iou} < ${BOUNDS.coverage_iou}`);
  if (!(m.terrain.pixels > 0.05 * m.width * m.height)) fails.push(`only ${m.terrain.pixels} terrain pixels`);
  within('terrain luminance ratio', m.terrain.ratio, BOUNDS.terrain_ratio);
  const tiles = m.tiles.filter((t) => t.pixels >= TILE_MIN * t.area);
  for (const t of tiles) within(`tile ${t.tile} luminance ratio`, t.ratio, BOUNDS.tile_ratio);
  if (!(m.terrain_blurred_rms <= BOUNDS.terrain_blurred_rms)) fails.push(`terrain blurred RMS ${m.terrain_blurred_rms} > ${BOUNDS.terrain_blurred_rms}`);
  if (!params.hide_instances && m.models.pixels >= 100) within('models luminance ratio', m.models.ratio, BOUNDS.models_ratio);
  if (m.found.sun !== 1) fails.push(`${m.found.sun} suns with extras.irradiance (expected 1)`);
  if (m.found.unlit < 1) fails.push('no material with extras.bake_light (export with --bake-light)');
  const report = { ...m, hide_instances: params.hide_instances, bounds: BOUNDS, tiles_checked: tiles.length, failures: fails };
  fs.writeFileSync(path.join(a.out, 'metrics.json'), JSON.stringify(report, null, 1));
  const r = (x) => (x == null ? 'n/a' : x.toFixed(4));
  console.log(`three.js r${m.three_revision} (${m.gl}), ${m.width}×${m.height}: loaded in ${m.seconds_load.toFixed(2)} s, `
    + `rendered in ${m.seconds_render.toFixed(2)} s; ${m.found.instanced} InstancedMeshes (one per model primitive) drawing ${m.found.instances} instances in all`);
  console.log(`coverage IoU ${r(m.coverage_iou)}; terrain (${m.terrain.pixels} px) luminance ratio ${r(m.terrain.ratio)}, `
    + `blurred RMS ${r(m.terrain_blurred_rms)}; tiles ${tiles.map((t) => r(t.ratio)).join(' ')}; `
    + `models (${m.models.pixels} px) ratio ${r(m.models.ratio)}`);
  console.log(`images in ${a.out}: three.png, side-by-side.png, metrics.json`);
  if (fails.length) finish(1, `check.js: outside the bounds:\n  ${fails.join('\n  ')}`);
  else finish(0);
}

// --terms ambient: the models' pixels against bake's ambient term (AMBIENT_BOUNDS).
function judgeAmbient(b, m, fails, within) {
  const B = AMBIENT_BOUNDS;
  if (!(m.coverage_iou >= B.coverage_iou)) fails.push(`coverage IoU ${m.coverage_iou} < ${B.coverage_iou}`);
  if (!(m.models.pixels > 0.02 * m.width * m.height)) fails.push(`only ${m.models.pixels} model pixels`);
  within('models luminance ratio', m.models.ratio, B.models_ratio);
  const tiles = m.model_tiles.filter((t) => t.pixels >= TILE_MIN * t.area);
  for (const t of tiles) within(`model tile ${t.tile} luminance ratio`, t.ratio, B.model_tile_ratio);
  if (!(m.models_blurred_rms <= B.models_blurred_rms)) fails.push(`models blurred RMS ${m.models_blurred_rms} > ${B.models_blurred_rms}`);
  if (m.found.vertex_ambient < 1) fails.push('no material with COLOR_0 and a vertex_ambient_scale (export with --vertex-ambient)');
  const report = { ...m, bounds: B, tiles_checked: tiles.length, failures: fails };
  fs.writeFileSync(path.join(a.out, 'metrics.json'), JSON.stringify(report, null, 1));
  const r = (x) => (x == null ? 'n/a' : x.toFixed(4));
  console.log(`three.js r${m.three_revision} (${m.gl}), ${m.width}×${m.height}, the ambient term: ${m.found.vertex_ambient} `
    + `materials drawn as base colour × COLOR_0 × ${m.vertex_ambient_scale}; loaded in ${m.seconds_load.toFixed(2)} s, `
    + `drawn and read back in ${m.seconds_render_readback.toFixed(2)} s`);
  console.log(`coverage IoU ${r(m.coverage_iou)}; models (${m.models.pixels} px) luminance ratio ${r(m.models.ratio)}, `
    + `blurred RMS ${r(m.models_blurred_rms)}; tiles ${tiles.map((t) => r(t.ratio)).join(' ')}`);
  console.log(`images in ${a.out}: three.png, side-by-side.png, metrics.json`);
  if (fails.length) finish(1, `check.js: outside the bounds:\n  ${fails.join('\n  ')}`);
  else finish(0);
}

const timer = setTimeout(() => finish(3, `check.js: no result within ${a.timeout} s`), a.timeout * 1000);
// One retry where Chromium or the page fails before reporting (a crash of the browser under a
// loaded machine); a result outside the bounds is never retried.
let attempt = 0;
function retryOr(msg) {
  if (finished) return;
  if (attempt < 2) {
    console.error(`check.js: attempt ${attempt} failed, retrying once: ${msg}`);
    if (chrome && chrome.exitCode === null) {
      chrome.removeAllListeners('exit');
      chrome.kill('SIGKILL');
    }
    launch();
  } else {
    finish(3, `check.js: ${msg}`);
  }
}

function launch() {
  attempt += 1;
  const url = `http://127.0.0.1:${server.address().port}/`;
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'bake-threejs-'));
  const c = spawn(a.chromium, [
    '--headless=new', '--no-sandbox', '--no-first-run', '--disable-extensions', '--mute-audio',
    '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist',
    `--user-data-dir=${profile}`, `--window-size=${params.width},${params.height}`, url,
  ], { stdio: ['ignore', 'ignore', 'pipe'] });
  chrome = c;
  let err = '';
  c.stderr.on('data', (d) => { err = (err + d).slice(-4000); });
  c.on('error', (e) => finish(3, `check.js: cannot start ${a.chromium}: ${e}`));
  c.on('exit', (code) => {
    // Chromium's helper processes may still write into the profile after the browser exits
    // (ENOTEMPTY seen once): retry, and leave a stray temporary folder rather than fail a
    // check whose result is already in.
    try {
      fs.rmSync(profile, { recursive: true, force: true, maxRetries: 5, retryDelay: 200 });
    } catch (e) {
      process.stderr.write(`check.js: could not remove ${profile}: ${e.message}\n`);
    }
    if (!finished && chrome === c) retryOr(`Chromium exited (${code}) before the page reported:\n${err}`);
  });
}
server.listen(0, '127.0.0.1', launch);
