// The page of scripts/threejs/check.js, run in headless Chromium: loads /scene.glb with three.js'
// GLTFLoader, renders it from `bake render`'s camera with bake's tone map, compares the picture
// with bake's PNG (/bake.png) region by region (/regions.png) and posts the numbers and images to
// /result. Errors go to /log and end the run.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const post = (path, body) =>
  fetch(path, { method: 'POST', headers: { 'content-type': 'application/json' }, body: JSON.stringify(body) });
const fail = (e) => post('/log', { error: String(e && e.stack ? e.stack : e) });
window.addEventListener('error', (e) => fail(e.error || e.message));
window.addEventListener('unhandledrejection', (e) => fail(e.reason));

// bake's tone map (src/render/shaders/tonemap.wgsl): L_s = 1 − exp(−L·s), then sRGB on output.
THREE.ShaderChunk.tonemapping_pars_fragment = THREE.ShaderChunk.tonemapping_pars_fragment.replace(
  'vec3 CustomToneMapping( vec3 color ) { return color; }',
  'vec3 CustomToneMapping( vec3 color ) { return 1.0 - exp( -max( color, 0.0 ) * toneMappingExposure ); }',
);

// bake's Z-up world to glTF's Y-up one: (x, y, z) → (x, z, −y), as the file's root node does.
const yUp = (p) => new THREE.Vector3(p[0], p[2], -p[1]);

async function pixels(url, w, h) {
  const blob = await (await fetch(url)).blob();
  const bmp = await createImageBitmap(blob, { colorSpaceConversion: 'none', premultiplyAlpha: 'none' });
  if (bmp.width !== w || bmp.height !== h) throw new Error(`${url} is ${bmp.width}×${bmp.height}, not ${w}×${h}`);
  const c = new OffscreenCanvas(w, h);
  const g = c.getContext('2d', { willReadFrequently: true });
  g.drawImage(bmp, 0, 0);
  return g.getImageData(0, 0, w, h).data;
}

async function main() {
  const p = await (await fetch('/params.json')).json();
  const { width: W, height: H } = p;
  const t0 = performance.now();
  const gltf = await new GLTFLoader().loadAsync('/scene.glb');
  const tLoad = performance.now() - t0;
  await post('/progress', { stage: `GLB loaded and parsed in ${(tLoad / 1000).toFixed(2)} s` });

  const scene = gltf.scene;
  const found = { sun: 0, unlit: 0, instanced: 0, instances: 0, vertex_ambient: 0 };
  // --terms ambient: bake's ambient term alone (`bake render --terms ambient`). The sun is off;
  // a model material with COLOR_0 (`bake export --vertex-ambient`) draws unlit as base colour ×
  // COLOR_0 × the file's vertex_ambient_scale, which docs/MATERIALS.md says is bake's ambient
  // radiance (W/m²/sr); a model without COLOR_0 keeps the hemisphere light (bake's sky fallback).
  const ambientOnly = p.terms === 'ambient';
  const rootExtras = (gltf.parser.json.nodes.find((n) => n.extras && n.extras.vertex_ambient_scale) || {}).extras;
  const vaScale = rootExtras ? rootExtras.vertex_ambient_scale : null;
  const basic = new Map();
  const ambientMaterial = (m) => {
    if (!basic.has(m)) {
      basic.set(m, new THREE.MeshBasicMaterial({
        name: m.name, color: m.color.clone().multiplyScalar(vaScale), map: m.map, vertexColors: true,
        alphaTest: m.alphaTest, transparent: m.transparent, opacity: m.opacity, side: m.side,
      }));
      found.vertex_ambient += 1;
    }
    return basic.get(m);
  };
  scene.traverse((o) => {
    // The sun in bake's units: its RGB irradiance (W/m², light extras), so that three.js'
    // Lambert term albedo/π·E·cos is bake's radiance.
    if (o.isDirectionalLight && o.userData.irradiance) {
      o.color.setRGB(...o.userData.irradiance);
      o.intensity = ambientOnly ? 0 : 1;
      found.sun += 1;
    }
    if (ambientOnly && o.isMesh && vaScale && o.geometry.attributes.color) {
      o.material = Array.isArray(o.material) ? o.material.map(ambientMaterial) : ambientMaterial(o.material);
    }
    if (o.isInstancedMesh) {
      found.instanced += 1;
      found.instances += o.count;
      // --hide-instances: loaded, not drawn (SwiftShader cannot draw 10⁹ triangles in minutes).
      if (p.hide_instances) o.visible = false;
    }
    if (o.isMesh) {
      for (const m of Array.isArray(o.material) ? o.material : [o.material]) {
        // The baked terrain: base colour × irradiance_scale/π is its radiance (docs/MATERIALS.md).
        const bl = m.userData.bake_light;
        if (bl && !m.userData.scaled) {
          m.color.multiplyScalar(bl.irradiance_scale / Math.PI);
          m.userData.scaled = true;
          found.unlit += 1;
        }
      }
    }
  });
  // --lod-select: per instance the level bake's renderer picks (src/lod/select.rs: the coarsest
  // level l with e_l·s·k ≤ τ·d, k = H / (2 tan(fov/2)), τ = 1 px, d = |eye − placed sphere
  // centre|), from the model node's extras.lod and its MSFT_lod nodes; instances whose placed
  // sphere misses the view frustum are dropped, as the renderer culls them.
  const lodStats = { models: 0, levels: [], culled: 0, triangles: 0 };
  if (p.lod_select) {
    const json = gltf.parser.json;
    const sunNode = json.nodes.find((n) => n.extras && n.extras.section === 'sun' && n.extras.direction);
    const sunDir = sunNode ? sunNode.extras.direction : null;
    const sunLight = json.extensions && json.extensions.KHR_lights_punctual && json.extensions.KHR_lights_punctual.lights[0];
    const sunIrr = sunLight && sunLight.extras ? sunLight.extras.irradiance : null;
    const kView = H / (2 * Math.tan((p.fov_y_deg * Math.PI) / 360));
    const eyeZ = new THREE.Vector3(...p.eye);
    const cam0 = new THREE.PerspectiveCamera(p.fov_y_deg, W / H, 0.01, 1e7);
    cam0.position.copy(yUp(p.eye));
    cam0.up.set(0, 1, 0);
    cam0.lookAt(yUp(p.target));
    cam0.updateMatrixWorld();
    const frustum = new THREE.Frustum().setFromProjectionMatrix(
      new THREE.Matrix4().multiplyMatrices(cam0.projectionMatrix, cam0.matrixWorldInverse));
    const instancedOf = (o) => { const out = []; o.traverse((c) => { if (c.isInstancedMesh) out.push(c); }); return out; };
    const trianglesOf = (m) => (m.geometry.index ? m.geometry.index.count : m.geometry.attributes.position.count) / 3;
    for (let i = 0; i < json.nodes.length; i++) {
      const lod = json.nodes[i].extras && json.nodes[i].extras.lod;
      if (!lod) continue;
      const main = await gltf.parser.getDependency('node', i);
      const levels = [main];
      for (const id of lod.nodes) levels.push(await gltf.parser.getDependency('node', id));
      const meshes = levels.map(instancedOf);
      const base = meshes[0][0];
      if (!base) continue;
      lodStats.models += 1;
      const n = base.count;
      const m = new THREE.Matrix4(), pos = new THREE.Vector3(), q = new THREE.Quaternion(), sc = new THREE.Vector3();
      const centre = new THREE.Vector3(...lod.centre);
      const chosen = levels.map(() => []);
      const skeleton = [];
      for (let k = 0; k < n; k++) {
        base.getMatrixAt(k, m);
        m.decompose(pos, q, sc);
        const s = Math.abs(sc.x);
        const c = centre.clone().multiplyScalar(s).applyQuaternion(q).add(pos); // bake's frame
        const sphere = new THREE.Sphere(yUp([c.x, c.y, c.z]), lod.radius * s);
        if (!frustum.intersectsSphere(sphere)) { lodStats.culled += 1; continue; }
        const d = c.distanceTo(eyeZ);
        if (lod.skeleton && lod.radius * s * kView <= lod.skeleton.pixels * d) { skeleton.push(k); continue; }
        let l = 0;
        for (let j = lod.errors.length - 1; j > 0; j--) if (lod.errors[j] * s * kView <= d) { l = j; break; }
        chosen[l].push(k);
      }
      const matrices = meshes[0].map((im) => im.instanceMatrix.array.slice());
      for (let l = 0; l < levels.length; l++) {
        lodStats.levels[l] = (lodStats.levels[l] || 0) + chosen[l].length;
        for (const im of meshes[l]) {
          const src = matrices[0];
          for (let j = 0; j < chosen[l].length; j++) im.instanceMatrix.array.set(src.subarray(16 * chosen[l][j], 16 * chosen[l][j] + 16), 16 * j);
          im.count = chosen[l].length;
          im.instanceMatrix.needsUpdate = true;
          im.computeBoundingSphere();
          im.frustumCulled = false;
          lodStats.triangles += trianglesOf(im) * chosen[l].length;
          if (p.hide_instances) im.visible = false;
        }
        if (l > 0) main.parent.add(levels[l]);
      }
      // The skeleton: three.js does not instance lines and points, so the chosen instances'
      // copies are placed here, in one line-segment and one point object per model, lit as bake
      // lights them (a surface facing +Z: albedo/π · (E_sky(+Z) + E_sun · max(0, s_z))).
      lodStats.skeleton = (lodStats.skeleton || 0) + skeleton.length;
      if (lod.skeleton && skeleton.length) {
        const sk = await gltf.parser.getDependency('node', lod.skeleton.node);
        const lit = (sunIrr && sunDir) ? sunIrr.map((e, c) => p.ambient[c] + e * Math.max(0, sunDir[2])) : p.ambient;
        sk.traverse((o) => {
          if (!(o.isLineSegments || o.isPoints)) return;
          const src = o.geometry.attributes.position;
          const out = new Float32Array(3 * src.count * skeleton.length);
          const v = new THREE.Vector3();
          let w = 0;
          for (const k of skeleton) {
            base.getMatrixAt(k, m);
            for (let j = 0; j < src.count; j++) {
              v.fromBufferAttribute(src, j).applyMatrix4(m);
              out[w++] = v.x; out[w++] = v.y; out[w++] = v.z;
            }
          }
          const g = new THREE.BufferGeometry();
          g.setAttribute('position', new THREE.BufferAttribute(out, 3));
          const material = o.material.clone();
          material.color.multiply(new THREE.Color().setRGB(...lit.map((e) => e / Math.PI)));
          if (o.isPoints) { material.size = 1; material.sizeAttenuation = false; }
          const obj = o.isPoints ? new THREE.Points(g, material) : new THREE.LineSegments(g, material);
          obj.frustumCulled = false;
          if (p.hide_instances) obj.visible = false;
          main.parent.add(obj);
        });
      }
    }
    // Every instanced triangle the frame draws (models without levels included), to set
    // beside `bake render`'s statistics (its triangles less the terrain's).
    lodStats.instance_triangles = 0;
    scene.traverse((o) => {
      if (o.isInstancedMesh && o.visible) lodStats.instance_triangles += o.count * (o.geometry.index ? o.geometry.index.count : o.geometry.attributes.position.count) / 3;
    });
    await post('/progress', { stage: `levels chosen: ${JSON.stringify(lodStats)}` });
  }
  // The sky's ambient on the models, as bake's sky fallback: albedo/π · E_sky · (1 + n_z)/2.
  const hemi = new THREE.HemisphereLight(new THREE.Color().setRGB(...p.ambient), new THREE.Color(0, 0, 0), 1);
  hemi.position.set(0, 1, 0);
  scene.add(hemi);

  const eye = yUp(p.eye);
  const target = yUp(p.target);
  const d = eye.distanceTo(target);
  const camera = new THREE.PerspectiveCamera(p.fov_y_deg, W / H, Math.max(1e-3 * d, 0.01), 1e4 * d);
  camera.position.copy(eye);
  camera.up.set(0, 1, 0);
  camera.lookAt(target);

  const canvas = document.createElement('canvas');
  canvas.width = W;
  canvas.height = H;
  document.body.appendChild(canvas);
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(W, H, false);
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  renderer.toneMapping = THREE.CustomToneMapping;
  renderer.toneMappingExposure = p.exposure;
  renderer.setClearColor(new THREE.Color().setRGB(1, 0, 1), 1); // magenta: "nothing drawn"
  renderer.compile(scene, camera);
  await post('/progress', { stage: `shaders compiled; drawing` });
  const t1 = performance.now();
  renderer.render(scene, camera);
  renderer.getContext().finish();
  const tRender = performance.now() - t1;

  const c3 = new OffscreenCanvas(W, H);
  const g3 = c3.getContext('2d', { willReadFrequently: true });
  g3.drawImage(canvas, 0, 0);
  const three = g3.getImageData(0, 0, W, H).data;
  // The frame's pixels in hand: Chromium's WebGL may return from finish() before SwiftShader has
  // drawn everything, so this is the honest end of the draw.
  const tPixels = performance.now() - t1;
  await post('/progress', { stage: `drawn and read back in ${(tPixels / 1000).toFixed(2)} s` });
  const bake = await pixels('/bake.png', W, H);
  const regions = await pixels('/regions.png', W, H);

  const lin = (v) => { const c = v / 255; return c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4; };
  const lum = (a, i) => 0.2126 * lin(a[i]) + 0.7152 * lin(a[i + 1]) + 0.0722 * lin(a[i + 2]);
  const N = W * H;
  const cls = new Uint8Array(N); // 0 sky, 1 terrain, 2 models, 3 mixed (edges)
  let inter = 0, union = 0;
  for (let k = 0; k < N; k++) {
    const i = 4 * k;
    const [r, g, b] = [regions[i], regions[i + 1], regions[i + 2]];
    cls[k] = r >= 250 ? 1 : g + b >= 250 ? 2 : r + g + b <= 5 ? 0 : 3;
    const drawnBake = r + g + b >= 128;
    const drawn3 = !(three[i] >= 250 && three[i + 1] <= 5 && three[i + 2] >= 250);
    if (drawnBake && drawn3) inter++;
    if (drawnBake || drawn3) union++;
  }
  // Mean linear luminance per class and per tile of a 4 × 3 grid (terrain).
  const stats = (pred) => {
    let n = 0, a = 0, b = 0;
    for (let k = 0; k < N; k++) if (pred(k)) { n++; a += lum(three, 4 * k); b += lum(bake, 4 * k); }
    return { pixels: n, three: n ? a / n : null, bake: n ? b / n : null, ratio: n && b > 0 ? a / b : null };
  };
  const terrain = stats((k) => cls[k] === 1);
  const models = stats((k) => cls[k] === 2);
  const tilesOf = (cl) => {
    const tiles = [];
    for (let ty = 0; ty < 3; ty++) for (let tx = 0; tx < 4; tx++) {
      const x0 = Math.floor(tx * W / 4), x1 = Math.floor((tx + 1) * W / 4);
      const y0 = Math.floor(ty * H / 3), y1 = Math.floor((ty + 1) * H / 3);
      const s = stats((k) => { const x = k % W, y = (k / W) | 0; return cls[k] === cl && x >= x0 && x < x1 && y >= y0 && y < y1; });
      s.tile = [tx, ty];
      s.area = (x1 - x0) * (y1 - y0);
      tiles.push(s);
    }
    return tiles;
  };
  const tiles = tilesOf(1);
  const modelTiles = tilesOf(2);
  // Blurred RMS over one class (terrain 1, models 2): each image's sRGB values averaged over the
  // class' pixels of a (2R+1)² window (normalized convolution), the RMS difference over them, 3
  // channels.
  const R = 4;
  const blurredRms = (cl) => {
    const blurred = (img) => {
      const out = new Float32Array(3 * N);
      const sum = new Float64Array(4 * (W + 1) * (H + 1)); // integral image of (v·m, m)
      const at = (x, y) => 4 * (y * (W + 1) + x);
      for (let y = 0; y < H; y++) for (let x = 0; x < W; x++) {
        const k = y * W + x, m = cls[k] === cl ? 1 : 0, o = at(x + 1, y + 1);
        for (let c = 0; c < 3; c++) sum[o + c] = m * img[4 * k + c] / 255 + sum[at(x, y + 1) + c] + sum[at(x + 1, y) + c] - sum[at(x, y) + c];
        sum[o + 3] = m + sum[at(x, y + 1) + 3] + sum[at(x + 1, y) + 3] - sum[at(x, y) + 3];
      }
      for (let y = 0; y < H; y++) for (let x = 0; x < W; x++) {
        const xa = Math.max(0, x - R), xb = Math.min(W, x + R + 1), ya = Math.max(0, y - R), yb = Math.min(H, y + R + 1);
        const box = (c) => sum[at(xb, yb) + c] - sum[at(xa, yb) + c] - sum[at(xb, ya) + c] + sum[at(xa, ya) + c];
        const m = box(3);
        for (let c = 0; c < 3; c++) out[3 * (y * W + x) + c] = m > 0 ? box(c) / m : 0;
      }
      return out;
    };
    const b3 = blurred(three), bb = blurred(bake);
    let se = 0, ns = 0;
    for (let k = 0; k < N; k++) if (cls[k] === cl) for (let c = 0; c < 3; c++) { const e = b3[3 * k + c] - bb[3 * k + c]; se += e * e; ns++; }
    return ns ? Math.sqrt(se / ns) : null;
  };

  // Side by side: bake | three.js | |difference| × 4.
  const side = new OffscreenCanvas(3 * W, H);
  const gs = side.getContext('2d');
  const diff = new ImageData(W, H);
  for (let i = 0; i < 4 * N; i += 4) {
    for (let c = 0; c < 3; c++) diff.data[i + c] = Math.min(255, 4 * Math.abs(three[i + c] - bake[i + c]));
    diff.data[i + 3] = 255;
  }
  gs.putImageData(new ImageData(new Uint8ClampedArray(bake), W, H), 0, 0);
  gs.putImageData(new ImageData(new Uint8ClampedArray(three), W, H), W, 0);
  gs.putImageData(diff, 2 * W, 0);
  const toData = async (c) => {
    const blob = await c.convertToBlob({ type: 'image/png' });
    const buf = new Uint8Array(await blob.arrayBuffer());
    let s = '';
    for (let i = 0; i < buf.length; i += 0x8000) s += String.fromCharCode(...buf.subarray(i, i + 0x8000));
    return btoa(s);
  };
  const info = renderer.getContext().getParameter(renderer.getContext().VERSION);
  await post('/result', {
    metrics: {
      width: W, height: H, found, gl: info, three_revision: THREE.REVISION,
      seconds_load: tLoad / 1000, seconds_render: tRender / 1000, seconds_render_readback: tPixels / 1000, lod_select: p.lod_select ? lodStats : null,
      coverage_iou: union ? inter / union : null,
      terrain, models, tiles, model_tiles: modelTiles, blur_radius: R, terms: p.terms,
      terrain_blurred_rms: blurredRms(1), models_blurred_rms: blurredRms(2),
      vertex_ambient_scale: vaScale,
    },
    three_png: await toData(c3),
    side_png: await toData(side),
  });
}

main().catch(fail);
